"""Tables and plots of a suite run: results.md and the Fig. 3b / 4b / 5a / 5b style PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from plmarl_sitl.learning.eval.report import COLOURS, comparison_text
from plmarl_sitl.learning.eval.transient import PLATEAU_FRACTION, WINDOW_S

SUMMARY_METHODS = ("pl-marl", "tag-mappo", "gru", "dead-reckoning", "service")
REFERENCE_COLUMNS = ("greedy", "clairvoyant")  # service is a method column too


def _pct(row: dict, key: str = "fraction_of_best_mean") -> str:
    return f"{100 * row[key]:.0f}%" if key in row else "-"


def _vs_cell(row: dict) -> str:
    """PL-MARL against the row's method (`suite.summarise` writes all three figures or none)."""
    if "p_pl_marl_vs" not in row:
        return "-"
    wins, losses = row["pl_marl_wins_losses"]
    return comparison_text({"p": row["p_pl_marl_vs"], "p_paired": row["p_paired_pl_marl_vs"], "wins": wins, "losses": losses})


def references_text(res: dict) -> str:
    """What each reference of the run is, and how the fractions are taken."""
    about = res.get("reference_about", {})
    if not about:
        return "No reference method in this run: no fractions."
    lines = ["References (none is a proven bound; a reference a method beats is not a ceiling):", ""]
    lines += [f"* `{k}`: {v}" for k, v in about.items()]
    lines += ["", "'of best' = mean per-episode ratio to the best reference of that episode (the one among "
              f"{', '.join(about)} with the highest coverage on it); 'best reference' = the mean of that per-episode "
              "best, and which reference it was how often."]
    return "\n".join(lines)


