"""Mesh loading (formats, clear errors), real-size rescaling and the object-frame origin."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isa.categories import CATEGORIES, PAPER_INSTANCES, PAPER_VIEWS, SIZES, check_category
from isa.data.meshes import MESH_EXTENSIONS, load_mesh, object_origin, prepare_mesh, real_size_scale, rescale_to_real_size
from isa.exceptions import DataError


def _box(extents=(1.0, 2.0, 3.0), offset=(0.5, -1.0, 2.0)) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(offset)
    return m


def test_paper_protocol_constants():
    assert CATEGORIES == ("bed", "chair", "table", "toilet")
    assert PAPER_INSTANCES == {"bed": 2, "chair": 28, "table": 8, "toilet": 7}  # Table 1 of the paper
    assert PAPER_VIEWS == 89
    for c in CATEGORIES:
        s = SIZES[c]
        assert 0 < s.height[0] < s.height[1] and 0 < s.length[0] < s.length[1] and s.sources


@pytest.mark.parametrize("ext", [e.lstrip(".") for e in MESH_EXTENSIONS])
def test_load_each_format_round_trip(tmp_path, ext):
    box = _box()
    path = tmp_path / f"box.{ext}"
    box.export(path)
    mesh = load_mesh(path)
    np.testing.assert_allclose(mesh.bounds, box.bounds, atol=1e-5)
    assert np.isclose(abs(mesh.volume), 6.0, atol=1e-4)


def test_missing_file_names_path(tmp_path):
    with pytest.raises(DataError, match="nothere.off"):
        load_mesh(tmp_path / "nothere.off")


def test_empty_file_names_path(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_bytes(b"")
    with pytest.raises(DataError, match=r"empty\.obj.*empty"):
        load_mesh(p)


@pytest.mark.parametrize(
    "name,content",
    [
        ("truncated.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n"),  # promises 3 vertices, holds 2
        ("junk.ply", b"garbage\x00\x01 not a ply"),
        ("junk.stl", b"\x00\x01\x02"),
    ],
)
def test_corrupt_file_names_path(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(DataError, match=name.replace(".", r"\.")):
        load_mesh(p)


def test_file_without_triangles(tmp_path):
    p = tmp_path / "points.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(DataError, match=r"points\.obj.*no triangles"):
        load_mesh(p)


def test_unsupported_extension(tmp_path):
    p = tmp_path / "model.fbx"
    p.write_text("x")
    with pytest.raises(DataError, match=r"model\.fbx.*unsupported"):
        load_mesh(p)


def test_unknown_category():
    with pytest.raises(DataError, match="sofa"):
        check_category("sofa")
    with pytest.raises(DataError, match="sofa"):
        real_size_scale([1, 1, 1], "sofa")


def test_object_origin_is_bbox_centre():
    np.testing.assert_allclose(object_origin(_box()), [0.5, -1.0, 2.0], atol=1e-12)


@pytest.mark.parametrize("category", CATEGORIES)
def test_rescale_lands_in_real_range(category):
    # Proportions of a plausible instance: a scale exists meeting both ranges.
    s = SIZES[category]
    h, length = np.mean(s.height), np.mean(s.length)
    box = _box(extents=(0.7 * length * 37, length * 37, h * 37))  # arbitrary units, like ModelNet
    seen = set()
    for seed in range(20):
        m, scale = rescale_to_real_size(box, category, seed)
        ext = m.extents
        assert s.height[0] - 1e-9 <= ext[2] <= s.height[1] + 1e-9
        assert s.length[0] - 1e-9 <= max(ext[:2]) <= s.length[1] + 1e-9
        np.testing.assert_allclose(ext, box.extents * scale)
        seen.add(round(scale, 9))
    assert len(seen) == 20  # the seed draws a size, not a constant
    assert real_size_scale(box.extents, category, 5) == real_size_scale(box.extents, category, 5)


def test_rescale_disjoint_ranges_meets_in_the_middle():
    # A "chair" 1 unit tall and 10 long: no scale satisfies both ranges; geometric mean of the gap.
    s = SIZES["chair"]
    scale = real_size_scale([10.0, 1.0, 1.0], "chair", 0)
    expected = np.sqrt(min(s.height[1] / 1.0, s.length[1] / 10.0) * max(s.height[0] / 1.0, s.length[0] / 10.0))
    assert scale == pytest.approx(expected)


def test_degenerate_extents_raise():
    with pytest.raises(DataError, match="degenerate"):
        real_size_scale([1.0, 1.0, 0.0], "table")


def test_prepare_mesh_centres_object_frame(tmp_path):
    p = tmp_path / "t.off"
    _box(extents=(20, 30, 15), offset=(3, 4, 5)).export(p)
    mesh, scale = prepare_mesh(p, "table", seed=1)
    np.testing.assert_allclose(mesh.bounds[0], -mesh.bounds[1], atol=1e-9)
    np.testing.assert_allclose(mesh.extents, np.array([20, 30, 15]) * scale, rtol=1e-9)


def test_real_modelnet_chair_scale(shared_data):
    path = shared_data / "modelnet10" / "ModelNet10" / "chair" / "train" / "chair_0001.off"
    raw = load_mesh(path)
    assert 30 < raw.extents[2] < 45  # arbitrary units (~37 per the data README)
    mesh, scale = prepare_mesh(path, "chair", seed=0)
    assert SIZES["chair"].height[0] <= mesh.extents[2] <= SIZES["chair"].height[1]
    np.testing.assert_allclose(object_origin(mesh), 0, atol=1e-9)
