"""Wrong-category rejection (isa.evaluation.rejection): threshold choice and rates on known scores
(a brute-force search is the reference)."""

import numpy as np
import pytest

from isa.evaluation import rejection


def test_separable_scores_get_a_threshold_between_them():
    own, other = np.array([0.5, 0.6, 0.7]), np.array([0.1, 0.2, 0.3])
    t = rejection.choose_threshold(own, other)
    assert 0.3 < t <= 0.5
    assert rejection.rates(own, other, t) == (1.0, 1.0)


def test_overlapping_scores_maximise_balanced_accuracy_by_brute_force():
    rng = np.random.default_rng(3)
    own, other = rng.normal(1.0, 1.0, 40), rng.normal(0.0, 1.0, 60)
    t = rejection.choose_threshold(own, other)
    best = max(np.mean(rejection.rates(own, other, c)) for c in np.linspace(-4, 5, 4001))
    assert np.mean(rejection.rates(own, other, t)) >= best - 1e-12


def test_frames_without_a_score_are_rejected():
    own, other = np.array([0.4, np.nan]), np.array([np.nan, 0.1])
    t = rejection.choose_threshold(own, other)
    assert rejection.rates(own, other, t) == (0.5, 1.0)


def test_threshold_needs_both_kinds_of_frames():
    with pytest.raises(ValueError, match="own category and of others"):
        rejection.choose_threshold(np.array([]), np.array([0.1]))


def test_summary_applies_given_thresholds_unchanged():
    fs = lambda *v: rejection.FrameScores(np.array(v), np.array(v) / 10, np.full(len(v), np.nan))  # noqa: E731
    cross = {"chair": {"chair": fs(5.0, 6.0), "table": fs(1.0, 5.5)}, "table": {"table": fs(4.0), "chair": fs(2.0)}}
    table, used = rejection.summarise(cross, {"chair": {"score": 5.2, "vote_share": 0.52}, "table": {"score": 3.0,
                                                                                                   "vote_share": 0.3}})
    assert used["chair"]["score"] == 5.2
    assert table["chair"]["score"]["accept_own"] == 50.0 and table["chair"]["score"]["reject"]["table"] == 50.0
    assert "verified" not in table["chair"]  # no shapes: no verified score


def test_first_frames_take_every_instance_in_turn():
    from types import SimpleNamespace

    # as pipeline.load_frames lists them: scene (instance) by scene, 3 views each
    frames = [SimpleNamespace(obj_id=o, im_id=i) for o in (1001, 1002, 1003, 1004) for i in range(3)]
    picked = rejection.first_frames(frames, 6)
    assert sorted((f.obj_id, f.im_id) for f in picked) == sorted(
        [(o, 0) for o in (1001, 1002, 1003, 1004)] + [(1001, 1), (1002, 1)])
    assert len(rejection.first_frames(frames, 100)) == 12
