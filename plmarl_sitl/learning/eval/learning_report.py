"""Regenerate the "## Learning" section of docs/RESULTS.md from saved artefacts.

    python -m plmarl_sitl.learning.eval.learning_report --results docs/RESULTS.md --dir docs/results/learning

Reads <dir>/results.json (plmarl eval), <dir>/prediction.json (python -m
plmarl_sitl.learning.eval.prediction), <dir>/bench_infer.json (plmarl bench infer --json), optional
<dir>/failure.json, <dir>/seeds.json, <dir>/scratch.json (more plmarl eval runs), and the
cards in policies/. Writes the block between <!-- learning:begin/end --> markers.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from plmarl_sitl.config import PROJECT_POLICIES, read_yaml
from plmarl_sitl.learning.eval.report import (
    coverage_table_md,
    full_table_md,
    lambda_table_md,
    pvalue_table_md,
    splice_section,
)


def _load(p: Path):
    return json.loads(p.read_text()) if p.is_file() else None


def training_table(policies: Path) -> str:
    lines = ["| method | MAPPO episodes | engine fit (s) | imitation (s) | MAPPO (s) | total (s) | git commit | machine |",
             "|---|---|---|---|---|---|---|---|"]
    for m in ("pl-marl", "gru", "tag-mappo"):
        f = policies / m / "card.yaml"
        if not f.is_file():
            continue
        c = read_yaml(f)
        t = c["training"]
        lines.append(f"| {m} | {t['episodes']} | {t.get('predictor_wall_s', 0):.0f} | {t.get('imitation_wall_s', 0):.0f} | "
                     f"{t['mappo_wall_s']:.0f} | {t['total_wall_s']:.0f} | `{c['git_commit'][:12]}{'+dirty' if c['git_commit'].endswith('+dirty') else ''}` | {t['machine']} |")
    return "\n".join(lines)


def prediction_table(pred: dict) -> str:
    ages = pred["ages_s"]
    engines = list(next(iter(pred["errors_m"].values())).keys())
    head = "| trajectories | " + " | ".join(f"{e} @ {a} s" for e in engines for a in ages) + " |"
    lines = [head, "|" + "---|" * (1 + len(engines) * len(ages))]
    for name, errs in pred["errors_m"].items():
        cells = []
        for e in engines:
            for a in ages:
                v = errs[e][str(a)] if str(a) in errs[e] else errs[e][a]
                cells.append(f"{v:.1f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def latency_table(bench: dict) -> str:
    lines = ["| method | N | median (us) | p99 (us) |", "|---|---|---|---|"]
    for r in bench["rows"]:
        lines.append(f"| {r['method']} | {r['n']} | {r['median_us']:.1f} | {r['p99_us']:.1f} |")
    by = {(r["method"], r["n"]): r["median_us"] for r in bench["rows"]}
    ns = sorted({r["n"] for r in bench["rows"]})
    extra = ""
    if ("pl-marl", ns[0]) in by and ("pl-marl", ns[-1]) in by:
        extra = f"\n\nPL-MARL N={ns[-1]} / N={ns[0]}: {by[('pl-marl', ns[-1])] / by[('pl-marl', ns[0])]:.2f}"
        if ("gru", ns[-1]) in by:
            extra += f"; GRU / PL-MARL at N={ns[-1]}: {by[('gru', ns[-1])] / by[('pl-marl', ns[-1])]:.2f}x"
    runs = bench.get("runs") or []
    if len(runs) > 1:
        extra += f"\n\nAll {len(runs)} runs (the table above is run 1), median us per N:\n\n"
        extra += "| run | load avg (1 min) | " + " | ".join(f"pl-marl N={n}" for n in ns) + f" | gru N={ns[-1]} | N={ns[-1]} / N={ns[0]} | GRU / PL-MARL |\n"
        extra += "|---" * (len(ns) + 5) + "|\n"
        for i, run in enumerate(runs, 1):
            b = {(r["method"], r["n"]): r["median_us"] for r in run["rows"]}
            extra += (f"| {i} | {run.get('load_average_1min', '')} | " + " | ".join(f"{b[('pl-marl', n)]:.1f}" for n in ns)
                      + f" | {b[('gru', ns[-1])]:.1f} | {b[('pl-marl', ns[-1])] / b[('pl-marl', ns[0])]:.2f}"
                      + f" | {b[('gru', ns[-1])] / b[('pl-marl', ns[-1])]:.2f}x |\n")
        extra = extra.rstrip("\n")
    if bench.get("note"):
        extra += f"\n\n{bench['note']}."
    return "\n".join(lines) + extra + f"\n\nMachine: {bench['machine']}, {bench['calls']} timed decisions per cell."


def build(d: Path, policies: Path, narrative: str) -> str:
    parts = [narrative.strip(), ""]
    res = _load(d / "results.json")
    if res:
        ex = res["extra"]
        parts += [
            "### Coverage vs T_up (deterministic, Fig. 3b)", "",
            f"`plmarl eval missions/paper_urban.yaml --methods pl-marl,gru,tag-mappo,dead-reckoning,oracle --tup 5,10,...,50 "
            f"--episodes {ex['episodes']} --seed {ex['seed']} --out docs/results/learning --json`", "",
            f"Coverage = mean C(t) for t > {ex['from_s']} s, mean [95% CI] over {ex['episodes']} paired episodes; "
            "(x%) = mean per-episode fraction of the Oracle (now called `greedy`) on the same episodes.", "",
            coverage_table_md(res), "",
            "Whole-episode mean coverage (t = 1..200 s, includes the fly-out from the launch line):", "",
            full_table_md(res), "",
            "Mean lambda_2 (weighted comm graph, t > 50 s):", "", lambda_table_md(res), "",
            "Mann-Whitney U (two-sided) p-values, PL-MARL vs each method (per-episode coverage):", "",
            pvalue_table_md(res), "",
            "![coverage vs T_up](results/learning/coverage_vs_tup.png)", "",
            "![training curves](results/learning/training_curves.png)", "",
        ]
    seeds = _load(d / "seeds.json")
    if seeds and "columns" in seeds:  # {"title", "text", "columns": [...], "rows": [{"method", "tup", "values": [...]}]}
        cols = seeds["columns"]
        parts += [f"### {seeds['title']}", "", seeds["text"], "",
                  "| method | T_up (s) | " + " | ".join(cols) + " | mean |", "|---" * (len(cols) + 3) + "|"]
        for r in seeds["rows"]:
            vals = [v for v in r["values"] if v is not None]
            cells = " | ".join("-" if v is None else f"{v:.3f}" for v in r["values"])
            parts.append(f"| {r['method']} | {r['tup']} | {cells} | {sum(vals) / len(vals):.3f} |")
        parts.append("")
    elif seeds:
        parts += ["### Training-seed spread (same pipeline, seeds 1-3, same evaluation episodes)", "",
                  "Seeds 2 and 3 reuse seed 1's fitted engines (`--predictor`); evaluated with "
                  + ", ".join(f"`{c}`" for c in seeds["commands"] if c) + ". Steady-state coverage:", "",
                  "| method | T_up (s) | seed 1 (shipped) | seed 2 | seed 3 | mean |", "|---|---|---|---|---|---|"]
        parts += [f"| {r['method']} | {r['tup']} | {r['seed1']:.3f} | {r['seed2']:.3f} | {r['seed3']:.3f} | {r['mean']:.3f} |"
                  for r in seeds["rows"]]
        parts.append("")
    for name, title in (("failure.json", "### One node fails at t = 100 s (every episode), coverage for t > 100 s"),
                        ("scratch.json", "### Ablation: MAPPO from scratch (no Oracle-imitation warm start), PL-MARL seed 1")):
        r = _load(d / name)
        if r:
            parts += [title, "", f"`{r['extra'].get('command', '')}`", "", coverage_table_md(r), ""]
            if r["p_values"]:
                parts += ["p-values (PL-MARL vs):", "", pvalue_table_md(r), ""]
    pred = _load(d / "prediction.json")
    if pred:
        parts += ["### Prediction error (position, metres) at P-AoI 10 / 25 / 50 s", "",
                  f"`python -m plmarl_sitl.learning.eval.prediction missions/paper_urban.yaml --episodes {pred['episodes']} --seed {pred['seed']}`", "",
                  prediction_table(pred), ""]
    bench = _load(d / "bench_infer.json")
    if bench:
        parts += ["### Decision latency (TorchScript, one thread)", "", "`plmarl bench infer --json`", "",
                  latency_table(bench), ""]
    parts += ["### Training time", "", "`plmarl train --method M --seed 1` (cards in policies/M/card.yaml)", "",
              training_table(policies), ""]
    return "\n".join(parts) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--results", default="docs/RESULTS.md")
    ap.add_argument("--dir", default="docs/results/learning")
    ap.add_argument("--policies", default=str(PROJECT_POLICIES))
    ap.add_argument("--narrative", default="docs/results/learning/narrative.md")
    a = ap.parse_args(argv)
    narrative = Path(a.narrative).read_text() if Path(a.narrative).is_file() else ""
    body = build(Path(a.dir), Path(a.policies), narrative)
    splice_section(Path(a.results), "## Learning", body, marker="learning")


if __name__ == "__main__":
    main()
