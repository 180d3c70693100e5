"""The experiment driver end to end on a tiny procedural run: the chosen object-frame origin
reaches the rendered ground truth, the model file and results.json."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from isa import experiment  # noqa: E402
from isa.forest import Forest  # noqa: E402


@pytest.mark.parametrize("centre", ["box", "com"])
def test_tiny_procedural_run_uses_the_chosen_origin(tmp_path, centre):
    out = tmp_path / "run"
    experiment.main(["--procedural", "--out", str(out), "--categories", "toilet", "--train-instances", "2",
                     "--test-instances", "1", "--views", "6", "--test-images", "2", "--qualities", "Q1",
                     "--trees", "2", "--depth", "6", "--candidates", "8", "--stride", "8", "--no-linemod",
                     "--centre", centre])
    res = json.loads((out / "results.json").read_text())
    cat = res["categories"]["toilet"]
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
            from isa.ssc import centre_of_mass

            np.testing.assert_allclose(centre_of_mass(mesh), 0, atol=mesh.extents.max() / 80 + 1e-3)


def test_unknown_centre_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        experiment.parser().parse_args(["--procedural", "--out", "x", "--centre", "middle"])
    assert "--centre" in capsys.readouterr().err


def test_augmented_copies_are_trained_on_and_rendered_as_stretched_models(tmp_path):
    out = tmp_path / "aug"
    experiment.main(["--procedural", "--out", str(out), "--categories", "chair", "--train-instances", "2",
                     "--test-instances", "1", "--views", "3", "--test-images", "1", "--qualities", "Q1",
                     "--trees", "1", "--depth", "4", "--candidates", "4", "--stride", "8", "--no-linemod",
                     "--augment", "1", "--augment-stretch", "0.2"])
    cat = json.loads((out / "results.json").read_text())["categories"]["chair"]
    assert len(cat["train_instances"]) == 4 and sum("#stretch" in s for s in cat["train_instances"]) == 2
    assert cat["train_images"] == 4 * 3
    # The written models of the copies are the originals stretched (per-axis extents ratios in range).
    models = out / "data" / "chair" / "models"
    ext = {int(p.stem.split("_")[-1]): trimesh.load(p, process=False).extents for p in models.glob("*.ply")}
    originals = sorted(k for k in ext if k < 1000)
    copies = sorted(k for k in ext if k >= 100_000)
    assert len(originals) == 2 and len(copies) == 2
    for o, c in zip(originals, copies):
        ratio = ext[c] / ext[o]
        assert np.all((ratio > 1 / 1.2 - 1e-6) & (ratio < 1.2 + 1e-6)) and np.ptp(ratio) > 1e-3
