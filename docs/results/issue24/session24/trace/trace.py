"""Issue 24, session 24 H-trace24 (diagnosis only, no product change): what splits the survivors' heard
graph after a 2-of-6 failure at T_up 50 (`pl-marl`, today's default, `replan` way of decompose.py).

Flies the episodes of session 24's decompose.py (suite_twin_seed(S, variant), 10 per mission and seed)
and, at every signalling instant after the failure, records *inside* the env's own signalling step
(exact positions of the instant; decompose.py samples at the next decision, up to 2 s later):
true positions, velocities, the env's receive mask and SINR, each survivor's knowledge (gossip failed
set, epoch), each copy's plan (points, failed set, epoch), each survivor's target input (the policy's
plan point), and the pre-failure plan (the copies' plan at the decision of t = 99).

Per episode it writes a JSON record; classify.py classes the episodes.

    PYTHONPATH=. python docs/results/issue24/session24/trace/trace.py --seeds 7 8 ... > trace_s7_14.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from plmarl_sitl.bench.replan import AFTER_S
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.graph import distances, link_mask
from plmarl_sitl.twin.env import CoverageEnv

FAIL_S = 100
MISSIONS = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"]


class dec:  # noqa: N801 - decompose.py's split test and its `instant` way, copied (its module patches the gate, absent from main)
    @staticmethod
    def strongly_connected(rx: torch.Tensor, alive: torch.Tensor) -> torch.Tensor:
        n = rx.shape[-1]
        a = (rx & alive.unsqueeze(-1) & alive.unsqueeze(-2)) | torch.eye(n, dtype=torch.bool)
        r = a.clone()
        for _ in range(n):
            r = r | ((r.float() @ a.float()) > 0)
        live = alive.unsqueeze(-1) & alive.unsqueeze(-2)
        return (r | ~live).all(-1).all(-1)

    @staticmethod
    def run(mission, make, episodes: int, seed: int, way: str) -> dict:  # noqa: ANN001 - decompose.run, way instant only
        assert way == "instant"
        env = CoverageEnv(mission, episodes, seed)
        ctl = make(env)
        ctl.reset()
        obs = env.observe()
        cover = []
        with torch.inference_mode():
            while not env.done:
                g = env.gossip
                dead = ~env.alive
                if bool(dead.any()):
                    new = dead.unsqueeze(1).expand(-1, env.n, -1) & env.alive.unsqueeze(-1) & ~g.failed
                    if bool(new.any()):
                        g.declare(new, torch.where(new.any(-1), torch.full_like(g.epoch, obs.t), torch.zeros_like(g.epoch)))
                obs, _, info = env.step(ctl.act(obs))
                cover.append(info.coverage)
        trace = torch.cat(cover, -1).numpy()
        return {"after": trace[:, FAIL_S - 1 + AFTER_S:].mean(1).tolist()}




def fly(m, twin_seed: int, episodes: int, loaded, way: str = "replan") -> dict:  # noqa: ANN001
    env = CoverageEnv(m, episodes, twin_seed)
    ctl = controller_factory("pl-marl", loaded)(env)
    ctl.reset()
    plan = ctl.perceive.plan
    snaps: list[dict] = []
    orig = env.run_signalling
    state = {"pre": None, "point": None}

    def hooked() -> None:
        t = env.t
        tup = env.events.instant_tup(t)
        if t >= FAIL_S and tup and t % tup == 0:
            rx, sinr = link_mask(env.pos, env.alive, m.channel, m.radii.comm_m)
            cp = plan.copy_points()
            snaps.append({
                "t": t, "pos": env.pos.double().numpy().copy(), "vel": env.vel.double().numpy().copy(),
                "alive": env.alive.numpy().copy(), "rx": rx.numpy().copy(), "sinr": sinr.double().numpy().copy(),
                "dist": distances(env.pos).double().numpy().copy(),
                "g_failed": env.gossip.failed.numpy().copy(), "g_epoch": env.gossip.epoch.numpy().copy(),
                "copy_points": None if cp is None else cp.numpy().copy(),
                "copy_failed": plan.plans.failed.copy(), "copy_epoch": plan.plans.epoch.copy(),
                "point": None if ctl.perceive.point is None else ctl.perceive.point.double().numpy().copy(),
                "own": None if plan.last is None else plan.last.double().numpy().copy(),
            })
        orig()

    env.run_signalling = hooked
    obs = env.observe()
    cover = []
    split_dec = np.zeros(episodes, bool)
    with torch.inference_mode():
        while not env.done:
            dead = ~env.alive
            if way == "spread" and bool(dead.any()):  # decompose.py's `spread` way: every survivor's knowledge merged before each decision
                g = env.gossip
                live = env.alive.unsqueeze(-1)
                merged = torch.where(live, g.rank, torch.zeros_like(g.rank)).amax(1, keepdim=True)
                g.rank = torch.where(live, torch.maximum(g.rank, merged), g.rank)
            if obs.t == FAIL_S - 1:
                cp = plan.copy_points()
                state["pre"] = cp.numpy().copy()  # (B, N, n, 2) each copy's plan at the decision of t = 99
            obs, _, info = env.step(ctl.act(obs))
            cover.append(info.coverage)
            if obs.t > FAIL_S and env.events.instant_tup(obs.t) and bool(dead.any()):
                tup = env.events.instant_tup(obs.t)
                if obs.t % tup < m.timing.decision_every_s:
                    rx, _ = link_mask(env.pos, env.alive, m.channel, m.radii.comm_m)
                    split_dec |= ~dec.strongly_connected(rx, env.alive).numpy()
    trace = torch.cat(cover, -1).numpy()
    after = trace[:, FAIL_S - 1 + AFTER_S:].mean(1)
    return {"snaps": snaps, "pre": state["pre"], "after": after, "split_dec": split_dec,
            "false_end": (env.gossip.failed & env.alive.unsqueeze(-1) & env.alive.unsqueeze(1)).sum((-1, -2)).numpy()}


def sc(adj: np.ndarray, live: np.ndarray) -> bool:
    return bool(dec.strongly_connected(torch.from_numpy(adj)[None], torch.from_numpy(live)[None])[0])


def comps(adj: np.ndarray, live: np.ndarray) -> list[list[int]]:
    """Strongly connected components of adj [i, j] (i hears j) among live."""
    idx = list(np.flatnonzero(live))
    n = adj.shape[0]
    r = adj | np.eye(n, dtype=bool)
    for _ in range(n):
        r = r | ((r.astype(float) @ r.astype(float)) > 0)
    out, seen = [], set()
    for i in idx:
        if i in seen:
            continue
        c = [j for j in idx if r[i, j] and r[j, i]]
        seen.update(c)
        out.append(c)
    return out


def graph_at(xy: np.ndarray, z: np.ndarray, live: np.ndarray, m) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """(receive mask, distance-only mask) with the UAVs at xy (N, 2), altitudes z (N,)."""
    p = torch.from_numpy(np.concatenate([xy, z[:, None]], -1))[None]
    rx, _ = link_mask(p, torch.from_numpy(live)[None], m.channel, m.radii.comm_m)
    d = distances(p)[0].numpy()
    return rx[0].numpy(), d <= m.radii.comm_m


def episode_record(r: dict, e: int, m) -> dict:  # noqa: ANN001
    n = r["snaps"][0]["pos"].shape[1] if r["snaps"] else 6
    eye = np.eye(n, dtype=bool)
    inst = []
    split100 = None
    for s in r["snaps"]:
        if s["t"] == FAIL_S:  # the failure's own instant (the failed UAVs are already silent): not counted as decompose.py
            split100 = not sc(s["rx"][e] & ~eye, s["alive"][e])
            continue
        live = s["alive"][e]
        rx = s["rx"][e] & ~eye
        inst.append({"t": s["t"], "split": not sc(rx, live)})
    rec = {"after": float(r["after"][e]), "split_dec": bool(r["split_dec"][e]), "false_end": int(r["false_end"][e]),
           "split_instants": [x["t"] for x in inst if x["split"]], "split100": split100}
    first = next((k for k, x in enumerate(inst) if x["split"]), None)
    if first is None:
        return rec
    s = next(x for x in r["snaps"] if x["t"] == inst[first]["t"])
    live = s["alive"][e]
    dead = np.flatnonzero(~live).tolist()
    rx = s["rx"][e] & ~eye
    pos, vel, dist = s["pos"][e], s["vel"][e], s["dist"][e]
    z = pos[:, 2]
    cs = comps(rx, live)
    # pairs across components (ordered both ways) and why each does not hear the other
    pairs = []
    point = s["point"][e] if s["point"] is not None else s["own"][e]
    own = s["own"][e]
    thr = 10 ** (m.channel.sinr_threshold_db / 10)
    for a in range(len(cs)):
        for b in range(a + 1, len(cs)):
            for i in cs[a]:
                for j in cs[b]:
                    pairs.append({"i": int(i), "j": int(j), "d": round(float(dist[i, j]), 1),
                                  "in_range": bool(dist[i, j] <= m.radii.comm_m),
                                  "sinr_ij_db": round(float(10 * np.log10(max(s["sinr"][e][i, j], 1e-12))), 1),
                                  "sinr_ji_db": round(float(10 * np.log10(max(s["sinr"][e][j, i], 1e-12))), 1),
                                  "i_hears_j": bool(rx[i, j]), "j_hears_i": bool(rx[j, i]),
                                  "d_points": round(float(np.linalg.norm(point[i] - point[j])), 1)})
    # graphs: distance only at true positions; at each survivor's own target (the policy's plan point input);
    # at its own copy's raw plan point; at the pre-failure plan (copy of the lowest live agent) minus the failed
    _, dist_only = graph_at(pos[:, :2], z, live, m)
    rx_pt, d_pt = graph_at(point, z, live, m)
    rx_own, _ = graph_at(own, z, live, m)
    pre = r["pre"][e]
    ref = int(np.flatnonzero(live)[0])
    rx_pre, d_pre = graph_at(np.nan_to_num(pre[ref]), z, live, m)
    # the copies: do the survivors' copies agree (failed set, epoch) and match the truth?
    cf, ce = s["copy_failed"][e], s["copy_epoch"][e]
    gf = s["g_failed"][e]
    truth = ~live
    copies = {int(i): {"copy_failed": np.flatnonzero(cf[i]).tolist(), "copy_epoch": int(ce[i]),
                       "knows": np.flatnonzero(gf[i]).tolist(),
                       "pos": pos[i, :2].round(0).tolist(), "speed": round(float(np.linalg.norm(vel[i, :2])), 1),
                       "point": point[i].round(0).tolist(),
                       "off_point": round(float(np.linalg.norm(pos[i, :2] - point[i])), 1),
                       "off_plan": round(float(np.linalg.norm(pos[i, :2] - own[i])), 1)} for i in np.flatnonzero(live)}
    agree = len({(tuple(v["copy_failed"]), v["copy_epoch"]) for v in copies.values()}) == 1
    correct = all(set(v["copy_failed"]) == set(dead) for v in copies.values())
    false_decl = any(set(v["copy_failed"]) - set(dead) for v in copies.values())
    unaware = [i for i, v in copies.items() if not set(dead) <= set(v["copy_failed"])]
    # distances of each survivor's point to every other survivor's point, in each copy: do the copies' plans
    # differ (a point of i in i's copy vs i's point in j's copy)?
    cp = s["copy_points"][e]
    spread = {int(i): round(float(max(np.linalg.norm(np.nan_to_num(cp[i, i]) - np.nan_to_num(cp[j, i])) for j in np.flatnonzero(live))), 1)
              for i in np.flatnonzero(live)}
    # each copy's own plan: all survivors at the points of survivor a's copy (a survivor the copy counts failed:
    # at its own point), connected?
    copy_plan = {}
    for a in np.flatnonzero(live):
        xy = np.where(np.isnan(cp[a]), point, cp[a])
        rxa, da = graph_at(xy, z, live, m)
        copy_plan[int(a)] = {"conn": sc(rxa & ~eye, live), "dist_conn": sc(da & ~eye, live),
                             "full": set(np.flatnonzero(cf[a]).tolist()) == set(dead)}
    rec.update({
        "copy_plan": copy_plan, "n_failed_sets": len({tuple(v["copy_failed"]) for v in copies.values()}),
        "t": s["t"], "first_idx": first, "n_split_instants": len(rec["split_instants"]),
        "n_instants": len(inst), "dead": dead, "components": cs, "pairs": pairs,
        "dist_only_connected": sc(dist_only & ~eye, live),
        "at_points_connected": sc(rx_pt & ~eye, live), "at_points_dist_connected": sc(d_pt & ~eye, live),
        "at_own_plan_connected": sc(rx_own & ~eye, live),
        "pre_plan_connected": sc(rx_pre & ~eye, live), "pre_plan_dist_connected": sc(d_pre & ~eye, live),
        "copies_agree": agree, "copies_correct": correct, "false_decl": false_decl, "unaware": unaware,
        "plan_spread": spread, "copies": copies,
    })
    return rec


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9, 10, 11, 12, 13, 14])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--tup", type=int, default=50)
    ap.add_argument("--no-instant", action="store_true")
    ap.add_argument("--way", default="replan", choices=["replan", "spread"], help="spread: decompose.py's zero-latency knowledge flood (a bound)")
    a = ap.parse_args()
    assert all(7 <= s <= 14 for s in a.seeds), "tuning seeds 7-14 only"
    loaded = {"pl-marl": load_policy("policies/pl-marl")}
    out = []
    for seed in a.seeds:
        for v, path in enumerate(MISSIONS):
            m = load_mission(path).with_tup(a.tup)
            ts = suite_twin_seed(seed, v)
            t0 = time.time()
            r = fly(m, ts, a.episodes, loaded, a.way)
            inst = None
            if not a.no_instant:
                make = controller_factory("pl-marl", loaded)
                inst = dec.run(m, make, a.episodes, ts, "instant")["after"]
            for e in range(a.episodes):
                rec = {"seed": seed, "mission": "ab"[v], "episode": e, **episode_record(r, e, m)}
                rec["instant"] = None if inst is None else inst[e]
                out.append(rec)
            ns = sum(1 for x in out if x["seed"] == seed and x["mission"] == "ab"[v] and x["split_instants"])
            nd = int(r["split_dec"].sum())
            print(f"seed {seed} {'ab'[v]}: after {r['after'].mean():.4f} split(exact) {ns} split(decompose) {nd} "
                  f"({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
    print(json.dumps({"way": a.way, "tup": a.tup, "episodes": a.episodes, "rows": out}, default=lambda o: o.item() if hasattr(o, "item") else o.tolist()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
