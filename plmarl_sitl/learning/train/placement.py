"""Train the placement scorer (issue 24.3, model/placement.py `LearnedPlacement`) by imitation.

CTDE: the TEACHER sees the true users: its plan is `SearchPlacement`'s search on the users'
true positions (each user's weight on its nearest sub-point instead of spread over its cell);
the STUDENT sees only what every agent has, the demand map, through `PickState.features`.
Episodes: the layouts of training missions (random connected layouts, the failure families'
clusters, lattices), users drawn and moved by the twin's user model from training twin seeds
(learning/train/seeds.py), plans for N and for N - 1 .. N - 2 survivors (failures). Each map
gives a pick sequence: the teacher's points in the order the greedy could have picked them
(at each step the remaining teacher point of the largest marginal gain on the map that is
allowed); each step whose candidate list (`PickState.top`) holds a remaining teacher point
is one sample, its loss -log of the scorer's softmax mass on those points.

    python -m plmarl_sitl.learning.train.placement --out policies/pl-marl --seed 7 --maps 400 --epochs 60
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from plmarl_sitl.config import REPO_ROOT
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.nn.placement import PlacementScorer, export
from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map
from plmarl_sitl.model.placement import PickState, SearchPlacement
from plmarl_sitl.model.service import GRID_M, ServiceGrid, grid_counts
from plmarl_sitl.model.users import init_users, step_users

TRAIN_MISSIONS = ("missions/suite/random_layout.yaml", "missions/suite/failure_2of6_a.yaml",
                  "missions/suite/failure_2of6_b.yaml", "missions/suite/failure_split.yaml",
                  "missions/suite/n8.yaml", "missions/suite/n20_random.yaml", "missions/paper_urban.yaml")


def true_weights(grid: ServiceGrid, xy: np.ndarray) -> np.ndarray:
    """(S,) the users xy (U, 2) on their nearest sub-point, in the map's units (sub^2 per user)."""
    cell_r = np.clip(np.floor(xy[:, 0] / grid.cell_m), 0, grid.rows - 1).astype(np.int64)
    cell_c = np.clip(np.floor(xy[:, 1] / grid.cell_m), 0, grid.cols - 1).astype(np.int64)
    step = grid.cell_m / grid.sub
    si = np.clip(np.floor((xy[:, 0] - cell_r * grid.cell_m) / step), 0, grid.sub - 1).astype(np.int64)
    sj = np.clip(np.floor((xy[:, 1] - cell_c * grid.cell_m) / step), 0, grid.sub - 1).astype(np.int64)
    idx = (cell_r * grid.cols + cell_c) * grid.sub * grid.sub + si * grid.sub + sj
    return np.bincount(idx, minlength=len(grid.subpts)).astype(np.float64) * grid.sub * grid.sub


