"""Session 19 summary table from `plmarl suite ... --out DIR/FAMILY` runs (one dir per family).

usage: python table.py OUT.md DIR [DIR ...]   (each DIR holds FAMILY/results.json)
Per family and T_up: coverage of every method, the fraction of the best reference (per
episode, the suite's own figure) for service and pl-marl, the best reference, and p
(two-sided Mann-Whitney U, the suite's) of PL-MARL against service and dead-reckoning.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

METHODS = ["service", "service-greedy", "greedy", "clairvoyant", "pl-marl", "dead-reckoning"]


def rows(run_dir: Path) -> list[str]:
    out = []
    for res in sorted(run_dir.glob("*/results.json")):
        d = json.loads(res.read_text())
        by = {(r["family"], r["tup"], r["method"]): r for r in d["rows"]}
        for fam in d["families"]:
            for tup in fam["tup"]:
                cov = " / ".join(f"{by[(fam['name'], tup, m)]['coverage_mean']:.4f}" if (fam["name"], tup, m) in by else "-"
                                 for m in METHODS)
                svc, plm = by[(fam["name"], tup, "service")], by[(fam["name"], tup, "pl-marl")]
                p = {(r["versus"]): r["p"] for r in d["p_values"] if r["family"] == fam["name"] and r["tup"] == tup}
                miss = min(svc["fraction_of_best_mean"], plm["fraction_of_best_mean"]) < 0.92
                out.append(
                    f"| {fam['name']} | {d['seed']} | {tup} | {cov} | {svc['fraction_of_best_mean']:.3f} | "
                    f"{plm['fraction_of_best_mean']:.3f} | {svc['best_reference']} ({svc['best_reference_coverage_mean']:.4f}) | "
                    f"{p.get('service', float('nan')):.2g} | {p.get('dead-reckoning', float('nan')):.2g} | "
                    f"{'**MISS**' if miss else 'ok'} |")
    return out


def main() -> None:
    head = ("| family | seed | T_up | coverage: " + " / ".join(METHODS) + " | frac. best, service | frac. best, pl-marl "
            "| best reference (coverage) | p pl-marl vs service | p vs dead-reckoning | >= 0.92 |\n"
            "|---|---|---|---|---|---|---|---|---|---|")
    body = [r for d in sys.argv[2:] for r in rows(Path(d))]
    text = head + "\n" + "\n".join(body) + "\n"
    Path(sys.argv[1]).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
