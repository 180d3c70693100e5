"""ModelNet10 adapter: listing, split selection and the paper protocol, on a synthetic layout and on
the real ../shared/data/modelnet10 (skipped when absent)."""

from __future__ import annotations

import os

import pytest

from isa.data.modelnet import find_root, list_instances, paper_instances, validation_instances
from isa.exceptions import DataError

# Counts and name ranges from ../shared/data/README.md (independent of the adapter).
REAL = {
    "bed": (80, 25, "bed_0001", "bed_0097", "bed_0516", "bed_0548"),
    "chair": (80, 25, "chair_0001", "chair_0093", "chair_0890", "chair_0918"),
    "table": (80, 25, "table_0001", "table_0086", "table_0393", "table_0418"),
    "toilet": (80, 25, "toilet_0001", "toilet_0097", "toilet_0345", "toilet_0374"),
}
PAPER = {"bed": 2, "chair": 28, "table": 8, "toilet": 7}


def _fake_root(tmp_path):
    base = tmp_path / "ModelNet10"
    for split, nums in (("train", [3, 1, 10, 2]), ("test", [900, 899])):
        d = base / "chair" / split
        d.mkdir(parents=True)
        for n in nums:
            (d / f"chair_{n:04d}.off").write_text("OFF\n0 0 0\n")
        (d / "readme.txt").write_text("not a mesh")
    (base / "bed" / "train").mkdir(parents=True)
    return tmp_path


def test_synthetic_layout_lists_in_name_order(tmp_path):
    root = _fake_root(tmp_path)
    names = [i.name for i in list_instances(root, "chair", "train")]
    assert names == ["chair_0001", "chair_0002", "chair_0003", "chair_0010"]
    assert [i.name for i in list_instances(root / "ModelNet10", "chair", "test")] == ["chair_0899", "chair_0900"]
    assert [i.name for i in paper_instances(root, "chair", 2)] == ["chair_0001", "chair_0002"]
    inst = list_instances(root, "chair", "test")[0]
    assert inst.category == "chair" and inst.split == "test" and inst.path.is_file()


def test_validation_is_the_last_train_instances_and_never_overlaps(tmp_path):
    root = _fake_root(tmp_path)
    assert [i.name for i in validation_instances(root, "chair", 2)] == ["chair_0003", "chair_0010"]
    assert [i.name for i in validation_instances(root, "chair", 2, n_train=2)] == ["chair_0003", "chair_0010"]
    with pytest.raises(DataError, match="3 training \\+ 2 validation"):
        validation_instances(root, "chair", 2, n_train=3)  # 4 train chairs cannot hold 3 + 2
    with pytest.raises(DataError, match="validation"):
        validation_instances(root, "chair", 0)


def test_validation_skip_takes_the_instances_just_before_the_last_ones(tmp_path):
    root = _fake_root(tmp_path)
    names = [i.name for i in list_instances(root, "chair", "train")]
    skipped = [i.name for i in validation_instances(root, "chair", 2, skip=1)]
    assert skipped == names[-3:-1]  # the two before the last, disjoint from validation_instances(.., 1)
    assert not set(skipped) & {i.name for i in validation_instances(root, "chair", 1)}
    with pytest.raises(DataError, match="2 training \\+ 2 validation instances \\+ 1 skipped"):
        validation_instances(root, "chair", 2, n_train=2, skip=1)  # 4 train chairs cannot hold 2 + 2 + 1
    with pytest.raises(DataError, match="validation"):
        validation_instances(root, "chair", 2, skip=-1)
    from isa.render.dataset import modelnet_objects

    with pytest.raises(DataError, match="skip=1 applies to split='validation' only"):
        modelnet_objects(root, "chair", 2, split="test", skip=1)  # refused before any mesh is read


def test_real_validation_instances_are_disjoint_from_the_protocol(shared_data):
    for cat, n_paper in PAPER.items():
        val = {i.name for i in validation_instances(shared_data / "modelnet10", cat, n_train=n_paper)}
        assert len(val) == 12
        assert not val & {i.name for i in paper_instances(shared_data / "modelnet10", cat)}
        assert max(val) == REAL[cat][3]  # the last train file


def test_protocol_needs_enough_instances(tmp_path):
    root = _fake_root(tmp_path)
    with pytest.raises(DataError, match="28"):
        paper_instances(root, "chair")  # 4 train chairs < 28


def test_missing_root_named(tmp_path):
    with pytest.raises(DataError, match="no_such_dir"):
        list_instances(tmp_path / "no_such_dir", "chair")


def test_root_without_categories_named(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="empty"):
        find_root(tmp_path / "empty")


def test_unknown_category_and_split(tmp_path):
    root = _fake_root(tmp_path)
    with pytest.raises(DataError, match="sofa"):
        list_instances(root, "sofa")
    with pytest.raises(DataError, match="validation"):
        list_instances(root, "chair", "validation")


def test_missing_category_folder_named(tmp_path):
    root = _fake_root(tmp_path)
    with pytest.raises(DataError, match=r"toilet[/\\]train"):
        list_instances(root, "toilet", "train")


@pytest.mark.parametrize("category", sorted(REAL))
def test_real_counts_and_protocol(shared_data, category):
    root = shared_data / "modelnet10"
    n_train, n_test, first_tr, last_tr, first_te, last_te = REAL[category]
    train = list_instances(root, category, "train")
    test = list_instances(root, category, "test")
    assert (len(train), len(test)) == (n_train, n_test)
    assert (train[0].name, train[-1].name, test[0].name, test[-1].name) == (first_tr, last_tr, first_te, last_te)
    assert not {i.name for i in train} & {i.name for i in test}
    # Protocol = first N file names in sorted order, checked against a plain directory listing.
    listing = sorted(f[:-4] for f in os.listdir(root / "ModelNet10" / category / "train") if f.endswith(".off"))
    proto = paper_instances(root, category)
    assert [i.name for i in proto] == listing[: PAPER[category]]
    assert all(i.split == "train" for i in proto)
