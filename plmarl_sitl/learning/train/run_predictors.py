"""Record twin trajectories and train the inference engines (phi and the GRU baseline).

    python -m plmarl_sitl.learning.train.run_predictors missions/paper_urban.yaml --out runs/predictors

Writes <out>/{mlp,gru}.pt (state dicts), <out>/errors.json (position error at P-AoI
10/25/50 s on held-out trajectories, learnt vs dead reckoning) and the loss curves.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from plmarl_sitl.learning.nn.belief import BeliefTracker
from plmarl_sitl.learning.nn.predictor import make_predictor
from plmarl_sitl.learning.train.predictor import (
    PredictorArgs,
    dead_reckoning_tracker,
    pair_rows,
    position_errors,
    train_predictor,
)
from plmarl_sitl.learning.train.trajectories import mixed_mobility, record
from plmarl_sitl.mission import load_mission

# The greedy reference's share (key "oracle", its name when these mixes were fixed) is the largest: trained policies imitate it first (train/imitation.py).
DATA_MIX = {"oracle": 96, "heuristic": 64, "waypoint": 96, "ou": 64}


def build_dataset(mission, seed: int, scale: float = 1.0) -> dict[str, torch.Tensor]:
    m = mixed_mobility(mission)
    return {c: record(m, c, max(2, int(n * scale)), seed + k)[0] for k, (c, n) in enumerate(DATA_MIX.items())}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mission")
    ap.add_argument("--out", default="runs/predictors")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mlp-iters", type=int, default=1500)
    ap.add_argument("--gru-iters", type=int, default=300)
    ap.add_argument("--kinds", default="mlp,gru")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(a.seed)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    mission = load_mission(a.mission)
    t0 = time.time()
    train = build_dataset(mission, a.seed)
    test = build_dataset(mission, a.seed + 1000, scale=0.25)
    print(f"data recorded in {time.time() - t0:.0f} s", flush=True)
    gen = torch.Generator().manual_seed(a.seed)
    x, o = zip(*(pair_rows(v, gen) for v in train.values()), strict=True)
    x, o = torch.cat(x), torch.cat(o)
    vm = mission.vehicle_model()
    errors: dict = {"dead-reckoning": {c: position_errors(dead_reckoning_tracker(), pair_rows(v, gen)[0]) for c, v in test.items()}}
    for kind in a.kinds.split(","):
        trk = BeliefTracker(make_predictor(kind, v_max=vm.max_speed_mps, a_max=vm.max_accel_mps2))
        iters = a.mlp_iters if kind == "mlp" else a.gru_iters
        rows = 512 if kind == "mlp" else 256
        t1 = time.time()
        curve = train_predictor(trk, x, o, PredictorArgs(iters=iters, rows=rows, seed=a.seed), log=lambda s: print(s, flush=True))
        wall = time.time() - t1
        torch.save(trk.predictor.state_dict(), out / f"{kind}.pt")
        (out / f"{kind}_curve.json").write_text(json.dumps(curve))
        errors[kind] = {c: position_errors(trk, pair_rows(v, gen)[0]) for c, v in test.items()}
        errors[kind]["train_wall_s"] = wall
        print(kind, json.dumps(errors[kind]), flush=True)
        (out / "errors.json").write_text(json.dumps(errors, indent=1))
    print(json.dumps(errors, indent=1))


if __name__ == "__main__":
    main()
