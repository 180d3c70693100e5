"""Issue 17's Scan2CAD count (isa.detection.evaluate.found_within) on hand-placed cases: a chair
found within 10 cm and 20 degrees, one off by 15 cm, one turned by 30 degrees, a table with its
yaw not counted, a hidden chair left out."""

from __future__ import annotations

import math

import numpy as np

from isa.evaluation.boxes3d import rot_z


def _gt(category, t, yaw, visib=1.0):
    from isa.scenes.io import GroundTruth

    return GroundTruth(1, category, rot_z(yaw), np.asarray(t, float), np.array([0.5, 0.5, 0.9]), visib, [np.eye(3)],
                       np.zeros((1, 3)))


def _det(category, t, yaw):
    from isa.scenes.scoring import Detection

    return Detection(category, rot_z(yaw), np.asarray(t, float), np.array([0.5, 0.5, 0.9]), 1.0)


def test_found_within_counts_centre_and_yaw():
    from isa.detection.evaluate import found_within

    g = np.eye(3)  # upright camera: the object frames' z is up
    gts = [[_gt("chair", (0, 2, 0), 0.3), _gt("chair", (1, 2, 0), 0.0), _gt("chair", (2, 2, 0), 0.0),
            _gt("chair", (3, 2, 0), 0.0, visib=0.4), _gt("table", (0, 4, 0), 0.0)]]
    dets = [[_det("chair", (0.05, 2.05, 0), 0.3 + math.radians(10)),  # found
             _det("chair", (1.15, 2, 0), 0.0),  # 15 cm off
             _det("chair", (2, 2, 0), math.radians(30)),  # turned too far
             _det("chair", (3, 2, 0), 0.0),  # right, but the chair is less than half visible
             _det("toilet", (1, 2, 0), 0.0),  # another category
             _det("table", (0, 4.08, 0), 2.0)]]  # a table: the centre only
    assert found_within(gts, dets, [g], "chair") == (1, 3)
    assert found_within(gts, dets, [g], "chair", max_yaw_deg=None) == (2, 3)
    assert found_within(gts, dets, [g], "table", max_yaw_deg=None) == (1, 1)
    assert found_within(gts, dets, [g], "table") == (0, 1)
