"""Any two methods of a suite run against each other (`plmarl suite --compare A,B`), per family
and T_up, from the per-episode values the result document keeps.

Why: the suite compares every method with PL-MARL only, but a study often asks another pair (an
option against the default, a method against `service`). Every method flies the same episodes
in the same order, so the pair is compared on them: the paired Wilcoxon test, Mann-Whitney U,
wins and losses (`stats.compare`), over the steady-state window (t > from_s) and, on failure
families, from TARGET_S after the failure (issue 24's window)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.report import comparison_text
from plmarl_sitl.learning.eval.stats import compare
from plmarl_sitl.learning.eval.transient import TARGET_S


def parse_pair(text: str) -> tuple[str, str]:
    """'A,B' -> (A, B): two different method names."""
    pair = [m.strip() for m in text.split(",")]
    if len(pair) != 2 or not all(pair) or pair[0] == pair[1]:
        raise UserError(f"--compare takes two different methods, 'A,B' (got {text!r})")
    return pair[0], pair[1]


def load_results(path: Path) -> dict:
    """A suite result document: results.json, or the directory `--out` wrote it to."""
    file = path / "results.json" if path.is_dir() else path
    try:
        return json.loads(file.read_text())
    except FileNotFoundError:
        raise UserError(f"no suite results at {file} (give results.json or the --out directory)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UserError(f"{file} is not a suite result document: {e}") from None


def _pair(a: list[float | None], b: list[float | None]) -> tuple[np.ndarray, np.ndarray]:
    """The episodes both values exist for (an episode ending before the window has none)."""
    x, y = np.array(a, dtype=np.float64), np.array(b, dtype=np.float64)
    both = np.isfinite(x) & np.isfinite(y)
    return x[both], y[both]


def compare_methods(res: dict, a: str, b: str) -> list[dict]:
    """One row per (family, T_up) of res: a against b, steady state and after the failure."""
    missing = [m for m in (a, b) if m not in res.get("methods", [])]
    if missing:
        raise UserError(f"method {missing[0]!r} is not in this run (it ran: {', '.join(res.get('methods', []))})")
    if any("coverage_per_episode" not in r for r in res["rows"]):
        raise UserError("this result document keeps no per-episode values (written before they were kept): "
                        "run the suite again to compare two methods")
    rows = {(r["family"], r["tup"], r["method"]): r for r in res["rows"]}
    after = {(t["family"], t["tup"], t["method"]): t["after_target_per_episode"]
             for t in res.get("transients", []) if "after_target_per_episode" in t}
    out = []
    for fam, tup in dict.fromkeys((r["family"], r["tup"]) for r in res["rows"]):
        x, y = _pair(rows[(fam, tup, a)]["coverage_per_episode"], rows[(fam, tup, b)]["coverage_per_episode"])
        row = {"family": fam, "tup": tup, "a": a, "b": b, "episodes": int(x.size),
               "a_mean": float(x.mean()), "b_mean": float(y.mean()), "difference": float((x - y).mean()), **compare(x, y)}
        if (fam, tup, a) in after and (fam, tup, b) in after:
            xa, ya = _pair(after[(fam, tup, a)], after[(fam, tup, b)])
            if xa.size:
                row["after_failure"] = {"a_mean": float(xa.mean()), "b_mean": float(ya.mean()),
                                        "difference": float((xa - ya).mean()), **compare(xa, ya)}
        out.append(row)
    return out


def comparison_md(res: dict, rows: list[dict]) -> str:
    """The rows as a markdown table: means, difference and 'MWU p / paired p (wins/losses)'."""
    a, b = rows[0]["a"], rows[0]["b"]
    lines = [f"`{a}` against `{b}` on the same episodes (suite seed {res.get('seed')}); coverage t > {res.get('from_s')} s, "
             f"and from {TARGET_S} s after the failure on failure families; tests: Mann-Whitney p / paired Wilcoxon p "
             f"(episodes {a} wins / loses)", "",
             f"| family | T_up | episodes | {a} | {b} | difference | tests | after failure: {a} | {b} | difference | tests |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [r["family"], str(r["tup"]), str(r["episodes"]), f"{r['a_mean']:.4f}", f"{r['b_mean']:.4f}",
                 f"{r['difference']:+.4f}", comparison_text(r)]
        f = r.get("after_failure")
        cells += ([f"{f['a_mean']:.4f}", f"{f['b_mean']:.4f}", f"{f['difference']:+.4f}", comparison_text(f)]
                  if f else ["-"] * 4)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
