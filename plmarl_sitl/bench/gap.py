"""Sim-to-SITL gap: the same mission, seeds and policy in the twin and in SITL.

Twin: `CoverageEnv(mission, 1, seed)` driven by `LearnedController` (the evaluation's
controller). SITL: `SitlWorld(seed=seed)` (same users: same generator seeding and
per-second stepping) with one `plmarl agent` child per UAV over a real broker. Both
report the mean of C(t) over mission seconds 1..episode_s. With --lockstep the SITL swarm
runs in lockstep (`plmarl swarm up --lockstep`: vehicle time waits for every agent, so the
result does not depend on the machine's load; the speedup paces only the start-up).

    python -m plmarl_sitl.bench.gap missions/paper_urban.yaml --seeds 0 1 2 --lockstep
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

from plmarl_sitl.cmdline import seed_arg, speedup_arg
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.deploy.mqtt.auth import create_key_file
from plmarl_sitl.errors import PlmarlError, UserError, run_reporting
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.model.events import EventSchedule
from plmarl_sitl.sitl.agents import SITL_AGENT_NICE, AgentFleet
from plmarl_sitl.sitl.network.broker import free_udp_ports, local_broker
from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

PROG = "python -m plmarl_sitl.bench.gap"
START_WALL_S = 120.0


class GapRunFailed(PlmarlError):
    """A SITL run that cannot give the gap: a vehicle missed the start, or the run never ended."""


def twin_coverage(mission: Mission, policy_dir: str | Path, seed: int) -> list[float]:
    return twin_series(mission, policy_dir, seed)[0]


def twin_series(mission: Mission, policy_dir: str | Path, seed: int, *, lambda2: bool = False) -> tuple[list[float], list[float]]:
    """C(t) and (with `lambda2`) lambda_2(t) of one twin episode, mission seconds 1..episode_s."""
    from plmarl_sitl.learning.eval.controllers import LearnedController
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.twin.env import CoverageEnv

    lp = load_policy(policy_dir, mission)
    env = CoverageEnv(mission, 1, seed, track_lambda2=lambda2)
    ctl = LearnedController(lp.tracker, lp.policy, mission)
    ctl.reset()
    obs = env.observe()
    cov: list[torch.Tensor] = []
    lam: list[torch.Tensor] = []
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        cov.append(info.coverage[0])
        if info.lambda2 is not None:
            lam.append(info.lambda2[0])
    return torch.cat(cov).tolist(), (torch.cat(lam).tolist() if lam else [])


async def sitl_coverage(
    mission_path: str | Path, policy_dir: str | Path, seed: int, *, speedup: float = 10.0, workdir: Path | None = None,
    lockstep: bool = False, start_wall_s: float = START_WALL_S,
) -> tuple[list[float], dict]:
    mission = load_mission(mission_path)
    n = mission.n_uavs
    base = free_udp_ports(n)
    tmp = workdir or Path(tempfile.mkdtemp(prefix="plmarl-gap-"))
    fleet = AgentFleet(tmp, nice=SITL_AGENT_NICE)
    key = create_key_file(tmp / "swarm.key")  # signed, as `plmarl swarm up` flies
    async with local_broker() as broker:
        # Every vehicle must fly the whole mission for the gap to mean anything: wait up to
        # START_WALL_S of wall time for all of them (the world's default, 300 vehicle s, is
        # 30 s at 10x, shorter than the agents' start-up on a loaded 2-core machine).
        world = SitlWorld(WorldConfig(mission=mission, broker_url=broker.url, speedup=speedup, base_port=base, seed=seed,
                                      episode_s=mission.timing.episode_s, swarm_key=key, lockstep=lockstep,
                                      start_timeout_s=start_wall_s * speedup,
                                      # the mission's events, as the twin applies them (its failures: issue 24)
                                      events=EventSchedule.of(mission)))
        try:
            await world.start()
            for i in range(n):
                await fleet.spawn(i, f"udpout://127.0.0.1:{base + i}", broker.url, mission=mission_path, policy=policy_dir,
                                  swarm_key=tmp / "swarm.key", extra=["--lockstep"] if lockstep else None)
            limit_s = start_wall_s + 3 * mission.timing.episode_s / speedup + 60
            try:
                async with asyncio.timeout(limit_s):
                    summary = await world.run()
            except TimeoutError:
                raise GapRunFailed(f"seed {seed}: the SITL run did not end within {limit_s:.0f} s wall") from None
            if summary.not_ready_at_start:  # a gap measured without every vehicle means nothing
                raise GapRunFailed(f"seed {seed}: the mission started without {'; '.join(summary.not_ready_at_start)} "
                                   f"(more --start-wall-s than {start_wall_s:g} on a loaded machine)")
        finally:
            await world.shutdown(fleet)
    stats = {i: ap.stats() for i, ap in fleet.procs.items()}
    return summary.coverage, {"wall_s": summary.wall_s, "links": summary.links, "agents": stats, "lambda2": summary.lambda2}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("mission")
    p.add_argument("--policy", default=str(PROJECT_POLICIES / "pl-marl"), help="policy directory (default: the project's policies/pl-marl)")
    p.add_argument("--seeds", type=seed_arg, nargs="+", default=[0, 1, 2], help="the seeds to fly (default 0 1 2)")
    p.add_argument("--speedup", type=speedup_arg, default=10.0)
    p.add_argument("--lockstep", action="store_true", help="fly the SITL side in lockstep (deterministic, load-independent)")
    p.add_argument("--start-wall-s", type=float, default=START_WALL_S,
                   help=f"wall seconds the vehicles get to be ready (default {START_WALL_S:g}; more on a loaded machine)")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    return run_reporting(PROG, lambda: measure(args))


def measure(args: argparse.Namespace) -> int:
    """Every failure is one line on stderr (`run_reporting`): a user's mistake exit 2, a SITL
    run that could not measure the gap (`GapRunFailed`) 3."""
    if not args.start_wall_s > 0:
        raise UserError("--start-wall-s must be > 0")
    mission = load_mission(args.mission)
    rows = []
    for seed in args.seeds:
        t = time.perf_counter()
        twin = twin_coverage(mission, args.policy, seed)
        sitl, info = asyncio.run(sitl_coverage(args.mission, args.policy, seed, speedup=args.speedup,
                                                 lockstep=args.lockstep, start_wall_s=args.start_wall_s))
        tw, st = sum(twin) / len(twin), (sum(sitl) / len(sitl) if sitl else float("nan"))
        rows.append({"seed": seed, "twin": tw, "sitl": st, "gap": st - tw, "sitl_seconds": len(sitl), "wall_s": time.perf_counter() - t})
        print(f"seed {seed}: twin {tw:.4f}  sitl {st:.4f}  gap {st - tw:+.4f}  ({len(sitl)} s, {rows[-1]['wall_s']:.0f} s wall)",
              file=sys.stderr, flush=True)
    mt = sum(r["twin"] for r in rows) / len(rows)
    ms = sum(r["sitl"] for r in rows) / len(rows)
    out = {"mission": mission.name, "policy": str(args.policy), "seeds": args.seeds, "lockstep": args.lockstep, "twin_mean": mt, "sitl_mean": ms,
           "gap": ms - mt, "max_abs_seed_gap": max(abs(r["gap"]) for r in rows), "per_seed": rows}
    print(json.dumps(out) if args.json else json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
