"""The geometric top view: each cell's samples land where the camera sees its 3D points."""

from __future__ import annotations

import numpy as np
import torch
from tiny_net import tiny_config

from layouts import LayoutSpec
from layouts.camera import Intrinsics
from layouts.canonical import CanonicalView
from network.heads.geotop import NOMINAL_DISTANCE, NOMINAL_RACK_DEPTH, top_view_grid
from network.model.net import ModelConfig, MVRackLay

SPEC = LayoutSpec(num_slots=2, size=16)


def tiny(geo_top: bool = True, variant: str = "mvracklay-disc-4") -> ModelConfig:
    return tiny_config(SPEC, variant, geo_top=geo_top)


def test_every_sample_lands_where_the_camera_projects_its_point():
    """A camera with an off-centre principal point at the nominal distance; boards 0.4 m below and
    0.9 m above the optical axis. Each cell centre (X, Z) at each height h over its board is
    projected with the pinhole model and carried into the canonical image as the warp does."""
    view = CanonicalView(96, 64, SPEC.x_extent)
    intr = Intrinsics(fx=300.0, fy=310.0, cx=170.0, cy=115.0, width=320, height=240)
    d, m = NOMINAL_DISTANCE, view.metres_per_pixel
    boards_y = np.array([0.4, -0.9])  # camera frame, Y down: below and above the axis
    anchors = torch.tensor(view.row_of(boards_y), dtype=torch.float64)[None]  # (1, R) board rows
    heights = torch.tensor([0.0, 0.25, 0.6], dtype=torch.float64)
    cells = 8
    grid = top_view_grid(anchors, view, SPEC, cells, heights).numpy()  # (1, R*K, cells*cells, 2)
    assert grid.shape == (1, 2 * 3, cells * cells, 2)
    centres = (np.arange(cells) + 0.5) * (SPEC.size / cells)
    xs, zs = SPEC.col_to_x(centres), SPEC.row_to_a("top", centres)
    for r, yb in enumerate(boards_y):
        for k, h in enumerate(heights.tolist()):
            zz, xx = np.meshgrid(zs, xs, indexing="ij")  # (rows, cols): row 0 the far side
            pts = np.stack([xx.ravel(), np.full(xx.size, yb - h), d + zz.ravel() + NOMINAL_RACK_DEPTH / 2], 1)
            uv = intr.project(pts)
            col = (uv[:, 0] - intr.cx) * d / (intr.fx * m) + view.width / 2
            row = (uv[:, 1] - intr.cy) * d / (intr.fy * m) + view.height / 2
            want = np.stack([col * 2 / view.width - 1, row * 2 / view.height - 1], 1)
            np.testing.assert_allclose(grid[0, r * 3 + k], want, atol=1e-9)
    # the rack front lies inside the grid's rows, and a point farther back moves toward the axis
    front = grid[0, 0].reshape(cells, cells, 2)
    z_front = int(np.argmin(np.abs(zs + NOMINAL_RACK_DEPTH / 2)))
    assert abs(zs[z_front] + NOMINAL_RACK_DEPTH / 2) < SPEC.z_extent / cells
    far_left, near_left = grid[0, 0, 0], front[-1, 0]
    assert abs(far_left[0]) < abs(near_left[0])


def test_a_fresh_branch_changes_nothing_and_a_trained_one_does():
    torch.manual_seed(5)
    model = MVRackLay(tiny()).eval()
    plain = MVRackLay(tiny(geo_top=False)).eval()
    missing, unexpected = model.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("slots.geo.") for k in missing)
    x = torch.rand(1, 3, 3, 64, 64)
    a = torch.tensor([52.0, 30.0]).expand(1, 3, 2)
    with torch.no_grad():
        torch.testing.assert_close(model(x, a)["top"], plain(x, a)["top"])  # zero-initialised: the warm start
        torch.testing.assert_close(model(x, a)["front"], plain(x, a)["front"])
        torch.nn.init.normal_(model.slots.geo.out.weight, std=5.0)
        full = model(x, a)
        assert not torch.allclose(full["top"], plain(x, a)["top"], atol=1e-4)
        torch.testing.assert_close(full["front"], plain(x, a)["front"])  # the front view does not use it
        state = None
        for t in range(3):
            out, state = model.step(x[:, t], state, a[:, t])
            torch.testing.assert_close(out["top"], full["top"][:, t], rtol=1e-4, atol=1e-5)


def test_the_option_round_trips_and_older_records_load_without_it():
    cfg = tiny(variant="racklay")
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    d = cfg.to_dict()
    del d["geo_top"]
    assert ModelConfig.from_dict(d).geo_top is False