def summary_table_md(res: dict) -> str:
    """Family x T_up: each method's coverage and its share of the best reference, the references."""
    methods = [m for m in SUMMARY_METHODS if m in res["methods"]]
    refs = [m for m in REFERENCE_COLUMNS if m in res["methods"]]
    best = {(b["family"], b["tup"]): b for b in res.get("references", [])}
    head = ["family", "N", "T_up (s)"] + methods + refs + (["best reference"] if best else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    by = {(r["family"], r["tup"], r["method"]): r for r in res["rows"]}
    for fam in res["families"]:
        for tup in fam["tup"]:
            cells = [fam["name"], "/".join(map(str, fam["n_uavs"])), str(tup)]
            for m in methods + refs:
                r = by[(fam["name"], tup, m)]
                cells.append(f"{r['coverage_mean']:.3f} ({_pct(r)})" if best else f"{r['coverage_mean']:.3f}")
            if best:
                b = best[(fam["name"], tup)]
                cells.append(f"{b['coverage_mean']:.3f} ({b['best']})")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def family_table_md(res: dict, family: str) -> str:
    lines = ["| T_up (s) | method | coverage [95% CI] | of best reference [95% CI] | best reference | full episode "
             "| lambda_2 [95% CI] | PL-MARL vs: MWU p / paired p (wins/losses) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in (r for r in res["rows"] if r["family"] == family):
        frac = (f"{100 * r['fraction_of_best_mean']:.1f}% [{100 * r['fraction_of_best_ci95'][0]:.1f}, "
                f"{100 * r['fraction_of_best_ci95'][1]:.1f}]") if "fraction_of_best_mean" in r else "-"
        p = _vs_cell(r)
        lines.append(
            f"| {r['tup']} | {r['method']} | {r['coverage_mean']:.3f} [{r['coverage_ci95'][0]:.3f}, {r['coverage_ci95'][1]:.3f}] "
            f"| {frac} | {r.get('best_reference', '-')} | {r['coverage_full_mean']:.3f} | {r['lambda2_mean']:.2f} [{r['lambda2_ci95'][0]:.2f}, "
            f"{r['lambda2_ci95'][1]:.2f}] | {p} |"
        )
    return "\n".join(lines)


def transient_table_md(res: dict) -> str:
    def med(v: float | None) -> str:
        return "never" if v is None else f"{v:.0f}"

    lines = ["| family | T_up (s) | method | pre-failure | trough [95% CI] | post-failure (of best reference) | reference level "
             "| from 30 s (of best reference) | reach s (median) | reached by 30 s | plateau s (median) | settled by 30 s | never settled |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for t in res["transients"]:
        lines.append(
            f"| {t['family']} | {t['tup']} | {t['method']} | {t['pre_failure_mean']:.3f} | {t['trough_mean']:.3f} "
            f"[{t['trough_ci95'][0]:.3f}, {t['trough_ci95'][1]:.3f}] | {t['post_failure_mean']:.3f} "
            f"({100 * t['post_failure_fraction_of_reference_mean']:.0f}%) | {t['reference_post_level_mean']:.3f} "
            f"| {100 * t.get('after_target_fraction_of_reference_mean', float('nan')):.1f}% "
            f"| {med(t['reach_s_median'])} | {100 * t['reach_within_target_share']:.0f}% | {med(t['plateau_s_median'])} "
            f"| {100 * t['plateau_within_target_share']:.0f}% | {t['plateau_never']} |"
        )
    return "\n".join(lines)


def results_markdown(res: dict, figures: dict[str, str]) -> str:
    parts = [
        f"Command: `{res.get('command', '')}`", "",
        f"Deterministic policies; {res['episodes']} episodes per family and T_up, the same episodes for every method "
        f"(twin seeds {res['eval_seed_base']} + {res['seed']} x 10000 + 100 x mission + batch: the evaluation range, "
        "disjoint from every training seed). Coverage = mean C(t) for t > "
        f"{res['from_s']} s; lambda_2 = mean "
        "algebraic connectivity of the weighted comm graph over the same window; PL-MARL vs: the two-sided "
        "Mann-Whitney U p of PL-MARL's per-episode coverage against the row's method (unpaired), then the two-sided "
        "Wilcoxon signed-rank p of the per-episode differences (paired: every method flies the same episodes), then "
        "the episodes PL-MARL wins / loses.", "",
        references_text(res), "",
        "## Summary: coverage (share of the best reference)", "", summary_table_md(res), "",
    ]
    for fam in res["families"]:
        parts += [f"## {fam['name']}: {fam['about']}", "",
                  f"Missions: {', '.join(fam['missions'])} (episodes each: {fam['episodes_per_mission']}); "
                  f"failure probability {fam['failure_prob']}.", "", family_table_md(res, fam["name"]), ""]
    if res["transients"]:
        parts += ["## Failure transient", "",
                  "Per episode (definitions in plmarl_sitl/learning/eval/transient.py): trough = min C(t) from the "
                  "failure on; reference level = the best reference's mean C over the second half of the post-failure time on the "
                  f"same episode; reach = first s after the failure whose {WINDOW_S}-s mean of C is at least "
                  f"{100 * PLATEAU_FRACTION:.0f}% of that level; plateau = first s from which every later {WINDOW_S}-s "
                  "mean stays there (settling time). Medians over episodes; 'by 30 s' = share of episodes.", "",
                  transient_table_md(res), ""]
    for title, rel in figures.items():
        parts += [f"![{title}]({rel})", ""]
    return "\n".join(parts)


# ---------------------------------------------------------------------- plots
def _plt():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:  # noqa: ANN001 - a matplotlib Figure
    """Every suite figure: tight layout, 110 dpi PNG, then free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)


def plot_coverage_vs_tup(res: dict, path: Path) -> None:
    """Fig. 3b per family: coverage (95% CI band) against T_up, one panel per family."""
    plt = _plt()
    fams = res["families"]
    cols = min(3, len(fams))
    rows = int(np.ceil(len(fams) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, fam in zip(axes.flat, fams, strict=False):
        for m in res["methods"]:
            rs = sorted((r for r in res["rows"] if r["family"] == fam["name"] and r["method"] == m), key=lambda r: r["tup"])
            x = [r["tup"] for r in rs]
            y = np.array([r["coverage_mean"] for r in rs])
            c = COLOURS.get(m)
            ax.plot(x, y, marker="o", ms=3, label=m, color=c, ls="--" if m in REFERENCE_COLUMNS else "-")
            ax.fill_between(x, [r["coverage_ci95"][0] for r in rs], [r["coverage_ci95"][1] for r in rs], alpha=0.2, color=c)
        ax.set_title(f"{fam['name']} (N = {'/'.join(map(str, fam['n_uavs']))})", fontsize=9)
        ax.set_xticks(fam["tup"])
        ax.set_xlabel("T_up (s)")
        ax.set_ylabel("coverage")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(fams):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"Held-out suite: coverage vs T_up (t > {res['from_s']} s, {res['episodes']} episodes)", fontsize=10)
    _save(fig, path)


def plot_coverage_vs_n(res: dict, scaling: list[str], path: Path) -> bool:
    """Fig. 4b: coverage and share of the best reference against N for the scaling families."""
    fams = [f for f in res["families"] if f["name"] in scaling and len(f["n_uavs"]) == 1]
    if len(fams) < 2:
        return False
    common = set.intersection(*(set(f["tup"]) for f in fams))
    if not common:
        return False
    tup = 15 if 15 in common else min(common)
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6))
    ns = [f["n_uavs"][0] for f in fams]
    by = {(r["family"], r["method"]): r for r in res["rows"] if r["tup"] == tup}
    for m in res["methods"]:
        rs = [by[(f["name"], m)] for f in fams]
        c = COLOURS.get(m)
        a1.errorbar(ns, [r["coverage_mean"] for r in rs], yerr=np.abs(np.array([r["coverage_ci95"] for r in rs]).T
                    - [r["coverage_mean"] for r in rs]), marker="o", ms=3, capsize=2, label=m, color=c,
                    ls="--" if m in REFERENCE_COLUMNS else "-")
        if m not in REFERENCE_COLUMNS and "fraction_of_best_mean" in rs[0]:
            a2.plot(ns, [r["fraction_of_best_mean"] for r in rs], marker="o", ms=3, label=m, color=c)
    a1.set_ylabel("coverage")
    a2.set_ylabel("fraction of the best reference")
    for ax in (a1, a2):
        ax.set_xlabel("swarm size N (trained at N = 4)")
        ax.set_xticks(ns)
        ax.set_ylim(0, 1.05)
        ax.grid(alpha=0.3)
    a1.legend(fontsize=7)
    fig.suptitle(f"Zero-shot scaling ({', '.join(f['name'] for f in fams)}), T_up = {tup} s", fontsize=10)
    _save(fig, path)
    return True


def plot_failure_transient(res: dict, path: Path) -> bool:
    """Fig. 5a: mean C(t) of each method on each failure family's episodes (one panel per family)."""
    if not res["transients"]:
        return False
    panels = {(t["family"], t["tup"]): t["failure_at_s"] for t in res["transients"]}
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 3.8), squeeze=False)
    for ax, ((fam, tup), fail_s) in zip(axes[0], panels.items(), strict=True):
        traces = res["traces"][fam]
        for m in res["methods"]:
            y = np.array(traces[f"{m}@{tup}"])
            ax.plot(np.arange(1, y.size + 1), y, label=m, color=COLOURS.get(m), ls="--" if m in REFERENCE_COLUMNS else "-", lw=1.2)
        ax.axvline(fail_s, color="k", lw=0.8, ls=":")
        ax.text(fail_s + 2, 0.05, "node failure", fontsize=8)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("coverage C(t), mean over episodes")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax.set_title(f"Failure transient ({fam}, T_up = {tup} s, {res['episodes']} episodes)", fontsize=10)
    _save(fig, path)
    return True


def plot_lambda2(res: dict, path: Path) -> None:
    """Fig. 5b: steady-state lambda_2 per family and method (95% CI), at T_up 15 where run."""
    plt = _plt()
    fams = res["families"]
    methods = res["methods"]
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(fams) + 2), 3.8))
    width = 0.8 / len(methods)
    by = {(r["family"], r["tup"], r["method"]): r for r in res["rows"]}
    for k, m in enumerate(methods):
        ys, errs = [], []
        for f in fams:
            tup = 15 if 15 in f["tup"] else f["tup"][0]
            r = by[(f["name"], tup, m)]
            ys.append(r["lambda2_mean"])
            errs.append([r["lambda2_mean"] - r["lambda2_ci95"][0], r["lambda2_ci95"][1] - r["lambda2_mean"]])
        x = np.arange(len(fams)) + (k - (len(methods) - 1) / 2) * width
        ax.bar(x, ys, width, yerr=np.array(errs).T, capsize=1.5, label=m, color=COLOURS.get(m))
    ax.set_xticks(np.arange(len(fams)), [f["name"] for f in fams], fontsize=8)
    ax.set_ylabel("mean lambda_2 (t > from_s)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=7)
    ax.set_title("Algebraic connectivity of the comm graph (T_up = 15 s where run)", fontsize=10)
    _save(fig, path)


def write_outputs(res: dict, scaling: list[str], out: Path) -> dict[str, str]:
    """results.json, results.md and the PNGs into `out`; returns {title: file}."""
    out.mkdir(parents=True, exist_ok=True)
    figures = {"Coverage vs T_up per family": "coverage_vs_tup.png"}
    plot_coverage_vs_tup(res, out / "coverage_vs_tup.png")
    if plot_coverage_vs_n(res, scaling, out / "coverage_vs_n.png"):
        figures["Coverage vs N"] = "coverage_vs_n.png"
    if plot_failure_transient(res, out / "failure_transient.png"):
        figures["Failure transient"] = "failure_transient.png"
    plot_lambda2(res, out / "lambda2.png")
    figures["lambda_2"] = "lambda2.png"
    (out / "results.json").write_text(json.dumps(res, indent=1))
    (out / "results.md").write_text(results_markdown(res, figures))
    return figures


def print_summary(res: dict) -> None:
    from rich.table import Table

    from plmarl_sitl.cmdline import table_console

    t = Table(title=f"held-out suite, coverage t > {res['from_s']} s, {res['episodes']} episodes per cell")
    for c in ("family", "T_up", "method", "coverage", "95% CI", "of best ref.", "best reference", "lambda2", "PL-MARL vs: MWU p / paired p (w/l)"):
        t.add_column(c)
    for r in res["rows"]:
        p = _vs_cell(r)
        t.add_row(r["family"], str(r["tup"]), r["method"], f"{r['coverage_mean']:.3f}",
                  f"[{r['coverage_ci95'][0]:.3f}, {r['coverage_ci95'][1]:.3f}]", _pct(r), r.get("best_reference", "-"),
                  f"{r['lambda2_mean']:.2f}", p)
    console = table_console()
    console.print(t)
    for b in res.get("references", []):
        wins = ", ".join(f"{k} in {100 * v:.0f}%" for k, v in b["wins"].items() if k.startswith("clairvoyant>"))
        console.print(f"{b['family']} T_up {b['tup']}: best reference {b['coverage_mean']:.3f} ({b['best']})"
                      + (f"; {wins} of episodes" if wins else ""))
    for k, v in res.get("reference_about", {}).items():
        console.print(f"reference {k}: {v}")
