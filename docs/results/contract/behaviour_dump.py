"""Issue 24's behaviour check (docs/RESULTS.md, "One policy contract"): dump what the checkout
on PYTHONPATH does, to compare two checkouts bit for bit.

    PYTHONPATH=<old checkout> python behaviour_dump.py dump /tmp/old.pt
    PYTHONPATH=<new checkout> python behaviour_dump.py dump /tmp/new.pt
    python behaviour_dump.py compare /tmp/old.pt /tmp/new.pt

What it dumps: every shipped policy flown by the twin's LearnedController (paper mission,
T_up 10, 3 environments, seed 123, a node failing at 30 s, 40 decisions), and a tiny
`mappo.train` (tag-mappo, seed 3: imitation + MAPPO + validation; then without validation,
failures from episode 0 and actor updates from iteration 0: curve rows and the final actor).
Only public entry points are used, so the same script runs on both sides of the change.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile

import torch

SHIPPED = ["pl-marl", "gru", "tag-mappo", "wave1/pl-marl", "wave1/gru", "wave1/tag-mappo"]


def dump(path: str) -> None:
    from plmarl_sitl.config import PAPER_MISSION, PROJECT_POLICIES
    from plmarl_sitl.learning.eval.controllers import LearnedController
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.learning.train import mappo
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.twin.env import CoverageEnv

    torch.set_num_threads(1)
    out: dict = {}
    m = load_mission(PAPER_MISSION).with_tup(10)
    for name in SHIPPED:
        lp = load_policy(PROJECT_POLICIES / name)
        env = CoverageEnv(m, 3, 123, failure_prob=1.0, failure_at_s=30.0)
        ctl = LearnedController(lp.tracker, lp.policy, m)
        obs = env.reset()
        ctl.reset()
        acts = []
        while not env.done and obs.t < 120:
            a = ctl.act(obs)
            acts.append(a.clone())
            obs, _, _ = env.step(a)
        out[name] = torch.stack(acts)
    with tempfile.TemporaryDirectory() as tmp:
        args = mappo.Args(method="tag-mappo", seed=3, episodes=4, num_envs=2, imitation_rounds=2, imitation_episodes_per_round=2,
                          imitation_tup_chunks=1, validate_every=1, validation_batches=1, validation_envs=2, out=f"{tmp}/a")
        out["selection"] = mappo.train(args)["selection"]
        res = mappo.train(dataclasses.replace(args, validate_every=0, critic_warmup_iters=0, failure_start_episode=0,
                                              failure_prob=1.0, out=f"{tmp}/b"))
        out["actor"] = {k: v.clone() for k, v in res["actor"].state_dict().items()}
        with open(res["curve"]) as f:
            out["curve"] = [{k: v for k, v in json.loads(row).items() if k not in ("wall_s", "charts/SPS")} for row in f]
    torch.save(out, path)


def compare(old: str, new: str) -> int:
    a, b = (torch.load(p, weights_only=False) for p in (old, new))
    differ = 0
    for k in a:
        if isinstance(a[k], torch.Tensor):
            same = torch.equal(a[k], b[k])
        elif k == "actor":
            same = all(torch.equal(a[k][n], b[k][n]) for n in a[k])
        else:
            same = a[k] == b[k]
        print(k, "identical" if same else "DIFFERENT")
        differ += not same
    return 1 if differ else 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["dump"]:
        dump(sys.argv[2])
    else:
        raise SystemExit(compare(sys.argv[2], sys.argv[3]))
