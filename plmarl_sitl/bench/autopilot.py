"""`plmarl bench autopilot`: how many vehicles one process sustains, and how fast.

Each trial runs an AutopilotHost in this process (real-time runner, PX4 personality,
streams HEARTBEAT 1 Hz + LOCAL_POSITION_NED 10 Hz of sim time) and a load generator in a
second process: one VehicleLink per vehicle that puts it in OFFBOARD, arms it and sends
acceleration setpoints at 20 Hz of sim time. A trial is *sustained* when, over the
measurement window, (1) the vehicle clock (time_boot_ms seen by the client) advances at
>= 95 % of the requested speedup, (2) every vehicle delivers >= 95 % of its
LOCAL_POSITION_NED messages and >= 90 % of its heartbeats, and (3) the host received
>= 97 % of the setpoints sent (UDP drops mean overload). The search doubles the load until
a trial fails, then bisects to ~10 %. Past 250 vehicles system ids repeat (MAVLink ids
are 8 bits; one host serves at most 250 distinct ids), each vehicle still on its own port.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import multiprocessing as mp
import os
import random
import time
from typing import Any

from rich.console import Console
from rich.table import Table

SETPOINT_HZ = 20.0
LPN_HZ = 10.0
HB_HZ = 1.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--window", type=float, default=6.0, help="measurement window, wall seconds (default 6)")
    p.add_argument("--warmup", type=float, default=2.0, help="wall seconds before measuring (default 2)")
    p.add_argument("--max-vehicles", type=int, default=1600, help="search cap for vehicles at 1x")
    p.add_argument("--max-speedup", type=float, default=320.0, help="search cap for the speedup of 20 vehicles")
    p.add_argument("--speedup-vehicles", type=int, default=20, help="vehicles in the speedup search (default 20)")
    p.add_argument("--only", choices=["vehicles", "speedup"], default=None, help="run one search only")


# ---------------------------------------------------------------------------- load generator


def _load_main(ports: list[int], speedup: float, warmup: float, window: float, q: Any) -> None:
    """Second process: drive every vehicle and measure what comes back."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        q.put(asyncio.run(_load(ports, speedup, warmup, window)))
    except Exception as exc:  # report, do not hang the parent
        q.put({"error": f"{type(exc).__name__}: {exc}"})


async def _load(ports: list[int], speedup: float, warmup: float, window: float) -> dict:
    from plmarl_sitl.deploy.mavlink.client import VehicleLink

    links = [VehicleLink("127.0.0.1", p) for p in ports]
    async with asyncio.timeout(60):
        await asyncio.gather(*(lk.open(10.0) for lk in links))
        for lk in links:
            lk.send_accel_ned(0.0, 0.0, -1.0)
        await asyncio.gather(*(lk.set_mode("OFFBOARD") for lk in links))
        await asyncio.gather(*(lk.arm() for lk in links))
    rate = SETPOINT_HZ * speedup  # per vehicle, per wall second
    tick = 1.0 / min(rate, 100.0)
    t0 = time.perf_counter()
    owed = 0.0
    marks: dict[str, Any] = {}
    t_measure, t_end = t0 + warmup, t0 + warmup + window
    last = t0
    while True:
        now = time.perf_counter()
        owed += (now - last) * rate
        last = now
        n = int(owed)
        owed -= n
        w = 0.5 * (now - t0)
        ax, ay = math.cos(w), math.sin(w)
        for lk in links:
            for _ in range(n):
                lk.send_accel_ned(ax, ay, -0.2)
        if "start" not in marks and now >= t_measure:
            marks["start"] = _snapshot(links, now)
        if now >= t_end:
            marks["end"] = _snapshot(links, now)
            break
        await asyncio.sleep(tick)
    for lk in links:
        lk.close()
    return {"sent": sum(lk.sent for lk in links), **_summarise(marks["start"], marks["end"])}


def _snapshot(links: list, now: float) -> dict:
    return {
        "wall": now,
        "lpn": [lk.counts["LOCAL_POSITION_NED"] for lk in links],
        "hb": [lk.counts["HEARTBEAT"] for lk in links],
        "boot": [lk.latest["LOCAL_POSITION_NED"].time_boot_ms / 1000 if "LOCAL_POSITION_NED" in lk.latest else 0.0
                 for lk in links],
    }


def _summarise(a: dict, b: dict) -> dict:
    wall = b["wall"] - a["wall"]
    sim = [tb - ta for ta, tb in zip(a["boot"], b["boot"], strict=True)]
    lpn = [(nb - na) / max(1e-9, s * LPN_HZ) for na, nb, s in zip(a["lpn"], b["lpn"], sim, strict=True)]
    hb = [(nb - na) / max(1e-9, math.floor(s * HB_HZ)) for na, nb, s in zip(a["hb"], b["hb"], sim, strict=True)]
    return {"wall_s": wall, "clock_rate": min(sim) / wall, "lpn_ratio": min(lpn), "hb_ratio": min(hb)}


# ---------------------------------------------------------------------------- one trial


