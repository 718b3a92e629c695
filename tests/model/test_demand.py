"""The published user-density map (model/demand.py) and the failure-flag rule (model/signalling.py)."""

import torch

from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map, grid_shape
from plmarl_sitl.model.signalling import silent_in_range


def test_grid_covers_the_area_row_major_from_the_south_west_corner():
    assert grid_shape(1000.0, 1000.0, 100.0) == (10, 10)
    assert grid_shape(1050.0, 300.0, 100.0) == (11, 3)
    c = cell_centres(1000.0, 300.0, 100.0)
    assert c.shape == (30, 2)
    assert c[0].tolist() == [50.0, 50.0] and c[1].tolist() == [50.0, 150.0] and c[3].tolist() == [150.0, 50.0]


def test_counts_every_user_once_in_its_cell_and_border_cells_take_strays():
    xy = torch.tensor([[[5.0, 5.0], [150.0, 20.0], [199.9, 99.9], [-3.0, 2000.0], [999.0, 999.0]]])
    counts = demand_map(xy, 1000.0, 1000.0, 100.0)
    assert counts.shape == (1, 100) and float(counts.sum()) == 5.0
    assert counts[0, 0] == 1 and counts[0, 10] == 2 and counts[0, 9] == 1 and counts[0, 99] == 1
    valid = torch.tensor([[True, False, True, True, True]])
    assert float(demand_map(xy, 1000.0, 1000.0, 100.0, valid)[0, 10]) == 1.0


def test_shape_depends_on_the_area_only_not_on_users_or_batch():
    for b, u in ((1, 60), (3, 240), (2, 1200)):
        xy = torch.rand(b, u, 2) * 1000.0
        counts = demand_map(xy, 1000.0, 1000.0, 100.0)
        assert counts.shape == (b, 100) and torch.allclose(counts.sum(-1), torch.full((b,), float(u)))
        cells = demand_cells(counts, cell_centres(1000.0, 1000.0, 100.0))
        assert cells.shape == (b, 100, 3) and torch.equal(cells[..., 2], counts)


def test_failure_rule_predicted_in_range_yet_silent():
    own = torch.tensor([[0.0, 0.0, -100.0], [0.0, 0.0, -100.0]])
    belief = torch.tensor([[[200.0, 0.0, -100.0], [900.0, 0.0, -100.0]],    # receiver 0: near, far
                           [[900.0, 0.0, -100.0], [0.0, 349.0, -100.0]]])   # receiver 1: far, near
    dropped = torch.tensor([[False, True], [True, False]])  # only the far ones dropped: they flew away
    assert silent_in_range(dropped, belief, own, 350.0).tolist() == [False, False]
    dropped = torch.tensor([[True, False], [False, True]])  # the near ones went silent
    assert silent_in_range(dropped, belief, own, 350.0).tolist() == [True, True]
    assert silent_in_range(torch.zeros(2, 0, dtype=torch.bool), belief[:, :0], own, 350.0).tolist() == [False, False]