def teacher_order(state: PickState, teacher: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Roll the teacher's picks through the student's state; -> samples (features, target mask)."""
    left = list(dict.fromkeys(int(t) for t in teacher))
    out = []
    while left and len(state.picks) < state.n:
        sc = state.score()
        ok = [t for t in left if sc[t] >= 0] or left
        nxt = max(ok, key=lambda t: (sc[t], -t))
        top = state.top()
        # a candidate one lattice step (or a diagonal one) from a remaining teacher point counts
        # as that point: neighbours 25 m apart serve nearly the same users
        g = state.grid
        lp = np.asarray(left)
        d2 = (g.cand_n[top, None] - g.cand_n[None, lp]) ** 2 + (g.cand_e[top, None] - g.cand_e[None, lp]) ** 2
        mask = (d2 <= 2.0 * GRID_M * GRID_M + 1e-6).any(-1)
        if mask.any() and len(top) > 1:
            out.append((state.features(top), mask))
        state.pick(nxt)
        left.remove(nxt)
    return out


def episodes(maps: int, seed: int, minutes: tuple[int, ...] = (0, 2, 5)) -> list[tuple[ServiceGrid, np.ndarray, np.ndarray, int]]:
    """(grid, map counts (K,), true sub-point weights (S,), points n) for `maps` maps."""
    out = []
    per = max(1, maps // (len(TRAIN_MISSIONS) * len(minutes) * 3))
    for v, path in enumerate(TRAIN_MISSIONS):
        m = load_mission(REPO_ROOT / path)
        grid = service_grid(m)
        gen = torch.Generator().manual_seed(training_twin_seed(seed * 1000 + v))
        users = init_users(m, per, gen, torch.float64)
        centres = cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, torch.float64)
        t = 0
        for minute in minutes:
            while t < minute * 60:
                users = step_users(users, m, 1.0, gen)
                t += 1
            xy = users.xy
            counts = demand_map(xy, m.area.north_m, m.area.east_m, m.demand.cell_m)
            for b in range(per):
                row = grid_counts(demand_cells(counts[b], centres).numpy(), grid)
                tw = true_weights(grid, xy[b].numpy())
                for n in (m.n_uavs, max(1, m.n_uavs - 1), max(1, m.n_uavs - 2)):
                    out.append((grid, row, tw, n))
    return out[:maps] if len(out) > maps else out


def samples(eps: list[tuple[ServiceGrid, np.ndarray, np.ndarray, int]], teacher_sees: str = "truth") -> list[tuple[np.ndarray, np.ndarray]]:
    """Teacher `truth`: the search on the users' true sub-points (CTDE); `map`: on the map itself."""
    teacher = SearchPlacement()
    out = []
    for grid, row, tw, n in eps:
        w = tw if teacher_sees == "truth" else grid.sub_weights(row)
        picks, _ = teacher.search(grid, w, grid.weight_gains(w), n)
        out += teacher_order(PickState(grid, row, n), list(picks))
    return out


def loss_of(model: PlacementScorer, batch: list[tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    total = torch.zeros((), dtype=torch.float64)
    for x, mask in batch:
        logp = torch.log_softmax(model(x), 0)
        total = total - torch.logsumexp(logp[mask], 0)
    return total / len(batch)


def train(maps: int, epochs: int, seed: int, out: Path, hidden: int = 32, teacher_sees: str = "truth",
          log=print) -> dict:  # noqa: ANN001 - log
    """Build the samples, fit, export out/placement.pt and out/placement.yaml; -> the card."""
    torch.manual_seed(seed)
    t0 = time.time()
    eps = episodes(maps, seed)
    data = [(torch.from_numpy(x), torch.from_numpy(mk)) for x, mk in samples(eps, teacher_sees)]
    if not data:
        raise UserError("placement training: no samples (too few --maps)")
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(data))
    cut = max(1, len(data) // 10)
    val = [data[i] for i in order[:cut]]
    fit = [data[i] for i in order[cut:]] or val
    log(f"placement: seed {seed}, {len(eps)} maps, {len(fit)} train / {len(val)} val samples ({time.time() - t0:.0f} s)")
    model = PlacementScorer(hidden).double()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    curve = []
    for ep in range(epochs):
        model.train()
        perm = rng.permutation(len(fit))
        for lo in range(0, len(fit), 64):
            opt.zero_grad()
            loss = loss_of(model, [fit[i] for i in perm[lo:lo + 64]])
            loss.backward()
            opt.step()
        with torch.no_grad():
            model.eval()
            v = float(loss_of(model, val))
            hit = float(np.mean([bool(mk[int(model(x).argmax())]) for x, mk in val]))
            first = float(np.mean([bool(mk[0]) for _, mk in val]))  # the greedy's pick (rank 0) is a teacher point
        curve.append({"epoch": ep, "val_loss": v, "val_top1": hit, "greedy_top1": first})
        log(f"epoch {ep}: val loss {v:.4f}, top-1 {hit:.3f} (greedy's pick {first:.3f})")
        out.mkdir(parents=True, exist_ok=True)
        torch.save(model.state_dict(), out / "placement_checkpoint.pth")  # a stopped run keeps its last epoch
    path = out / "placement.pt"
    export(model, path)
    card = {"what": "placement scorer of `placement: learned` (model/placement.py LearnedPlacement, issue 24.3)",
            "features": "model/placement.py PickState.features", "top": "model/placement.py TOP",
            "teacher": ("SearchPlacement on the users' true sub-point positions (CTDE: the teacher only)" if teacher_sees == "truth"
                        else "SearchPlacement on the demand map (what every agent has)"),
            "training": {"seed": seed, "maps": len(eps), "epochs": epochs, "hidden": hidden, "missions": list(TRAIN_MISSIONS),
                         "samples": len(data), "command": " ".join(["python -m plmarl_sitl.learning.train.placement"] + sys.argv[1:])},
            "result": curve[-1] if curve else {}, "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    (out / "placement.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    (out / "placement_curve.jsonl").write_text("".join(json.dumps(c) + "\n" for c in curve))
    return card


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="train the learnt placement scorer (issue 24.3) by imitation of a CTDE teacher")
    ap.add_argument("--out", type=Path, required=True, help="directory for placement.pt and placement.yaml")
    ap.add_argument("--seed", type=int, default=7, help="training seed (twin seeds seed * 1000 + v)")
    ap.add_argument("--maps", type=int, default=400)
    ap.add_argument("--epochs", type=int, default=60)
    ap.add_argument("--hidden", type=int, default=32)
    ap.add_argument("--teacher", choices=("truth", "map"), default="truth",
                    help="what the teacher's search sees: the true users (CTDE) or the demand map")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    try:
        if a.maps < 1 or a.epochs < 1 or a.hidden < 1:
            raise UserError("--maps, --epochs and --hidden must be >= 1")
        train(a.maps, a.epochs, a.seed, a.out, a.hidden, a.teacher)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
