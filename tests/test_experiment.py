"""The experiment driver end to end on a tiny procedural run: the chosen object-frame origin
reaches the rendered ground truth, the model file and results.json; --mirror adds flipped views."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from isa import experiment  # noqa: E402
from isa.forest.model import Forest  # noqa: E402


@pytest.mark.parametrize("centre, mirror", [("box", False), ("com", True)])
def test_tiny_procedural_run_uses_the_chosen_origin(tmp_path, centre, mirror):
    out = tmp_path / "run"
    experiment.main(["--procedural", "--out", str(out), "--categories", "toilet", "--train-instances", "2",
                     "--test-instances", "1", "--views", "6", "--test-images", "2", "--qualities", "Q1",
                     "--trees", "2", "--depth", "6", "--candidates", "8", "--stride", "8", "--no-linemod",
                     "--centre", centre] + (["--mirror"] if mirror else []))
    res = json.loads((out / "results.json").read_text())
    cat = res["categories"]["toilet"]
    # Procedural toilets are symmetric left to right: --mirror doubles the 2 x 6 training views.
    assert cat["train_images"] == (24 if mirror else 12)
    assert cat.get("mirrored_instances") == (2 if mirror else None)
    assert cat["centre"] == centre and res["config"]["centre"] == centre
    isa_q1 = cat["isa"]["Q1"]
    assert 0.0 <= isa_q1["recall_at_0.1"] <= isa_q1["recall_at_0.1_symmetric"] <= 100.0  # ADD-S never stricter
    assert Forest.load(out / "models" / "toilet-Q1.isa").metadata["centre"] == centre
    # Independent check on the written ground truth: the BOP models (mm) are centred on the origin.
    for ply in sorted((out / "data" / "toilet" / "models").glob("*.ply")):
        mesh = trimesh.load(ply, process=False)
        mesh.apply_scale(0.001)
        if centre == "box":
            np.testing.assert_allclose(mesh.bounds.mean(0), 0, atol=1e-3)
        else:
            # The solid's centre of mass, to within a voxel of the 80-voxel grid.
            from isa.privileged.ssc import centre_of_mass

            np.testing.assert_allclose(centre_of_mass(mesh), 0, atol=mesh.extents.max() / 80 + 1e-3)


def test_unknown_centre_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        experiment.parser().parse_args(["--procedural", "--out", "x", "--centre", "middle"])
    assert "--centre" in capsys.readouterr().err


def test_canonical_labels_and_the_symmetry_ceiling_reach_results_json(tmp_path):
    out = tmp_path / "run"
    experiment.main(["--procedural", "--out", str(out), "--categories", "table", "--train-instances", "2",
                     "--test-instances", "1", "--views", "6", "--test-images", "2", "--qualities", "Q1",
                     "--trees", "2", "--depth", "6", "--candidates", "8", "--stride", "8", "--no-linemod",
                     "--canonical"])
    cat = json.loads((out / "results.json").read_text())["categories"]["table"]
    # Procedural tables are rectangles or squares on four legs: every one has a turn symmetry (C2 or C4),
    # so a symmetry-blind estimator is right at most half the time.
    assert cat["canonical_instances"] == 2
    assert set(cat["symmetry"]["orders"].values()) <= {2, 4}
    assert 0.0 < cat["symmetry"]["ceiling_at_0.1"] <= 50.0
    assert "Ceiling: any estimator blind to symmetry" in (out / "report.md").read_text()


@pytest.mark.slow
def test_scene_section_runs_the_baseline_and_the_detector(tmp_path):
    """With --scenes the report holds the one-class baseline and the detector on the same rooms;
    each model gets its shape library beside it, and rankers are written for every category or
    for none."""
    out = tmp_path / "run"
    experiment.main(["--procedural", "--out", str(out), "--categories", "chair", "--train-instances", "2",
                     "--test-instances", "1", "--views", "6", "--test-images", "2", "--qualities", "Q1",
                     "--trees", "2", "--depth", "6", "--candidates", "8", "--stride", "8", "--no-linemod",
                     "--scenes", "2"])
    scenes = json.loads((out / "results.json").read_text())["scenes"]
    base, full = scenes["procedural rooms, one-class baseline"], scenes["procedural rooms, detector"]
    assert base["n_frames"] == full["n_frames"] == 4 and base["source"] == full["source"]
    assert "verify" in full["params"] and "verify" not in base["params"]
    assert (out / "models" / "chair-Q1.shapes.isl").is_file()
    ranker = (out / "models" / "chair-Q1.ranker.json").is_file()
    assert ("ranker: yes" in full["models"]["chair"]) == ranker
    text = (out / "report.md").read_text()
    assert "## Scenes: procedural rooms, one-class baseline" in text and "## Scenes: procedural rooms, detector" in text