async def _trial_async(count: int, speedup: float, warmup: float, window: float) -> dict:
    from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime

    for _ in range(20):
        host = AutopilotHost(
            count,
            base_port=random.randrange(20000, 60000 - count),
            streams={"HEARTBEAT": HB_HZ, "LOCAL_POSITION_NED": LPN_HZ, **{k: 0 for k in _OTHER_STREAMS}},
            # Beyond 250 vehicles MAVLink's 8-bit system ids repeat; each vehicle still has its
            # own port and link, so capacity can be measured past the id limit.
            sysids=[i % 250 + 1 for i in range(count)],
        )
        try:
            await host.start()
            break
        except OSError:
            continue
    else:
        raise RuntimeError("no free UDP port range")
    stop = asyncio.Event()
    clock = asyncio.create_task(run_realtime(host, speedup, stop=stop, log_every_s=1e9), name="clock")
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    gen = ctx.Process(target=_load_main, args=(host.ports, speedup, warmup, window, q), daemon=True)
    gen.start()
    try:
        res = await asyncio.to_thread(q.get, True, warmup + window + 90)
        await asyncio.sleep(0.3)  # let the last datagrams in
    finally:
        stop.set()
        stats = await clock
        host.close()
        gen.join(5)
        if gen.is_alive():
            gen.kill()
    if "error" in res:
        return {"count": count, "speedup": speedup, "ok": False, "error": res["error"]}
    received = sum(v.counters.messages for v in host.vehicles)
    res.update(count=count, speedup=speedup, recv_ratio=received / res["sent"], host_cpu=stats.cpu_load)
    res["ok"] = (
        res["clock_rate"] >= 0.95 * speedup
        and res["lpn_ratio"] >= 0.95
        and res["hb_ratio"] >= 0.9
        and res["recv_ratio"] >= 0.97
    )
    return res


_OTHER_STREAMS = ("SYS_STATUS", "SYSTEM_TIME", "GPS_RAW_INT", "EXTENDED_SYS_STATE", "HOME_POSITION", "ATTITUDE",
                  "GLOBAL_POSITION_INT", "POSITION_TARGET_LOCAL_NED")


def trial(count: int, speedup: float, warmup: float, window: float) -> dict:
    return asyncio.run(_trial_async(count, speedup, warmup, window))


def _search(lo: float, cap: float, run_at, integer: bool, log: list) -> float:
    """Largest x in [lo, cap] that passes: double until a failure, then bisect to ~10 %."""
    best = 0.0
    x = lo
    fail = None
    while x <= cap:
        r = run_at(x)
        log.append(r)
        if not r["ok"]:
            fail = x
            break
        best = x
        x *= 2
    if fail is None:
        return best
    lo_ok, hi_bad = best, fail
    while hi_bad - lo_ok > max(0.1 * lo_ok, 1):
        mid = (lo_ok + hi_bad) / 2
        mid = float(round(mid)) if integer else round(mid, 1)
        r = run_at(mid)
        log.append(r)
        if r["ok"]:
            lo_ok = mid
        else:
            hi_bad = mid
    return lo_ok


def run(args: argparse.Namespace) -> dict:
    log: list[dict] = []
    result: dict[str, Any] = {}
    quiet = getattr(args, "json", False)
    con = Console(stderr=True, quiet=quiet)

    def at(count: float, speedup: float) -> dict:
        r = trial(int(count), speedup, args.warmup, args.window)
        con.print(
            f"  {int(count):5d} vehicles x{speedup:<6g} {'ok ' if r['ok'] else 'FAIL'} "
            + (r.get("error") or f"clock x{r['clock_rate']:.2f} lpn {r['lpn_ratio']:.2f} hb {r['hb_ratio']:.2f} "
               f"recv {r['recv_ratio']:.3f} host cpu {r['host_cpu']:.2f}")
        )
        return r

    if args.only in (None, "vehicles"):
        result["max_vehicles_1x"] = int(_search(100, args.max_vehicles, lambda n: at(n, 1.0), True, log))
    if args.only in (None, "speedup"):
        n = args.speedup_vehicles
        result[f"max_speedup_{n}"] = _search(10.0, args.max_speedup, lambda k: at(n, k), False, log)
    if not quiet:  # --json prints exactly the headline numbers
        result["trials"] = log
    return result


def print_table(result: dict) -> None:
    t = Table(title="Autopilot emulator: what one process sustains")
    for col in ("vehicles", "speedup", "sustained", "vehicle clock", "LPN", "HB", "setpoints in", "host CPU"):
        t.add_column(col, justify="right")
    for r in result["trials"]:
        if "error" in r:
            t.add_row(str(r["count"]), f"{r['speedup']:g}", "no", r["error"], "", "", "", "")
            continue
        t.add_row(
            str(r["count"]), f"{r['speedup']:g}", "yes" if r["ok"] else "no", f"x{r['clock_rate']:.2f}",
            f"{r['lpn_ratio']:.0%}", f"{r['hb_ratio']:.0%}", f"{r['recv_ratio']:.1%}", f"{r['host_cpu']:.0%}",
        )
    con = Console()
    con.print(t)
    for k, v in result.items():
        if k != "trials":
            con.print(f"{k}: {v}")
