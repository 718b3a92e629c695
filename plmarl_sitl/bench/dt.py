"""`plmarl bench dt`: speed of the vectorised twin and of one greedy-reference episode.

An agent-step is one agent advanced by one 1-s physics step (the unit VMAS reports), so a
decision of tau = 3 s for B envs of N agents is 3 B N agent-steps. Actions are uniform
random accelerations (seeded), held for a decision, as a policy's would be.

Two ways to use the cores are measured in the same run, since which is faster depends on
the machine and on what else runs on it:
* `threads`: one process, one batch of B envs, torch intra-op threads = cores;
* `shards`: the batch split over one single-threaded process per core (B / cores envs
  each, stepped concurrently), the layout of SubprocVecEnv / EnvPool.
Each row's `agent_steps_per_s` is the faster of the two and names it in `mode`.
Stepping runs under torch.inference_mode, as `plmarl sim`, evaluation and SITL do (the
trainer's rollouts use plain tensors, so autograd can use them; that costs ~5%).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

from plmarl_sitl.cmdline import comma_list, seed_arg
from plmarl_sitl.config import PAPER_MISSION
from plmarl_sitl.machine import machine_info

MEASURE_S = 3.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mission", default=str(PAPER_MISSION), help="mission YAML (default: the project's missions/paper_urban.yaml)")
    p.add_argument("--envs", default="1,64,1024", type=comma_list(int, "batch size", positive=True),
                   help="comma-separated batch sizes (default: 1,64,1024)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed (default: 0)")


def _steps_for(mission_path: str, envs: int, seed: int, threads: int, start_at: float, seconds: float) -> tuple[int, float]:
    """Step a CoverageEnv from `start_at` (wall clock) for `seconds`; (agent-steps, wall)."""
    import torch

    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.twin.env import CoverageEnv

    torch.set_num_threads(threads)
    env = CoverageEnv(load_mission(mission_path), envs, seed)
    gen = torch.Generator().manual_seed(seed)
    a_max = env.limits.max_accel

    def act() -> torch.Tensor:
        return (torch.rand(envs, env.n, 3, generator=gen) * 2 - 1) * a_max

    with torch.inference_mode():
        env.step(act())  # warm-up
        while time.time() < start_at:
            time.sleep(0.001)
        steps = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            if env.done:
                env.reset()
            before = env.t
            env.step(act())
            steps += env.t - before
    return envs * env.n * steps, time.perf_counter() - t0


def _shard_worker(args: tuple) -> tuple[int, float]:
    return _steps_for(*args)


def _threads_mode(mission_path: str, envs: int, seed: int) -> float:
    steps, wall = _steps_for(mission_path, envs, seed, os.cpu_count() or 1, 0.0, MEASURE_S)
    return steps / wall


def _shards_mode(mission_path: str, envs: int, seed: int) -> float | None:
    cores = os.cpu_count() or 1
    if cores < 2 or envs < cores:
        return None
    start_at = time.time() + 3.0  # every shard built and warmed up before the clock starts
    jobs = [(mission_path, envs // cores, seed + i, 1, start_at, MEASURE_S) for i in range(cores)]
    with mp.get_context("spawn").Pool(cores) as pool:
        results = pool.map(_shard_worker, jobs)
    return sum(s for s, _ in results) / max(w for _, w in results)


def _time_greedy(mission, seed: int) -> float:
    import torch

    from plmarl_sitl.twin.env import CoverageEnv
    from plmarl_sitl.twin.greedy import GreedyController

    env = CoverageEnv(mission, 1, seed)
    ctl = GreedyController(env)
    with torch.inference_mode():
        obs = env.reset()
        t0 = time.perf_counter()
        while not env.done:
            obs, _, _ = env.step(ctl.act(obs))
    return time.perf_counter() - t0


def run(args: argparse.Namespace) -> dict:
    import torch

    from plmarl_sitl.mission import load_mission

    mission = load_mission(args.mission)
    rows = []
    for envs in args.envs:
        threads = _threads_mode(args.mission, envs, args.seed)
        shards = _shards_mode(args.mission, envs, args.seed)
        best, mode = (shards, "shards") if shards and shards > threads else (threads, "threads")
        rows.append({"envs": envs, "agent_steps_per_s": best, "mode": mode, "threads_mode": threads, "shards_mode": shards})
    torch.set_num_threads(1)
    return {
        "rows": rows,
        "greedy_episode_s": _time_greedy(mission, args.seed),
        "machine": machine_info(),
        "n_uavs": mission.n_uavs,
        "seed": args.seed,
    }


def print_table(res: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    console.print(f"machine: {res['machine']}; N = {res['n_uavs']}; seed {res['seed']}")
    t = Table(title="digital twin: agent-steps/s (1 agent x 1 s of physics)")
    t.add_column("envs", justify="right")
    t.add_column("1 process, threads", justify="right")
    t.add_column("shards, 1 per core", justify="right")
    t.add_column("best", justify="right")
    for r in res["rows"]:
        shards = f"{r['shards_mode']:,.0f}" if r["shards_mode"] else "-"
        t.add_row(str(r["envs"]), f"{r['threads_mode']:,.0f}", shards, f"{r['agent_steps_per_s']:,.0f}")
    console.print(t)
    console.print(f"one greedy-reference episode (200 s, batch 1): {res['greedy_episode_s']:.2f} s wall")
