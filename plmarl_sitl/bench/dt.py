"""`plmarl bench dt`: speed of the vectorised twin and of one Oracle episode.

An agent-step is one agent advanced by one 1-s physics step (the unit VMAS reports), so a
decision of tau = 3 s for B envs of N agents is 3 B N agent-steps. Each row runs whole
episodes with random (seeded) accelerations, after one warm-up decision.
"""

from __future__ import annotations

import argparse
import time

from plmarl_sitl.bench.machine import machine_info

DEFAULT_MISSION = "missions/paper_urban.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mission", default=DEFAULT_MISSION, help=f"mission YAML (default: {DEFAULT_MISSION})")
    p.add_argument("--envs", default="1,64,1024", help="comma-separated batch sizes (default: 1,64,1024)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (default: all cores)")
    p.add_argument("--seed", type=int, default=0, help="seed (default: 0)")


def _time_env(mission, envs: int, seed: int) -> float:
    import torch

    from plmarl_sitl.dt.env import CoverageEnv

    env = CoverageEnv(mission, envs, seed)
    gen = torch.Generator().manual_seed(seed)
    a_max = env.limits.max_accel

    def act() -> torch.Tensor:
        return (torch.rand(envs, env.n, 3, generator=gen) * 2 - 1) * a_max

    env.step(act())  # warm-up
    steps = 0
    t0 = time.perf_counter()
    episodes = 0
    while time.perf_counter() - t0 < 2.0 or episodes == 0:
        env.reset()
        while not env.done:
            before = env.t
            env.step(act())
            steps += env.t - before
        episodes += 1
    wall = time.perf_counter() - t0
    return envs * env.n * steps / wall


def _time_oracle(mission, seed: int) -> float:
    from plmarl_sitl.dt.env import CoverageEnv
    from plmarl_sitl.dt.oracle import OracleController

    env = CoverageEnv(mission, 1, seed)
    ctl = OracleController(env)
    obs = env.reset()
    t0 = time.perf_counter()
    while not env.done:
        obs, _, _ = env.step(ctl.act(obs))
    return time.perf_counter() - t0


def run(args: argparse.Namespace) -> dict:
    import torch

    from plmarl_sitl.mission import load_mission

    if args.threads:
        torch.set_num_threads(args.threads)
    mission = load_mission(args.mission)
    rows = [{"envs": e, "agent_steps_per_s": _time_env(mission, e, args.seed)} for e in (int(x) for x in args.envs.split(","))]
    return {
        "rows": rows,
        "oracle_episode_s": _time_oracle(mission, args.seed),
        "machine": machine_info(),
        "torch_threads": torch.get_num_threads(),
        "n_uavs": mission.n_uavs,
    }


def print_table(res: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"digital twin speed, N = {res['n_uavs']}, {res['torch_threads']} torch threads, {res['machine']}")
    t.add_column("parallel envs", justify="right")
    t.add_column("agent-steps/s", justify="right")
    for r in res["rows"]:
        t.add_row(str(r["envs"]), f"{r['agent_steps_per_s']:,.0f}")
    Console().print(t)
    Console().print(f"one Oracle episode (200 steps): {res['oracle_episode_s']:.2f} s")
