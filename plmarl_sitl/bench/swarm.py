"""`plmarl bench swarm`: wall time of the 200 s paper mission flown as a SITL swarm.

For each N it tries speedups from high to low and keeps the first whose sim-to-SITL
coverage gap is within `--max-gap` (0.03): |mean C(t) in SITL - mean C(t) in the twin|
for the same mission, seeds (means over `--seeds`) and policy (the twin run is
`bench.gap.twin_coverage`), and that kept up with its speedup: 95% of decisions acted
within `--max-delay` vehicle seconds of their mission second (the twin acts at once)
and on sensing at most `--max-lag` seconds old. An overloaded swarm backs up its bus and acts late; with a
poor policy that need not move the coverage gap, so the gap alone cannot tell.
N = 20 is the zero-shot mission `missions/scale_20.yaml` (20 clusters in the same 1 km^2).

With `--lockstep` it then flies each seed in lockstep (`plmarl swarm up --lockstep`: never
late by construction, so only the gap is judged) and the first seed twice, and reports
the lockstep wall time next to the best on-time free-running one, the lockstep coverage
gap, and whether the two runs' outputs (metrics.jsonl, events.jsonl, the summary without
its run directory) hash the same.

Every row also gives the mission's own wall time (second 0 to the last) and the speedup
achieved over it: a free-running world that cannot keep its --speedup falls behind
(bounded catch-up), so on a loaded machine the nominal speedup overstates the pace.
Every row also says what share of the telemetry (at the rate each asked for) the agents answered after the
start ("answered"): a free-running agent that falls behind skips to the newest sample,
which keeps it on time by the criteria above while it does less work per vehicle second
than a lockstep one, which answers all of them.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from plmarl_sitl.cmdline import comma_list
from plmarl_sitl.config import PAPER_MISSION, PROJECT_MISSIONS, PROJECT_POLICIES
from plmarl_sitl.machine import machine_info

MISSIONS = {4: str(PAPER_MISSION), 20: str(PROJECT_MISSIONS / "scale_20.yaml")}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", default="4,20", type=comma_list(int, "swarm size", choices=sorted(MISSIONS)),
                   help="swarm sizes to measure (4 and/or 20; default 4,20)")
    p.add_argument("--speedups", default="20,15,10,5,2", type=comma_list(float, "speedup", positive=True), help="speedups to try, high to low (default 20,15,10,5,2)")
    p.add_argument("--max-gap", type=float, default=0.03, help="largest acceptable coverage gap (default 0.03)")
    p.add_argument("--max-lag", type=float, default=3.0,
                   help="largest acceptable age of the sensing a decision used, mission s (default 3: one decision period)")
    p.add_argument("--max-delay", type=float, default=1.5,
                   help="largest acceptable 95th-percentile decision delay, vehicle s (default 1.5: half a decision period)")
    p.add_argument("--seeds", default="0,1,2", type=comma_list(int, "seed"),
                   help="mission seeds; the gap compares mean coverage over them, as one run's is noisy (default 0,1,2)")
    p.add_argument("--policy", default=str(PROJECT_POLICIES / "pl-marl"), help="policy directory (default: the project's policies/pl-marl)")
    p.add_argument("--broker", default="embedded", metavar="embedded|mosquitto",
                   help="the broker every run starts (default embedded amqtt)")
    p.add_argument("--lockstep", action="store_true",
                   help="also fly every seed in lockstep (and the first seed twice): wall time, gap, output hashes")


def _fly(mission_path: str, policy: str, speedup: float, seed: int, lockstep: bool = False,
         broker: str = "embedded") -> tuple[dict, float]:
    """(summary, wall seconds) of one headless run (the summary's run_dir has its outputs)."""
    from rich.console import Console

    from plmarl_sitl.sitl.launcher import swarm_up
    from plmarl_sitl.sitl.options import UpOptions

    out = Path(tempfile.mkdtemp(prefix="plmarl-bench-swarm-"))
    opts = UpOptions(Path(mission_path), speedup=speedup, headless=True, out=out, seed=seed, policy=Path(policy),
                     lockstep=lockstep, broker=broker)
    t0 = time.perf_counter()
    summary = asyncio.run(swarm_up(opts, console=Console(quiet=True)))
    return summary, time.perf_counter() - t0


def answered_share(run_dir: Path) -> float | None:
    """Telemetry samples the agents answered after the start, over mission seconds x the
    rate they asked for (from agents/*.stats.json); None without stats."""
    from plmarl_sitl.deploy.agent.session import TELEMETRY_HZ

    samples = expected = 0.0
    for f in (run_dir / "agents").glob("*.stats.json"):
        st = json.loads(f.read_text())
        samples += int(st.get("mission_samples", 0))
        expected += int(st.get("seconds", 0)) * float(st.get("telemetry_hz") or TELEMETRY_HZ)
    return samples / expected if expected else None


def _flown(flights: list[tuple[dict, float]]) -> dict:
    """What every row says of a set of runs (one per seed): means over them."""
    shares = [answered_share(Path(f[0]["run_dir"])) for f in flights]
    return {"wall_s": float(np.mean([f[1] for f in flights])),
            "sitl": float(np.mean([f[0]["coverage_mean"] for f in flights])),
            "sitl_by_seed": [f[0]["coverage_mean"] for f in flights],
            "mission_wall_s": float(np.mean([f[0]["mission_wall_s"] for f in flights])),
            "achieved_speedup": float(np.mean([f[0]["achieved_speedup"] for f in flights])),
            "answered": float(np.mean(shares)) if None not in shares else None}


def outputs_hash(run_dir: Path) -> str:
    """SHA-256 over a run's metrics.jsonl, events.jsonl and summary.json without run_dir."""
    summary = json.loads((run_dir / "summary.json").read_text())
    summary.pop("run_dir", None)
    h = hashlib.sha256()
    for part in ((run_dir / "metrics.jsonl").read_bytes(), (run_dir / "events.jsonl").read_bytes(),
                 json.dumps(summary, sort_keys=True).encode()):
        h.update(hashlib.sha256(part).digest())
    return h.hexdigest()


def _lockstep(path: str, policy: str, seeds: list[int], twin_mean: float, free_wall_s: float, free_mission_wall_s: float,
              broker: str) -> dict:
    """Every seed in lockstep, and the first one again: wall, gap, the two runs' hashes."""
    flights = [_fly(path, policy, 10.0, s, lockstep=True, broker=broker) for s in seeds]
    again = _fly(path, policy, 10.0, seeds[0], lockstep=True, broker=broker)
    f = _flown(flights)
    hashes = [outputs_hash(Path(fl[0]["run_dir"])) for fl in (flights[0], again)]
    return {"wall_s": f["wall_s"], "x_faster_than_free": free_wall_s / f["wall_s"], "sitl_coverage": f["sitl"],
            "mission_wall_s": f["mission_wall_s"], "achieved_speedup": f["achieved_speedup"],
            "coverage_gap": abs(f["sitl"] - twin_mean), "sitl_by_seed": f["sitl_by_seed"], "answered": f["answered"],
            "x_faster_than_free_mission": free_mission_wall_s / f["mission_wall_s"],
            "hash_runs": hashes, "identical": hashes[0] == hashes[1]}


def run(args: argparse.Namespace) -> dict:
    from dataclasses import replace

    from plmarl_sitl.bench.gap import twin_coverage
    from plmarl_sitl.mission import load_mission

    seeds = args.seeds
    rows = []
    for n in args.n:
        path = MISSIONS[n]
        twin = [float(np.mean(twin_coverage(replace(load_mission(path), seed=s), args.policy, s))) for s in seeds]
        twin_mean = float(np.mean(twin))
        tried = []
        for k in args.speedups:
            flights = [_fly(path, args.policy, k, s, broker=getattr(args, "broker", "embedded")) for s in seeds]
            flown = _flown(flights)
            on_time = [f[0]["timeliness"] for f in flights]
            lags = [t["sensing_age_s"]["max"] for t in on_time if t["sensing_age_s"]]
            delays = [t["decision_delay_s"]["p95"] for t in on_time if t["decision_delay_s"]]
            lag = max(lags) if len(lags) == len(seeds) else None
            delay = max(delays) if len(delays) == len(seeds) else None
            gap = abs(flown["sitl"] - twin_mean)
            ok = gap <= args.max_gap and lag is not None and lag <= args.max_lag and delay is not None and delay <= args.max_delay
            tried.append({"speedup": k, **flown, "coverage_gap": gap, "sensing_lag_max_s": lag,
                          "decision_delay_p95_s": delay, "ok": ok})
            if ok:
                break
        best = tried[-1]
        rows.append({"n": n, "speedup": best["speedup"], "wall_s": best["wall_s"], "coverage_gap": best["coverage_gap"],
                     "mission_wall_s": best["mission_wall_s"], "achieved_speedup": best["achieved_speedup"],
                     "twin_coverage": twin_mean, "twin_by_seed": twin, "sitl_coverage": best["sitl"],
                     "sensing_lag_max_s": best["sensing_lag_max_s"], "decision_delay_p95_s": best["decision_delay_p95_s"],
                     "answered": best["answered"], "ok": best["ok"], "tried": tried})
        if getattr(args, "lockstep", False):
            rows[-1]["lockstep"] = _lockstep(path, args.policy, seeds, twin_mean, best["wall_s"], best["mission_wall_s"],
                                             args.broker)
    return {"rows": rows, "machine": machine_info(), "seeds": seeds, "broker": getattr(args, "broker", "embedded")}


def print_table(res: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"200 s mission as a SITL swarm ({res['machine']}, seeds {res['seeds']}; wall = mean per run)")
    for col in ("N", "speedup", "achieved", "wall", "twin C", "SITL C", "gap", "delay p95", "sensing age", "answered", "ok"):
        t.add_column(col, justify="right")
    for r in res["rows"]:
        t.add_row(str(r["n"]), f"{r['speedup']:g}x", f"{r['achieved_speedup']:.1f}x", f"{r['wall_s']:.1f} s",
                  f"{r['twin_coverage']:.3f}",
                  f"{r['sitl_coverage']:.3f}", f"{r['coverage_gap']:.3f}", f"{r['decision_delay_p95_s']} s", f"{r['sensing_lag_max_s']} s",
                  _pct(r["answered"]), "yes" if r["ok"] else "no")
    Console().print(t)
    if any("lockstep" in r for r in res["rows"]):
        lt = Table(title="the same missions in lockstep (--lockstep), next to the best on-time free-running speedup above")
        for col in ("N", "free wall (mission)", "lockstep wall (mission)", "x faster (mission)", "achieved", "SITL C", "gap",
                    "answered", "2 runs identical", "hash"):
            lt.add_column(col, justify="right")
        for r in res["rows"]:
            ls = r.get("lockstep")
            if ls is not None:
                lt.add_row(str(r["n"]), f"{r['wall_s']:.1f} s ({r['mission_wall_s']:.1f} s)",
                           f"{ls['wall_s']:.1f} s ({ls['mission_wall_s']:.1f} s)",
                           f"{ls['x_faster_than_free']:.2f} ({ls['x_faster_than_free_mission']:.2f})", f"{ls['achieved_speedup']:.1f}x",
                           f"{ls['sitl_coverage']:.3f}", f"{ls['coverage_gap']:.3f}", _pct(ls["answered"]),
                           "yes" if ls["identical"] else "no", ls["hash_runs"][0][:12])
        Console().print(lt)


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"
