"""Size-aware settings of the pipeline (feature reach, voting kernel) on analytic training sets."""

from __future__ import annotations

import numpy as np
import pytest

from isa import pipeline
from isa.exceptions import DataError
from isa.privileged.annotate import TrainingSet


def _training_set(offsets: np.ndarray) -> TrainingSet:
    n = len(offsets)
    return TrainingSet(images=[np.ones((4, 4), np.uint16)], parts=np.zeros((n, 3), np.int32),
                       offsets=offsets.astype(np.float32), rotations=np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32),
                       link_angles=np.zeros((n, 1), np.float32), node_offsets=np.zeros((n, 3), np.float32),
                       crops=np.zeros((1, 2), int))


def test_diameter_is_twice_the_95th_percentile_distance():
    # Distances 0.01, 0.02, ..., 1.00 m along random directions: the 95th percentile is 0.9505.
    rng = np.random.default_rng(0)
    d = np.arange(1, 101) / 100
    u = rng.normal(size=(100, 3))
    ts = _training_set(u / np.linalg.norm(u, axis=1, keepdims=True) * d[:, None])
    assert pipeline.parts_diameter(ts) == pytest.approx(2 * 0.9505, rel=1e-5)


def test_max_offset_scales_with_size_and_focal_length_and_is_clipped():
    ts = _training_set(np.tile([1.0, 0, 0], (10, 1)))  # diameter 2 m
    fx = 500.0
    assert pipeline.scaled_max_offset(ts, fx) == pytest.approx(pipeline.PROBE_REACH * 2 * fx, rel=1e-6)
    assert pipeline.scaled_max_offset(ts, 2 * fx) == pytest.approx(2 * pipeline.scaled_max_offset(ts, fx), rel=1e-6)
    tiny = _training_set(np.tile([1e-4, 0, 0], (10, 1)))
    assert pipeline.scaled_max_offset(tiny, fx) == 50.0
    huge = _training_set(np.tile([100.0, 0, 0], (10, 1)))
    assert pipeline.scaled_max_offset(huge, fx) == 2000.0
    assert pipeline.scaled_predict_defaults(ts)["position_bandwidth"] == pytest.approx(pipeline.VOTE_BANDWIDTH * 2, abs=1e-4)


def test_empty_training_set_is_a_data_error():
    with pytest.raises(DataError, match="no parts"):
        pipeline.parts_diameter(_training_set(np.zeros((0, 3))))


def test_predict_reads_the_models_defaults_and_explicit_parameters_win():
    from isa.camera import Intrinsics
    from isa.forest.model import Forest, ForestParams
    from test_vote import K, plate, plate_training_set

    images, parts, offsets, rotations = plate_training_set()
    f = Forest(ForestParams(n_trees=2, max_depth=10, n_candidates=30, max_offset=60.0, quality="Q1"))
    f.fit(images, parts, offsets, rotations, metadata={"predict_defaults": {"stride": 2}})
    depth, _ = plate(centre=(0.02, 0.0, 1.5))
    intr = Intrinsics.from_K(K, depth.shape[1], depth.shape[0])
    depth_m = depth.astype(np.float32) / 1000
    s2 = f.core.predict(depth_m, K, stride=2)[0]["support"]
    s4 = f.core.predict(depth_m, K, stride=4)[0]["support"]
    assert s2 > 2 * s4  # a quarter of the parts at stride 4
    assert pipeline.predict(f, depth_m, intr)[0]["support"] == s2  # the model's default
    assert pipeline.predict(f, depth_m, intr, stride=4)[0]["support"] == s4  # explicit wins
