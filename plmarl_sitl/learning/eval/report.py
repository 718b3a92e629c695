"""Tables, plots and the RESULTS.md section for an evaluation."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import numpy as np


def _rows_by(res: dict) -> dict[tuple[str, int], dict]:
    rows = {(r["method"], r["tup"]): dict(r) for r in res["results"]}
    for e in res["extra"]["rows"]:
        rows[(e["method"], e["tup"])].update(e)
    return rows


def coverage_table_md(res: dict) -> str:
    rows = _rows_by(res)
    methods = list(dict.fromkeys(r["method"] for r in res["results"]))
    tups = sorted({r["tup"] for r in res["results"]})
    # Results saved before issue 24 hold the fraction of the Oracle (the greedy) under its old key.
    key = next((k for k in ("fraction_of_best_mean", "fraction_of_oracle_mean") if any(k in r for r in rows.values())), None)
    has_ref = key is not None
    head = "| T_up (s) | " + " | ".join(methods) + " |"
    lines = [head, "|" + "---|" * (len(methods) + 1)]
    for t in tups:
        cells = []
        for m in methods:
            r = rows[(m, t)]
            c = f"{r['coverage_mean']:.3f} [{r['coverage_ci95'][0]:.3f}, {r['coverage_ci95'][1]:.3f}]"
            if has_ref:
                c += f" ({100 * r[key]:.0f}%)" if key in r else ""
            cells.append(c)
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _per_tup_table(res: dict, key: str, fmt: str) -> str:
    """A T_up x method markdown table of one per-run field."""
    rows = _rows_by(res)
    methods = list(dict.fromkeys(r["method"] for r in res["results"]))
    tups = sorted({r["tup"] for r in res["results"]})
    lines = ["| T_up (s) | " + " | ".join(methods) + " |", "|" + "---|" * (len(methods) + 1)]
    for t in tups:
        lines.append(f"| {t} | " + " | ".join(format(rows[(m, t)][key], fmt) for m in methods) + " |")
    return "\n".join(lines)


def best_reference_md(res: dict) -> str:
    """One line per T_up: the per-episode best reference's mean coverage and which one it was."""
    rows = _rows_by(res)
    seen: dict[int, dict] = {}
    for (_, t), r in rows.items():
        if "best_reference" in r:
            seen.setdefault(t, r)
    if not seen:
        return "No reference method in this run (greedy, clairvoyant or service): no fractions."
    return "\n".join(f"Best reference at T_up {t} s: {r['best_reference_coverage_mean']:.3f} ({r['best_reference']})."
                     for t, r in sorted(seen.items()))


def lambda_table_md(res: dict) -> str:
    return _per_tup_table(res, "lambda2_mean", ".2f")


def full_table_md(res: dict) -> str:
    return _per_tup_table(res, "coverage_full_mean", ".3f")


def comparison_text(c: dict) -> str:
    """One comparison (`stats.compare`) for a table cell: 'MWU p / paired p (wins/losses)'."""
    return f"{c['p']:.2g} / {c['p_paired']:.2g} ({c['wins']}/{c['losses']})"


def _p_cell(p: dict) -> str:
    """Results written before the paired test carry only the MWU p."""
    return comparison_text(p) if "p_paired" in p else f"{p['p']:.2g}"


def pvalue_table_md(res: dict) -> str:
    others = list(dict.fromkeys(p["versus"] for p in res["p_values"]))
    tups = sorted({p["tup"] for p in res["p_values"]})
    pv = {(p["versus"], p["tup"]): _p_cell(p) for p in res["p_values"]}
    lines = ["| T_up (s) | " + " | ".join(f"vs {o}" for o in others) + " |", "|" + "---|" * (len(others) + 1)]
    for t in tups:
        lines.append(f"| {t} | " + " | ".join(pv[(o, t)] for o in others) + " |")
    return "\n".join(lines)


COLOURS = {"pl-marl": "tab:blue", "gru": "tab:orange", "tag-mappo": "tab:green", "dead-reckoning": "tab:red",
           "greedy": "black", "clairvoyant": "tab:brown", "heuristic": "tab:gray", "service": "tab:purple"}
REFERENCE_LINES = ("greedy", "clairvoyant")  # drawn dashed


MARKERS = ("o", "s", "^", "D", "v", "P")
COINCIDE = 0.002  # coverage: lines closer than this everywhere cannot be told apart on the plot


