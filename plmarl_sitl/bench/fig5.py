"""The letter's Fig. 5a/5b on the failure families: C(t) and lambda_2(t), twin beside SITL.

For each mission (a failure family: two of six failing, a failure in transit, a failure that
splits the swarm, ...) one seed is flown twice with the same policy: in the twin and in a
lockstep SITL swarm (real agents, real broker, emulated vehicles; `bench.gap`'s runs). The
figure has one column per mission: coverage over time on top (Fig. 5a, the failure
transient) and the algebraic connectivity of the communication graph below (Fig. 5b), each
node failure marked. Lockstep makes the SITL side independent of the machine's load, so the
twin and SITL curves should lie on each other; where they part is the sim-to-SITL gap.

    python -m plmarl_sitl.bench.fig5 missions/suite/failure_2of6_a.yaml \\
        missions/suite/failure_transit.yaml missions/suite/failure_split.yaml \\
        --seed 0 --policy policies/service --out docs/results/fig5
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

from plmarl_sitl.bench.gap import START_WALL_S, sitl_coverage, twin_series
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.errors import UserError, run_reporting
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.model.events import EventSchedule

PROG = "python -m plmarl_sitl.bench.fig5"


def failure_seconds(mission: Mission) -> list[float]:
    """When the mission's node failures happen (the failure families' own)."""
    return sorted({e.at_s for e in EventSchedule.of(mission).events if e.type == "node_failure"})


def fly(mission_path: str, policy: str, seed: int, speedup: float, start_wall_s: float) -> dict:
    """One mission's twin and lockstep-SITL series."""
    mission = load_mission(mission_path)
    t = time.perf_counter()
    twin_cov, twin_lam = twin_series(mission, policy, seed, lambda2=True)
    sitl_cov, info = asyncio.run(sitl_coverage(mission_path, policy, seed, speedup=speedup, lockstep=True,
                                               start_wall_s=start_wall_s))
    return {"mission": mission.name, "path": mission_path, "seed": seed, "policy": policy,
            "failures_s": failure_seconds(mission),
            "twin": {"coverage": twin_cov, "lambda2": twin_lam},
            "sitl": {"coverage": sitl_cov, "lambda2": info["lambda2"]},
            "gap": sum(sitl_cov) / max(1, len(sitl_cov)) - sum(twin_cov) / max(1, len(twin_cov)),
            "wall_s": time.perf_counter() - t}


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(rows), figsize=(5.2 * len(rows), 6.4), squeeze=False, sharex="col")
    for col, r in enumerate(rows):
        for row, key, label in ((0, "coverage", "coverage C(t)"), (1, "lambda2", "lambda_2(t)")):
            ax = axes[row][col]
            for side, style in (("twin", "-"), ("sitl", "--")):
                y = r[side][key]
                ax.plot(range(1, len(y) + 1), y, style, lw=1.2, label=f"{side}" + (" (lockstep)" if side == "sitl" else ""))
            for s in r["failures_s"]:
                ax.axvline(s, color="k", lw=0.8, ls=":")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_ylim(0, 1.02)
                ax.set_title(f"{r['mission']} (seed {r['seed']}, gap {r['gap']:+.4f})", fontsize=9)
                ax.legend(fontsize=7, loc="lower right")
            else:
                ax.set_xlabel("t (s); dotted: node failures")
    fig.suptitle(f"Fig. 5a/5b on failure families: twin vs SITL, policy {Path(rows[0]['policy']).name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n\n")[0],
        epilog="example:\n  " + __doc__.split("\n\n")[-1].strip().replace("\n    ", "\n  "),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("missions", nargs="+", help="mission YAML files, one figure column each")
    p.add_argument("--policy", default=str(PROJECT_POLICIES / "service"),
                   help="policy directory flown on both sides (default: the project's policies/service)")
    p.add_argument("--seed", type=int, default=0, help="the episode's seed (users, channel), the same on both sides")
    p.add_argument("--speedup", type=float, default=10.0, help="pace of the SITL start-up (lockstep runs as fast as the agents)")
    p.add_argument("--start-wall-s", type=float, default=START_WALL_S, help="wall seconds the vehicles get to be ready")
    p.add_argument("--out", type=Path, default=Path("runs/fig5"), help="writes fig5.png and fig5.json there")
    args = p.parse_args(argv)
    return run_reporting(PROG, lambda: draw(args))


def draw(args: argparse.Namespace) -> int:
    for m in args.missions:
        if not Path(m).is_file():
            raise UserError(f"no mission file {m}")
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"{PROG}: seed {args.seed}, policy {args.policy}", file=sys.stderr)
    rows = []
    for m in args.missions:
        rows.append(fly(m, args.policy, args.seed, args.speedup, args.start_wall_s))
        r = rows[-1]
        print(f"{r['mission']}: twin {sum(r['twin']['coverage']) / len(r['twin']['coverage']):.4f}, gap {r['gap']:+.4f} "
              f"({r['wall_s']:.0f} s wall)", file=sys.stderr, flush=True)
    (args.out / "fig5.json").write_text(json.dumps(rows))
    plot(rows, args.out / "fig5.png")
    print(args.out / "fig5.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
