# ruff: noqa  (a scratch probe kept to reproduce the numbers in docs/RESULTS.md, session 19; not product code)
"""Session 19 probe (training twin seeds only): what map staleness costs when crowds move fast,
and what a prediction of the demand map could earn. Paired: every method flies the same episodes.

    PYTHONPATH=. python docs/results/issue24/session19/move/probe.py --missions probe_paper,probe_random \
        --methods service,fresh,extrap15,... --episodes 20 --seed 4242 --tup 15

Probe controllers (all the plan follower `service` with another map fed to the same ServiceTargets):
* fresh      bound: the true map at every decision (no staleness);
* truevel<L> bound: the true users moved on by their true velocities L s ahead, every decision;
* extrap<H>  the published maps only (common knowledge): a flow estimated from the last two maps,
             the newest map shifted H s ahead of the map's second, re-planned at each new map;
* extrapc<L> the same flow, the map shifted (t - map second + L) s ahead at every decision;
* drift<D>   service, target moved toward the centroid of the users the UAV senses, at most D m.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies, run_method
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map, grid_shape

HERE = Path(__file__).parent


def flow_extrapolate(prev, cur, rows, cols, cell_m, dt, ahead, vmax, win=3):
    """Counts (K,) of cur moved `ahead` s along a per-cell flow: the shift of the count-weighted
    centroid within `win` cells between prev and cur (dt s apart), capped at vmax."""
    P, C = prev.reshape(rows, cols), cur.reshape(rows, cols)
    rr, cc = np.meshgrid(np.arange(rows, dtype=float), np.arange(cols, dtype=float), indexing="ij")
    def box(a):
        pad = np.pad(a, win)
        out = np.zeros_like(a)
        for i in range(2 * win + 1):
            for j in range(2 * win + 1):
                out += pad[i:i + rows, j:j + cols]
        return out
    mc, mp = box(C), box(P)
    cn, ce = box(C * rr) / np.maximum(mc, 1e-9), box(C * cc) / np.maximum(mc, 1e-9)
    pn, pe = box(P * rr) / np.maximum(mp, 1e-9), box(P * cc) / np.maximum(mp, 1e-9)
    vn, ve = (cn - pn) * cell_m / dt, (ce - pe) * cell_m / dt
    ok = (mc > 0) & (mp > 0)
    vn, ve = np.where(ok, vn, 0), np.where(ok, ve, 0)
    sp = np.hypot(vn, ve)
    f = np.minimum(1.0, vmax / np.maximum(sp, 1e-9))
    vn, ve = vn * f, ve * f
    nr = np.clip(np.floor(rr + 0.5 + vn * ahead / cell_m), 0, rows - 1).astype(int)
    nc = np.clip(np.floor(cc + 0.5 + ve * ahead / cell_m), 0, cols - 1).astype(int)
    out = np.zeros(rows * cols)
    np.add.at(out, (nr * cols + nc).ravel(), C.ravel())
    return out


class MapFed(ServiceController):
    """service with the map chosen by `feed(obs)` (B, K) counts; every decision if `every`."""
    def __init__(self, env, every):
        super().__init__(env.mission)
        self.env = env
        m = env.mission
        if every:
            self.targets.period = int(m.timing.decision_every_s)
        self.cent = cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, torch.float64)
        self.rows, self.cols = grid_shape(m.area.north_m, m.area.east_m, m.demand.cell_m)
    def reset(self):
        super().reset(); self.maps = []  # (second, counts (B, K)) of the published maps seen
    @torch.no_grad()
    def act(self, obs):
        cur = obs.demand[..., 2].double().numpy()
        if not self.maps or not np.array_equal(self.maps[-1][1], cur):
            self.maps.append((obs.t, cur.copy()))
        counts = self.feed(obs)
        dem = demand_cells(torch.from_numpy(counts), self.cent).to(obs.demand.dtype)
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, dem, mask=obs.nbr_mask, alive=obs.alive, gossip=obs.gossip)
        return self.targets.accel(obs.ego, xy)


class Fresh(MapFed):
    def __init__(self, env, lead=0.0):
        super().__init__(env, every=True); self.lead = lead
    def feed(self, obs):
        m = self.env.mission
        xy = self.env.users.xy.double() + self.lead * self.env.users.vel.double().transpose(-1, -2)
        return demand_map(xy, m.area.north_m, m.area.east_m, m.demand.cell_m).numpy()


class Extrap(MapFed):
    def __init__(self, env, ahead, continuous):
        super().__init__(env, every=continuous); self.ahead, self.cont = ahead, continuous
    def feed(self, obs):
        t_map, cur = self.maps[-1]
        if len(self.maps) < 2:
            return cur
        t_prev, prev = self.maps[-2]
        m = self.env.mission
        h = (obs.t - t_map + self.ahead) if self.cont else self.ahead
        return np.stack([flow_extrapolate(p, c, self.rows, self.cols, m.demand.cell_m, t_map - t_prev, h, m.users.max_speed_mps)
                         for p, c in zip(prev, cur)])


class Drift(ServiceController):
    def __init__(self, env, d):
        super().__init__(env.mission); self.d = d; self.rs = float(env.mission.radii.sensing_m)
    @torch.no_grad()
    def act(self, obs):
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask, alive=obs.alive, gossip=obs.gossip)
        cnt = obs.sense[..., 0]
        cen = obs.ego[..., :2] + obs.sense[..., 1:3] * self.rs
        step = cen - xy
        n = torch.linalg.norm(step, dim=-1, keepdim=True)
        step = step * torch.clamp(self.d / torch.clamp(n, min=1e-9), max=1.0)
        tgt = torch.where((cnt > 0).unsqueeze(-1), xy + step, xy)
        return self.targets.accel(obs.ego, tgt)


def factory(name, loaded):
    if name == "fresh":
        return lambda env: Fresh(env)
    if name.startswith("truevel"):
        return lambda env: Fresh(env, float(name[7:]))
    if name.startswith("extrapc"):
        return lambda env: Extrap(env, float(name[7:]), True)
    if name.startswith("extrap"):
        return lambda env: Extrap(env, float(name[6:]), False)
    if name.startswith("drift"):
        return lambda env: Drift(env, float(name[5:]))
    return controller_factory(name, loaded)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--missions", required=True)
    ap.add_argument("--methods", required=True)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=4242)
    ap.add_argument("--tup", default="15")
    ap.add_argument("--out", default=None)
    ap.add_argument("--failure-prob", type=float, default=0.0)
    a = ap.parse_args()
    assert a.seed < 1_000_000_000, "probes use training twin seeds only"
    methods = a.methods.split(",")
    loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
    print(f"seed {a.seed} episodes {a.episodes}", flush=True)
    out = {}
    for mname in a.missions.split(","):
        for tup in [int(x) for x in a.tup.split(",")]:
            m = load_mission(mname if "/" in mname else HERE / f"{mname}.yaml").with_tup(tup)
            cov = {}
            for meth in methods:
                t0 = time.process_time()
                cov[meth] = run_method(m, factory(meth, loaded), a.episodes, a.seed, batch=a.episodes,
                                       failure_prob=a.failure_prob).coverage
                cpu = time.process_time() - t0
                line = f"{mname} T_up {tup} {meth:16s} {cov[meth].mean():.4f}"
                if meth != "service" and "service" in cov:
                    d = cov[meth] - cov["service"]
                    pw = stats.wilcoxon(cov[meth], cov["service"]).pvalue if np.any(d != 0) else 1.0
                    pm = stats.mannwhitneyu(cov[meth], cov["service"]).pvalue
                    line += f"  d {d.mean():+.4f} w/l {(d > 0).sum()}/{(d < 0).sum()} pW {pw:.2g} pMWU {pm:.2g}"
                print(line + f"  cpu {cpu:.0f}s", flush=True)
                out[f"{mname}@{tup}/{meth}"] = cov[meth].tolist()
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "episodes": a.episodes, "coverage": out}, indent=1))


if __name__ == "__main__":
    main()
