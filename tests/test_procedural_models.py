"""Models without any dataset (isa.forest.procedural_models): built once, cached, deterministic,
with the shape library detection verifies against (tiny settings; the real ones are measured in
docs/experiments.md)."""

import pytest

from isa.exceptions import DataError
from isa.forest import procedural_models as pm

TINY = {"procedural": 2, "views": 2, "stride": 8, "trees": 1, "depth": 6, "quality": "Q1", "seed": 0}


def test_build_writes_a_loadable_model_with_shapes_keeps_it_and_is_deterministic(tmp_path):
    from isa.detection import load_model

    a = pm.build(["chair"], tmp_path / "a", progress=False, settings=TINY)["chair"]
    assert a == tmp_path / "a" / "chair.isa"
    model = load_model(a)
    assert model.category == "chair" and model.shapes is not None and len(model.shapes.points) == 2
    stamp = a.stat().st_mtime_ns
    assert pm.get("chair", tmp_path / "a", progress=False) == a  # kept, not rebuilt
    assert a.stat().st_mtime_ns == stamp
    b = pm.build(["chair"], tmp_path / "b", progress=False, settings=TINY)["chair"]
    assert a.read_bytes() == b.read_bytes()
    assert a.with_suffix(".shapes.isl").read_bytes() == b.with_suffix(".shapes.isl").read_bytes()


def test_folder_comes_from_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("ISA_MODELS", str(tmp_path))
    assert pm.model_path("bed") == tmp_path / "bed.isa"


def test_unknown_category_is_refused_by_name(tmp_path):
    with pytest.raises(DataError, match="sofa"):
        pm.build(["sofa"], tmp_path, progress=False)
