"""Meshes -> model in one command (isa.forest.build, ``python -m isa train``): a folder of OBJ and
PLY files trains a model that finds one of them again; the experiment's training path, the
Python function and the command write the same bytes, and a rerun takes everything from the
cache; bad input is refused naming the file or flag, with nothing written."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from isa import _core
from isa.data.procedural import generate
from isa.exceptions import DataError
from isa.forest import build
from isa.forest.model import Forest

TINY = ["--views", "6", "--stride", "8", "--trees", "2", "--depth", "6", "--candidates", "8"]


@pytest.fixture(scope="module")
def mesh_folder(tmp_path_factory):
    """Three procedural chairs in their own units (x 10: not metres), as OBJ, OBJ and PLY."""
    d = tmp_path_factory.mktemp("meshes")
    for i, ext in enumerate(["obj", "obj", "ply"]):
        m = generate("chair", (7, i)).mesh.copy()
        m.apply_scale(10.0)
        m.export(d / f"chair_{i}.{ext}")
    return d


def _angle_deg(Ra, Rb) -> float:
    c = (np.trace(Ra.T @ Rb) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


@pytest.mark.slow
def test_folder_of_obj_and_ply_trains_a_model_that_finds_an_instance(mesh_folder, tmp_path):
    from isa.camera import KINECT_V1
    from isa.render.renderer import DepthRenderer
    from isa.render.views import training_views

    out = tmp_path / "models" / "seat.isa"
    # A category without a size table: sized by --height, template from the instances' own skeletons.
    build.main([str(mesh_folder), "--category", "seat", "--height", "0.9", "--centre", "box", "-o", str(out),
                "--views", "16", "--stride", "6", "--trees", "3", "--depth", "12", "--candidates", "24", "--quiet"])
    forest = Forest.load(out)
    meta = forest.metadata
    assert meta["category"] == "seat" and meta["centre"] == "box"
    assert meta["training"]["instances"] == [str(mesh_folder / f"chair_{i}.{e}") for i, e in enumerate(["obj", "obj", "ply"])]
    assert meta["training"]["template"] == "instances" and meta["training"]["views"] == 16
    assert meta["box"]["size"][2] == pytest.approx(0.9, abs=1e-6)  # every instance 0.9 m tall
    # The size-aware inference defaults are the model's own, not the core's generic ones.
    assert forest.predict_defaults["position_bandwidth"] != _core.PREDICT_DEFAULTS["position_bandwidth"]

    # Truth from the file itself: scaled to 0.9 m tall, origin at its box centre (--centre box).
    mesh = trimesh.load(mesh_folder / "chair_2.ply", process=False)
    mesh.apply_scale(0.9 / mesh.extents[2])
    mesh.apply_translation(-mesh.bounds.mean(0))
    views = training_views(40, seed=99, intrinsics=KINECT_V1)  # a camera of its own, not a training one
    R, t = views[5]
    with DepthRenderer(KINECT_V1) as r:
        depth, mask = r.render(mesh, R, t)
    assert mask.sum() > 500
    best = forest.predict(depth, KINECT_V1)[0]
    err_t = float(np.linalg.norm(np.asarray(best["t"]) - t))
    assert err_t < 0.1, f"position off by {err_t:.3f} m"
    assert _angle_deg(np.asarray(best["R"]), R) < 30


@pytest.mark.slow
def test_function_command_and_experiment_write_the_same_bytes_and_rerun_uses_the_cache(tmp_path, monkeypatch):
    from isa import experiment

    exp = tmp_path / "exp"
    experiment.main(["--procedural", "--out", str(exp), "--categories", "chair", "--train-instances", "2",
                     "--test-instances", "1", "--test-images", "2", "--qualities", "Q1+Q2+Q3", "--no-linemod"] + TINY)
    cache = tmp_path / "cache"
    a = build.train_category(None, "chair", tmp_path / "a.isa", procedural=2, views=6, stride=8, trees=2, depth=6,
                             candidates=8, cache=cache, progress=False)
    assert a.read_bytes() == (exp / "models" / "chair-Q1Q2Q3.isa").read_bytes()

    # The rerun (the command, same cache) extracts no skeleton, builds no template, renders no frame.
    def refuse(*_a, **_k):
        raise AssertionError("the rerun should have used the cache")

    from isa.render.renderer import DepthRenderer

    monkeypatch.setattr(build, "extract_skeleton", refuse)
    monkeypatch.setattr("isa.pipeline.category_template", refuse)
    monkeypatch.setattr(DepthRenderer, "render", refuse)
    b = tmp_path / "b.isa"
    build.main(["--procedural", "2", "--category", "chair", "-o", str(b), "--cache", str(cache), "--quiet"] + TINY)
    assert b.read_bytes() == a.read_bytes()


def test_bad_input_is_refused_naming_the_file_or_flag(mesh_folder, tmp_path, capsys):
    out = tmp_path / "out" / "m.isa"
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "broken.obj").write_bytes(b"\x00\x01 this is not a mesh \xff" * 10)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no meshes here")

    cases = [  # (meshes, category, height, what the message must name)
        (bad, "chair", None, "broken.obj"),
        (empty, "chair", None, str(empty)),
        (tmp_path / "missing", "chair", None, "missing"),
        (tmp_path / "*.stl", "chair", None, "*.stl"),
        (mesh_folder, "stool", None, "--height"),
        (mesh_folder, "stool", -1.0, "--height"),
    ]
    for meshes, category, height, named in cases:
        with pytest.raises(DataError) as exc:
            build.train_category([str(meshes)], category, out, height=height, progress=False)
        assert named in str(exc.value), (meshes, str(exc.value))
    assert not out.parent.exists()  # not even the output folder

    with pytest.raises(DataError, match="--height"):
        build.train_category(None, "chair", out, procedural=2, height=0.9, progress=False)
    with pytest.raises(DataError, match="not both"):
        build.train_category([str(mesh_folder)], "chair", out, procedural=2, progress=False)

    # Output folder that cannot be created (a file is in the way) or written.
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(DataError, match="output folder"):
        build.train_category([str(mesh_folder)], "chair", blocker / "m.isa", progress=False)
    with pytest.raises(DataError, match="is a folder"):
        build.train_category([str(mesh_folder)], "chair", tmp_path, progress=False)
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            with pytest.raises(DataError, match="not writable"):
                build.train_category([str(mesh_folder)], "chair", ro / "m.isa", progress=False)
        finally:
            ro.chmod(0o700)

    # The command: exit status 2, the message names the file; nothing written.
    with pytest.raises(SystemExit) as exc:
        build.main([str(bad), "--category", "chair", "-o", str(out), "--quiet"])
    assert exc.value.code == 2
    assert "broken.obj" in capsys.readouterr().err
    assert not out.parent.exists()


def test_mesh_files_expands_folders_globs_and_files_once(mesh_folder):
    files = build.mesh_files([str(mesh_folder / "*.obj"), str(mesh_folder), str(mesh_folder / "chair_0.obj")])
    assert [f.name for f in files] == ["chair_0.obj", "chair_1.obj", "chair_2.ply"]


def test_modelnet_root_gives_the_experiments_training_instances(shared_data):
    from isa.render.dataset import modelnet_objects

    root = shared_data / "modelnet10"
    ours = build.training_objects(str(root), "toilet", progress=False)
    theirs = modelnet_objects(root, "toilet", None, split="train", seed=0, first_obj_id=1, progress=False)
    assert len(ours) == 7  # the paper's protocol count
    for a, b in zip(ours, theirs, strict=True):
        assert (a.obj_id, a.source, a.scale) == (b.obj_id, b.source, b.scale)
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)


def test_a_y_up_glb_reads_as_the_z_up_mesh_it_came_from(tmp_path):
    """glTF's convention (y up, front +z) turned into ours (z up, front -y) by --up y."""
    m = generate("chair", (7, 0)).mesh
    m.export(tmp_path / "z_up.ply")
    y_up = m.copy()
    y_up.vertices = np.c_[m.vertices[:, 0], m.vertices[:, 2], -m.vertices[:, 1]]  # z -> y, front -y -> +z
    y_up.export(tmp_path / "y_up.glb")
    ref = build.training_objects([str(tmp_path / "z_up.ply")], "chair", progress=False)[0]
    got = build.training_objects([str(tmp_path / "y_up.glb")], "chair", up="y", progress=False)[0]
    assert got.scale == pytest.approx(ref.scale, rel=1e-5)
    np.testing.assert_allclose(got.mesh.vertices, ref.mesh.vertices, atol=1e-5)
    with pytest.raises(DataError, match="--up"):
        build.training_objects([str(tmp_path / "y_up.glb")], "chair", up="x", progress=False)
