"""Scene figures: box wireframes land where the pinhole model puts them; the PNG is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from isa.camera import Intrinsics
from isa.data.sunrgbd import UPRIGHT_FROM_CAMERA_AXES, SceneFrame
from isa.evaluation.boxes3d import Box3D
from isa.report.figures.scenes import box_edges_image, scene_figure

K = Intrinsics(fx=500.0, fy=500.0, cx=159.5, cy=119.5, width=320, height=240)


def level_frame(boxes=()):
    depth = np.full((240, 320), 4.0, np.float32)
    depth[:, :40] = 0
    return SceneFrame("synthetic", depth, K, UPRIGHT_FROM_CAMERA_AXES.copy(), tuple(boxes), Path("."))


def test_box_edges_project_analytically():
    # Level camera; a 1 x 1 x 1 box centred 3 m ahead on the optical axis. Its near face (y = 2.5)
    # spans u = cx +- fx * 0.5 / 2.5 and v = cy +- fy * 0.5 / 2.5.
    box = Box3D("chair", (0, 3, 0), (1, 1, 1), 0.0)
    segs = box_edges_image(level_frame(), box)
    assert len(segs) == 12
    pts = np.concatenate(segs)
    assert pts[:, 0].min() == pytest.approx(159.5 - 100.0)
    assert pts[:, 0].max() == pytest.approx(159.5 + 100.0)
    assert pts[:, 1].min() == pytest.approx(119.5 - 100.0)
    assert pts[:, 1].max() == pytest.approx(119.5 + 100.0)


def test_box_edges_behind_and_across_the_camera():
    assert box_edges_image(level_frame(), Box3D("chair", (0, -3, 0), (1, 1, 1), 0.0)) == []
    segs = box_edges_image(level_frame(), Box3D("bed", (0, 0.5, 0), (2, 2, 1), 0.3), near=0.1)
    assert 0 < len(segs) < 12 and all(np.all(np.isfinite(s)) for s in segs)


def test_scene_figure_writes_png(tmp_path):
    gt = Box3D("chair", (0, 3, 0), (1, 1, 1), 0.0)
    pred = gt.replace(centre=(0.2, 3.1, 0), score=0.6)
    out = scene_figure(level_frame([gt]), [pred], tmp_path / "fig" / "scene.png")
    with Image.open(out) as im:
        assert im.size[0] > 600 and im.size[1] > 200
