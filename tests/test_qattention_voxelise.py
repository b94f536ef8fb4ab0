"""Voxel grid of spec §2: where points land, what is dropped, and the index <-> world helpers."""

import torch

from qattention.voxelise import child_bounds, flat_index, point_to_voxel_index, unflatten_index, voxel_centre, voxelise

BOUNDS = torch.tensor([-0.3, -0.5, 0.6, 0.7, 0.5, 1.6])  # the reference's 1 m cube
V = 16


def test_voxel_index_world_round_trip():
    idx = torch.stack(torch.meshgrid(*[torch.arange(V)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres = voxel_centre(idx, BOUNDS, V)
    assert torch.equal(point_to_voxel_index(centres, BOUNDS, V), idx)
    # the centre sits half a voxel (3.125 cm) above the corner on every axis
    assert torch.allclose(centres[0], BOUNDS[:3] + 1.0 / 32)
    assert torch.equal(unflatten_index(flat_index(idx, V), V), idx)


def test_point_lands_in_the_voxel_the_spec_says():
    p = torch.tensor([[0.0, 0.0, 1.0]])  # 0.3/0.0625 = 4.8, 0.5/0.0625 = 8.0, 0.4/0.0625 = 6.4
    assert point_to_voxel_index(p, BOUNDS, V).tolist() == [[4, 8, 6]]
    grid = voxelise(p[None], torch.tensor([[[1.0, -1.0, 0.0]]]), BOUNDS, V)
    assert grid.shape == (1, 10, V, V, V)
    cell = grid[0, :, 4, 8, 6]
    # [mean xyz, mean rgb, i/V, j/V, k/V, occupancy]
    torch.testing.assert_close(cell, torch.tensor([0.0, 0.0, 1.0, 1.0, -1.0, 0.0, 4 / V, 8 / V, 6 / V, 1.0]))
    assert grid[0, 9].sum() == 1


def test_features_are_averaged_per_voxel():
    pts = torch.tensor([[[-0.04, 0.01, 1.01], [0.0, 0.03, 1.03]]])  # both in voxel (4, 8, 6)
    rgb = torch.tensor([[[1.0, 0.0, -1.0], [0.0, 0.0, 1.0]]])
    grid = voxelise(pts, rgb, BOUNDS, V)
    i, j, k = point_to_voxel_index(pts[0, 0], BOUNDS, V).tolist()
    torch.testing.assert_close(grid[0, :6, i, j, k], torch.cat([pts[0].mean(0), rgb[0].mean(0)]))


def test_out_of_bounds_and_invalid_points_are_dropped():
    outside = torch.tensor([[[-0.31, 0.0, 1.0], [0.7, 0.0, 1.0], [0.0, 0.6, 1.0], [0.0, 0.0, 0.5],
                             [float("nan"), 0.0, 1.0], [0.0, 0.0, float("inf")]]])  # noqa: E127
    grid = voxelise(outside, torch.zeros_like(outside), BOUNDS, V)
    assert grid[0, 9].sum() == 0  # max is exclusive, as with the reference's padding shell
    inside = torch.tensor([[[0.699, 0.499, 1.599]]])
    assert voxelise(inside, torch.zeros_like(inside), BOUNDS, V)[0, 9, 15, 15, 15] == 1


def test_empty_grid_stays_zero():
    grid = voxelise(torch.zeros(2, 0, 3), torch.zeros(2, 0, 3), BOUNDS, V)
    assert grid.shape == (2, 10, V, V, V)
    assert grid[:, :6].abs().sum() == 0 and grid[:, 9].sum() == 0
    # only the index channels are non-zero, as in the reference
    assert torch.allclose(grid[0, 6, 3], torch.full((V, V), 3 / V))


def test_per_sample_bounds_in_one_batch():
    torch.manual_seed(0)
    centres = torch.tensor([[0.0, 0.0, 1.0], [0.3, -0.2, 0.9]])
    bounds = child_bounds(centres, 0.15)  # two depth-1 cubes of 0.30 m
    torch.testing.assert_close(bounds[1], torch.tensor([0.15, -0.35, 0.75, 0.45, -0.05, 1.05]))
    pts = centres[:, None] + (torch.rand(2, 500, 3) - 0.5) * 0.4  # some inside, some outside
    grid = voxelise(pts, torch.zeros_like(pts), bounds, V)
    for b in range(2):
        inside = ((pts[b] >= bounds[b, :3]) & (pts[b] < bounds[b, 3:])).all(-1)
        idx = point_to_voxel_index(pts[b][inside], bounds[b], V)
        expected = torch.zeros(V, V, V)
        expected[idx[:, 0], idx[:, 1], idx[:, 2]] = 1
        assert torch.equal(grid[b, 9], expected)
