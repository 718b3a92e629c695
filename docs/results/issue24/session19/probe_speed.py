"""Session 19: how fast each UAV flies in a long transit (TRAINING twin seeds only).

usage: PYTHONPATH=. python probe_speed.py MISSION SEED EPISODES TUP METHODS
Prints, per method, the swarm's mean ground speed every 12 s up to 120 s and the mean ground
distance from each UAV to its nearest teammate (how tightly the swarm holds together).
"""

from __future__ import annotations

import sys

import torch

from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv


def main() -> None:
    path, seed, episodes, tup, methods = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5].split(",")
    training_twin_seed(seed)
    m = load_mission(path).with_tup(tup)
    loaded = {meth: load_policy(f"policies/{meth}", m) for meth in sorted(needed_policies(methods))}
    for meth in methods:
        with torch.inference_mode():
            env = CoverageEnv(m, episodes, seed)
            ctl = controller_factory(meth, loaded)(env)
            ctl.reset()
            obs = env.observe()
            rows = []
            while not env.done and obs.t <= 120:
                obs, _, _ = env.step(ctl.act(obs))
                if obs.t % 12 == 0:
                    pos, vel = obs.ego[..., :2], obs.ego[..., 3:5]
                    speed = vel.norm(dim=-1).mean()
                    d = torch.cdist(pos, pos) + torch.eye(pos.shape[1]) * 1e9
                    rows.append(f"t{obs.t}: v {speed:.1f} nn {d.min(-1).values.mean():.0f}")
        print(f"{meth:15s}", " | ".join(rows), flush=True)


if __name__ == "__main__":
    main()