def coinciding(ys: dict[str, np.ndarray], tol: float = COINCIDE) -> list[list[str]]:
    """Methods in groups whose curves are within `tol` of the group's first everywhere."""
    groups: list[list[str]] = []
    for m, y in ys.items():
        g = next((g for g in groups if np.max(np.abs(ys[g[0]] - y)) < tol), None)
        if g is None:
            groups.append([m])
        else:
            g.append(m)
    return groups


def plot_coverage_vs_tup(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _rows_by(res)
    methods = list(dict.fromkeys(r["method"] for r in res["results"]))
    tups = sorted({r["tup"] for r in res["results"]})
    fig, ax = plt.subplots(figsize=(5.5, 4.3))
    ys = {m: np.array([rows[(m, t)]["coverage_mean"] for t in tups]) for m in methods}
    groups = coinciding(ys)
    spread = 0.012 * (max(tups) - min(tups) if len(tups) > 1 else 1.0)  # x offset between coinciding lines
    for m in methods:
        lo = np.array([rows[(m, t)]["coverage_ci95"][0] for t in tups])
        hi = np.array([rows[(m, t)]["coverage_ci95"][1] for t in tups])
        c = COLOURS.get(m)
        group = next(g for g in groups if m in g)
        k = group.index(m)
        x = np.array(tups, dtype=float) + (k - (len(group) - 1) / 2) * spread
        ax.plot(x, ys[m], marker=MARKERS[k % len(MARKERS)], ms=4 if len(group) > 1 else 3, label=m,
                ls="--" if m in REFERENCE_LINES else "-", color=c, alpha=0.85)
        ax.fill_between(x, lo, hi, alpha=0.15, color=c)
    same = [" = ".join(g) for g in groups if len(g) > 1]
    if same:  # lines drawn on top of each other hide all but one: say so
        fig.text(0.01, 0.01, f"coincide within {COINCIDE:g} (drawn side by side): " + "; ".join(same), fontsize=7)
    ax.set_xlabel("signalling interval T_up (s)")
    ax.set_ylabel(f"steady-state coverage (t > {res['extra']['from_s']} s)")
    low = min(r["coverage_ci95"][0] for r in res["results"])
    ax.set_ylim(max(0.0, round(low - 0.05, 1)), 1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Coverage vs T_up, deterministic, {res['extra']['episodes']} episodes")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_training_curves(curves: dict[str, list[dict]], path: Path) -> None:
    """Each policy's training curve. No reference line: the curves are episodes of the training
    distribution (random scenarios), and a reference from the evaluated mission belongs to another problem."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for m, rows in curves.items():
        x = np.array([r["episodes"] for r in rows])
        y = np.array([r["charts/coverage"] for r in rows])
        k = 5
        ys = np.convolve(y, np.ones(k) / k, mode="valid") if len(y) >= k else y
        ax.plot(x[len(x) - len(ys):], ys, label=m, color=COLOURS.get(m))
        ax.plot(x, y, alpha=0.2, color=ax.lines[-1].get_color())
    ax.set_xlabel("training episode")
    ax.set_ylabel("coverage C (stochastic policy, training episodes)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Training convergence (Fig. 3a)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def load_curves(loaded: dict) -> dict[str, list[dict]]:
    curves = {}
    for m, lp in loaded.items():
        f = Path(lp.directory) / "curve.jsonl"
        if f.is_file():
            curves[m] = [json.loads(x) for x in f.read_text().splitlines() if x.strip()]
    return curves


def failures_text(mission, failure_prob: float) -> str:  # noqa: ANN001 - Mission
    """What failed in these episodes: the mission's scripted node failures, and the random one
    of the training curriculum (`failure_prob`), told apart."""
    from plmarl_sitl.model.events import EventSchedule

    scripted = [f"UAV {e.uav} at t = {e.at_s:g} s" for e in EventSchedule.of(mission).events if e.type == "node_failure"]
    said = f"scripted node failures: {', '.join(scripted)}" if scripted else "no scripted node failure"
    return said + (f"; and a random node failure at t = 100 s with probability {failure_prob:g} per episode"
                   if failure_prob > 0 else "; no random failure")


def results_markdown(res: dict, figs_rel: dict[str, str], command: str, failures: str | None = None) -> str:
    ex = res["extra"]
    failures = failures or f"random failure probability {ex['failure_prob']}"
    parts = [
        f"Command: `{command}`",
        "",
        f"Deterministic policies, {ex['episodes']} paired episodes per cell (same twin seeds for every method), "
        f"{failures}. Coverage = mean C(t) for t > {ex['from_s']} s "
        "(steady state), mean [95% CI]; in brackets the mean per-episode fraction of the best reference's coverage on the "
        "same episodes (per episode the best of greedy, clairvoyant and service among the methods run; "
        "plmarl_sitl/learning/eval/references.py). No reference is a proven bound.",
        "",
        best_reference_md(res),
        "",
        coverage_table_md(res),
        "",
        "Whole-episode mean coverage (t = 1..200 s, includes the fly-out from the launch line):",
        "",
        full_table_md(res),
        "",
        "Mean algebraic connectivity lambda_2 (weighted comm graph, same window):",
        "",
        lambda_table_md(res),
    ]
    if res["p_values"]:
        parts += ["", "PL-MARL vs each method, per-episode coverage on the same episodes: two-sided Mann-Whitney U p / "
                  "paired Wilcoxon signed-rank p (episodes PL-MARL wins / loses):", "", pvalue_table_md(res)]
    for title, rel in figs_rel.items():
        parts += ["", f"![{title}]({rel})"]
    return "\n".join(parts) + "\n"


def splice_section(md_path: Path, heading_prefix: str, body: str, marker: str = "eval") -> None:
    """Replace the block between <!-- {marker}:begin --> and <!-- {marker}:end --> inside the
    section whose heading starts with `heading_prefix` (appending the block if absent)."""
    text = md_path.read_text() if md_path.is_file() else ""
    begin, end = f"<!-- {marker}:begin -->", f"<!-- {marker}:end -->"
    block = f"{begin}\n{body}{end}\n"
    if begin in text and end in text:
        a, b = text.index(begin), text.index(end) + len(end)
        text = text[:a] + block.rstrip("\n") + text[b:]
    else:
        lines = text.splitlines(keepends=True)
        idx = next((i for i, ln in enumerate(lines) if ln.startswith(heading_prefix)), None)
        if idx is None:
            text = text.rstrip("\n") + f"\n\n{heading_prefix}\n\n{block}"
        else:
            j = next((k for k in range(idx + 1, len(lines)) if lines[k].startswith("## ")), len(lines))
            body_lines = [ln for ln in lines[idx + 1 : j] if ln.strip() != "(pending)"]
            lines[idx + 1 : j] = body_lines + ["\n", block, "\n"]
            text = "".join(lines)
    md_path.write_text(text)


def write_outputs(res: dict, mission, loaded: dict, out: Path, results_md: str | None, args) -> None:  # noqa: ANN001
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(res, indent=1))
    plot_coverage_vs_tup(res, out / "coverage_vs_tup.png")
    curves = load_curves(loaded)
    figs = {"Coverage vs T_up": "coverage_vs_tup.png"}
    if curves:
        plot_training_curves(curves, out / "training_curves.png")
        figs["Training curves"] = "training_curves.png"
    command = res["extra"].get("command") or "plmarl " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    (out / "results.md").write_text(results_markdown(res, figs, command, failures_text(mission, res["extra"]["failure_prob"])))
    if results_md:
        md = Path(results_md)
        try:
            rel = {k: str((out / v).resolve().relative_to(md.resolve().parent)) for k, v in figs.items()}
        except ValueError:
            rel = {k: str((out / v).resolve()) for k, v in figs.items()}
        splice_section(md, "## Learning", results_markdown(res, rel, command))


def print_tables(res: dict) -> None:
    from rich.table import Table

    from plmarl_sitl.cmdline import table_console

    rows = _rows_by(res)
    t = Table(title=f"coverage (t > {res['extra']['from_s']} s), deterministic, {res['extra']['episodes']} episodes")
    for c in ("method", "T_up", "coverage", "95% CI", "of best ref.", "best reference", "full episode", "lambda2", "PL-MARL vs: MWU p / paired p (w/l)"):
        t.add_column(c)
    pv = {(p["versus"], p["tup"]): _p_cell(p) for p in res["p_values"]}
    for (m, tup), r in rows.items():
        frac = f"{100 * r['fraction_of_best_mean']:.0f}%" if "fraction_of_best_mean" in r else "-"
        p = pv.get((m, tup), "-")
        t.add_row(m, str(tup), f"{r['coverage_mean']:.3f}", f"[{r['coverage_ci95'][0]:.3f}, {r['coverage_ci95'][1]:.3f}]",
                  frac, r.get("best_reference", "-"), f"{r['coverage_full_mean']:.3f}", f"{r['lambda2_mean']:.2f}", p)
    console = table_console()
    console.print(t)
    from plmarl_sitl.learning.eval.references import ABOUT

    for m in dict.fromkeys(m for m, _ in rows):
        if m in ABOUT:
            console.print(f"reference {m}: {ABOUT[m]}")
