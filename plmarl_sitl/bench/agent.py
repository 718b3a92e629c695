"""`plmarl bench agent`: the deployed agent's decision loop, memory and start-up, in SITL.

A SITL world with N vehicles (default 20) at --speedup (default 10) runs in this process
over a mosquitto broker (amqtt if mosquitto is missing); one `plmarl agent` child per
vehicle flies the policy. Agents are started one after the other (each once the previous
one reports ready), so start-up is measured per process, not N processes fighting for the
cores at once; the fleet then flies --mission-s mission seconds together.

* loop_p50_ms / loop_p99_ms: decision ticks, telemetry message handled -> setpoint sent
  (closing the instant, Algorithm 1's tracker step, sensing features, policy.pt, the band
  guard, the SET_POSITION_TARGET_LOCAL_NED send), pooled over all agents;
  loop_cpu_*: the same ticks in thread CPU time (the wall figure also holds whatever the
  OS gave other processes mid-tick; on a loaded machine that dominates the tail);
  arrival_*: the same ticks from the telemetry datagram's arrival in the kernel, i.e. also
  the time the message waited for the agent to get a CPU (here: the other 19 agents
  deciding at the same second, on 2 cores);
* rss_mb: the largest agent resident set size at exit;
* startup_s: process start (interpreter and imports included) -> autopilot found,
  policy loaded, telemetry and home valid; median over agents (max also reported).

The fleet flies twice in one run: agents at normal priority, then under SCHED_FIFO
(`plmarl agent --rt-priority`, how a control loop runs on a companion computer) when this
process may use it. The top-level figures are the real-time fleet's (the normal one's
when real-time is off or not permitted); `normal_priority` holds the other fleet's.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from pathlib import Path

from plmarl_sitl.cmdline import rt_priority_arg, speedup_arg
from plmarl_sitl.config import PAPER_MISSION, PROJECT_POLICIES
from plmarl_sitl.machine import machine_info


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", type=int, default=20, help="vehicles and agents (default 20)")
    p.add_argument("--speedup", type=speedup_arg, default=10.0, help="sim seconds per wall second (default 10)")
    p.add_argument("--mission", default=str(PAPER_MISSION), help="mission YAML (default: the project's missions/paper_urban.yaml)")
    p.add_argument("--policy", default=str(PROJECT_POLICIES / "pl-marl"), help="policy directory (default: the project's policies/pl-marl)")
    p.add_argument("--mission-s", type=int, default=120, help="mission seconds flown together (default 120)")
    p.add_argument("--workdir", default=None, help="keep agent logs/traces here (default: a temp dir)")
    p.add_argument("--no-auth", action="store_true",
                   help="unsigned messages (default: signed with a fresh swarm key, as `plmarl swarm up` flies)")
    p.add_argument("--rt-priority", type=rt_priority_arg(0), default=None, metavar="P",
                   help="SCHED_FIFO priority of the second fleet (default 20 when permitted; 0: fly only at normal priority)")


def _pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    s = sorted(xs)
    return s[min(len(s) - 1, int(q * len(s)))]


async def _run(args: argparse.Namespace, rt_priority: int, workdir: Path) -> dict:
    import dataclasses

    from plmarl_sitl.deploy.mqtt.auth import create_key_file
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.agents import AgentFleet
    from plmarl_sitl.sitl.network.broker import free_udp_ports, local_broker
    from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

    mission = dataclasses.replace(load_mission(args.mission), n_uavs=args.n)
    n = args.n
    base = free_udp_ports(n)
    fleet = AgentFleet(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    key_path = None if args.no_auth else workdir / "swarm.key"
    key = None if key_path is None else create_key_file(key_path)
    extra = ["--rt-priority", str(rt_priority)] if rt_priority else []
    async with local_broker() as broker:
        url = broker.url
        world = SitlWorld(WorldConfig(mission=mission, broker_url=url, speedup=args.speedup, base_port=base,
                                      episode_s=args.mission_s, start_timeout_s=1e9, swarm_key=key))
        t_start = time.perf_counter()
        try:
            await world.start()
            run = asyncio.create_task(world.run(), name="world")
            for i in range(n):
                ap = await fleet.spawn(i, f"udpout://127.0.0.1:{base + i}", url, mission=args.mission, policy=args.policy,
                                       n_uavs=n, trace=False, extra=extra, swarm_key=key_path)
                async with asyncio.timeout(60):
                    while "ready after" not in ap.log():
                        if ap.proc.returncode is not None:
                            raise RuntimeError(f"agent {i} exited: {ap.log()[-500:]}")
                        await asyncio.sleep(0.05)
            async with asyncio.timeout(120 + 3 * args.mission_s / args.speedup):
                summary = await run
        finally:
            await world.shutdown(fleet)
    stats = [ap.stats() for ap in fleet.procs.values()]
    missing = [i for i, s in enumerate(stats) if s is None]
    if missing:
        raise RuntimeError(f"agents {missing} wrote no stats (see {workdir})")
    loop = [x for s in stats for x in s.get("decision_ms_samples", [])]
    cpu = [x for s in stats for x in s.get("decision_cpu_ms_samples", [])]
    arrival = [x for s in stats for x in s.get("decision_arrival_ms_samples", [])]
    starts = [s["startup_s"] for s in stats if s["startup_s"] is not None]
    return {
        "loop_p50_ms": _pct(loop, 0.5),
        "loop_p99_ms": _pct(loop, 0.99),
        "loop_samples": len(loop),
        "loop_cpu_p50_ms": _pct(cpu, 0.5),
        "loop_cpu_p99_ms": _pct(cpu, 0.99),
        "arrival_p50_ms": _pct(arrival, 0.5),
        "arrival_p99_ms": _pct(arrival, 0.99),
        "rt_priority": rt_priority or None,
        "rss_mb": max(s["rss_mb"] for s in stats),
        "startup_s": statistics.median(starts) if starts else None,
        "startup_max_s": max(starts) if starts else None,
        "decisions_per_agent": statistics.median(s["decisions"] for s in stats),
        "n": n,
        "speedup": args.speedup,
        "mission_s": len(summary.coverage),
        "mean_coverage": summary.mean_coverage,
        "wall_s": time.perf_counter() - t_start,
        "machine": machine_info(),
    }


def run(args: argparse.Namespace) -> dict:
    import logging
    import sys

    from plmarl_sitl.errors import UserError
    from plmarl_sitl.proc import RT_HOWTO, realtime_permitted

    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    logging.getLogger("plmarl.world").setLevel(logging.INFO)
    rt = args.rt_priority
    if rt is None:
        rt = 20 if realtime_permitted(20) else 0
        if not rt:
            logging.getLogger("plmarl.bench").warning("real-time priority not permitted, flying at normal priority only (%s)", RT_HOWTO)
    elif rt and not realtime_permitted(rt):
        raise UserError(f"--rt-priority {rt}: {RT_HOWTO}")
    root = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="plmarl-bench-agent-"))
    normal = asyncio.run(_run(args, 0, root / "normal"))
    if not rt:
        return normal
    out = asyncio.run(_run(args, rt, root / "realtime"))
    out["normal_priority"] = {k: v for k, v in normal.items() if k != "machine"}
    return out


def print_table(r: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"deployed agent, N = {r['n']}, speedup {r['speedup']:g} ({r['mission_s']} mission s)")
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_column("target", justify="right")
    fleets = [r] + ([r["normal_priority"]] if "normal_priority" in r else [])
    for f in fleets:
        how = f"SCHED_FIFO {f['rt_priority']}" if f["rt_priority"] else "normal priority"
        t.add_row(f"decision loop p50 / p99 ({how})", f"{f['loop_p50_ms']:.3f} / {f['loop_p99_ms']:.3f} ms", "p99 <= 2 ms")
        t.add_row(f"  CPU time p50 / p99 ({how})", f"{f['loop_cpu_p50_ms']:.3f} / {f['loop_cpu_p99_ms']:.3f} ms", "")
        if f["arrival_p50_ms"] is not None:
            t.add_row(f"  from datagram arrival p50 / p99 ({how})", f"{f['arrival_p50_ms']:.3f} / {f['arrival_p99_ms']:.3f} ms", "")
    t.add_row("RSS (largest agent)", f"{r['rss_mb']:.0f} MB", "<= 300 MB")
    t.add_row("start-up (median / max)", f"{r['startup_s']:.2f} / {r['startup_max_s']:.2f} s", "<= 2 s")
    t.add_row("decisions per agent", f"{r['decisions_per_agent']:.0f}", "")
    Console().print(t)
    print(f"machine: {r['machine']}")
