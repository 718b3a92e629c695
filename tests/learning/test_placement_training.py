"""The placement scorer's training path (learning/train/placement.py) on a tiny config: it
writes a TorchScript scorer that `placement: learned` loads and its card (sha256 of the file,
teacher, seeds), the teacher's samples hold the teacher's points, and bad input is a one-line
error with exit 2. CI never trains a real scorer."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch
import yaml

from plmarl_sitl.learning.nn.placement import load_placement_scorer
from plmarl_sitl.learning.train.placement import episodes, main, samples, train, true_weights
from plmarl_sitl.model.placement import FEATURES, LearnedPlacement


def test_tiny_training_writes_a_scorer_the_plan_loads(tmp_path: Path) -> None:
    card = train(maps=8, epochs=2, seed=3, out=tmp_path, hidden=8, log=lambda _: None)
    path = tmp_path / "placement.pt"
    assert card["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert yaml.safe_load((tmp_path / "placement.yaml").read_text())["training"]["seed"] == 3
    scorer = load_placement_scorer(path)
    x = torch.rand(5, FEATURES, dtype=torch.float64)
    assert scorer(x).shape == (5,) and torch.equal(scorer(x), load_placement_scorer(path)(x))
    grid, row, _, n = episodes(4, 3)[0]
    pts, served = LearnedPlacement(scorer).place(grid, row[None], n)
    assert pts.shape == (1, n, 2) and np.allclose(grid.served(row[None], pts), served)


def test_teacher_samples_mark_the_teachers_points() -> None:
    eps = episodes(4, 5)
    grid, row, tw, _ = eps[0]
    assert tw.sum() == row.sum() * grid.sub * grid.sub  # every user on one sub-point, in the map's units
    data = samples(eps)
    assert data and all(x.shape[1] == FEATURES and m.any() for x, m in data)


def test_true_weights_put_a_user_on_its_nearest_sub_point() -> None:
    grid = episodes(1, 1)[0][0]
    w = true_weights(grid, np.array([[10.0, 10.0], [40.0, 10.0]]))
    hit = np.flatnonzero(w)
    assert np.allclose(grid.subpts[hit], [[12.5, 12.5], [37.5, 12.5]])


def test_bad_input_is_a_one_line_error(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    assert main(["--out", str(tmp_path), "--maps", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err
