"""Training sets as shards and the pipeline on a Dask cluster (issue 18): the model trained
from shards, tree by tree on a 2-worker LocalCluster, and with a worker killed mid-job, has the
bytes of ``Forest.fit`` in one process on the same arrays; cluster rendering writes the serial
renderer's frames; a truncated or foreign shard is refused by name."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from isa import _core
from isa.exceptions import InvalidInputError
from isa.forest import Forest, ForestParams
from isa.forest.shards import MANIFEST, shard_name, write_manifest, write_shard
from isa.privileged.annotate import TrainingSet

distributed = pytest.importorskip("distributed")
from isa import cluster  # noqa: E402  (after the optional dependency is known to be there)

PARAMS = ForestParams(n_trees=4, max_depth=8, n_candidates=30, min_samples_leaf=2, quality="Q1+Q2+Q3",
                      bag_fraction=0.8, seed=3)


def _instance(seed: int, n_images: int = 3) -> TrainingSet:
    """A synthetic instance: blobs of depth, parts on them, targets that depend on the pixel."""
    rng = np.random.default_rng(seed)
    images, parts = [], []
    for i in range(n_images):
        h, w = rng.integers(30, 40, size=2)
        d = np.zeros((h, w), np.uint16)
        d[4:-4, 4:-4] = rng.integers(800, 1500, size=(h - 8, w - 8))
        images.append(d)
        v, u = np.nonzero(d)
        keep = rng.random(len(u)) < 0.3
        parts += [[i, uu, vv] for uu, vv in zip(u[keep], v[keep])]
    p = np.asarray(parts, np.int32)
    offsets = np.stack([(p[:, 1] - 15) * 0.01, (p[:, 2] - 15) * 0.01, rng.normal(0, 0.01, len(p))], 1)
    q = np.concatenate([np.ones((len(p), 1)), rng.normal(0, 0.2, (len(p), 3))], 1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    links = rng.uniform(-np.pi, np.pi, (len(p), 4)) * 0.2 + (p[:, 1:2] * 0.05)
    nodes = rng.normal(0, 1, (len(p), 6)) + p[:, 1:2]
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    return TrainingSet(images, p, f32(offsets), f32(q), f32(links), f32(nodes), np.zeros((n_images, 2), np.int64))


def _concatenated(sets: list[TrainingSet]) -> dict:
    """The instances as one in-memory training set (image indices shifted), as
    ``isa.pipeline.training_set`` makes it from all the frames."""
    first = np.cumsum([0] + [len(s.images) for s in sets])[:-1]
    parts = np.concatenate([s.parts + np.array([f, 0, 0], np.int32) for s, f in zip(sets, first)])
    cat = lambda name: np.ascontiguousarray(np.concatenate([getattr(s, name) for s in sets]))  # noqa: E731
    return {"images": [im for s in sets for im in s.images], "parts": np.ascontiguousarray(parts),
            "offsets": cat("offsets"), "rotations": cat("rotations"), "link_angles": cat("link_angles"),
            "node_offsets": cat("node_offsets")}


@pytest.fixture(scope="module")
def instances() -> list[TrainingSet]:
    return [_instance(s) for s in range(3)]


@pytest.fixture
def shards(tmp_path, instances):
    folder = tmp_path / "shards"
    folder.mkdir()
    for k, ts in enumerate(instances):
        write_shard(folder / shard_name(k), ts, PARAMS.quality)
    write_manifest(folder, [shard_name(k) for k in range(len(instances))])
    return folder


@pytest.fixture(scope="module")
def expected(instances) -> bytes:
    return Forest(PARAMS).fit(**_concatenated(instances), metadata={"category": "chair"}).to_bytes()


@pytest.fixture(scope="module")
def client():
    with cluster.connect(workers=2) as c:
        yield c


def test_shards_round_trip_and_a_bad_shard_is_refused_by_name(shards, instances):
    back = _core.read_trainset(os.fspath(shards / shard_name(1)))
    for name in ("parts", "offsets", "rotations", "link_angles", "node_offsets"):
        np.testing.assert_array_equal(back[name], getattr(instances[1], name))
    for a, b in zip(back["images"], instances[1].images):
        np.testing.assert_array_equal(a, b)
    trainer = _core.ShardTrainer(os.fspath(shards), **PARAMS._core_kwargs())
    assert trainer.n_parts == sum(len(s) for s in instances)

    victim = shards / shard_name(2)
    good = victim.read_bytes()
    victim.write_bytes(good[: len(good) // 2])
    with pytest.raises(InvalidInputError, match=f"{shard_name(2)}.*truncated"):
        Forest(PARAMS).fit_shards(shards)
    victim.write_bytes(b"PK\x03\x04" + good[4:])  # same size, another file's magic
    with pytest.raises(InvalidInputError, match=f"{shard_name(2)}.*not an isa training-set file"):
        Forest(PARAMS).fit_shards(shards)
    (shards / MANIFEST).write_text("{}")
    with pytest.raises(InvalidInputError, match=MANIFEST):
        Forest(PARAMS).fit_shards(shards)


def test_fit_from_shards_and_on_two_workers_gives_the_in_memory_bytes(shards, expected, client):
    assert Forest(PARAMS).fit_shards(shards, metadata={"category": "chair"}).to_bytes() == expected
    assert len(client.scheduler_info()["workers"]) == 2
    got = cluster.fit_forest(client, shards, PARAMS, {"category": "chair"}, progress=False)
    assert got.to_bytes() == expected


def _malloc_trim() -> str | None:
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


# Read before any cluster starts: a nanny that sets it also sets it in its own process.
_TRIM_SET_OUTSIDE = _malloc_trim() is not None


def test_local_workers_keep_glibcs_adaptive_malloc(client):
    # Dask's nannies set MALLOC_TRIM_THRESHOLD_ (which fixes glibc's mmap threshold, and made
    # the core's large buffers fault in afresh); connect() unsets it for its workers.
    if _TRIM_SET_OUTSIDE:
        pytest.skip("MALLOC_TRIM_THRESHOLD_ is set in this environment, and workers inherit it")
    assert set(client.run(_malloc_trim).values()) == {None}


class _KillOnce(distributed.WorkerPlugin):
    """Kills (SIGKILL) the first worker process that starts a tree task, once per marker file."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def setup(self, worker) -> None:
        self.worker = worker

    def transition(self, key, start, finish, **kwargs) -> None:
        if finish == "executing" and "fit_tree_task" in str(key):
            try:
                os.close(os.open(self.marker, os.O_CREAT | os.O_EXCL))
            except FileExistsError:
                return
            os.kill(os.getpid(), signal.SIGKILL)


def test_a_worker_killed_during_training_still_gives_the_same_bytes(shards, expected, client, tmp_path):
    marker = tmp_path / "killed"
    client.register_plugin(_KillOnce(os.fspath(marker)), name="kill-once")
    try:
        got = cluster.fit_forest(client, shards, PARAMS, {"category": "chair"}, progress=False)
    finally:
        client.unregister_worker_plugin("kill-once")
    assert marker.exists(), "no worker was killed"
    assert got.to_bytes() == expected
    client.wait_for_workers(2, timeout=60)
    assert set(client.run(_malloc_trim).values()) == {None}  # the restarted worker too


def test_a_task_failing_on_bad_input_fails_the_job_naming_it(shards, client):
    victim = shards / shard_name(0)
    victim.write_bytes(victim.read_bytes()[:100])
    with pytest.raises(InvalidInputError, match=shard_name(0)):
        cluster.fit_forest(client, shards, PARAMS, progress=False)


def test_cluster_rendering_writes_the_serial_renderers_frames(tmp_path, client):
    from isa.data import bop
    from isa.render.dataset import procedural_objects, render_dataset

    objects = procedural_objects("chair", 2, seed=4)
    render_dataset(tmp_path / "serial", objects, n_views=2, view_seed=1, progress=False)
    assert cluster.render_dataset(client, tmp_path / "dask", objects, n_views=2, view_seed=1, progress=False) == [1, 2]
    serial, dask = bop.FrameSequence(tmp_path / "serial", "train"), bop.FrameSequence(tmp_path / "dask", "train")
    assert len(serial) == len(dask) == 4
    for a, b in zip(serial, dask):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_array_equal(a.R, b.R)
    # A finished instance is skipped on rerun.
    assert cluster.render_dataset(client, tmp_path / "dask", objects, n_views=2, view_seed=1, progress=False) == []


def test_train_command_with_shards_writes_the_in_memory_model(tmp_path):
    from isa.forest import build

    kw = dict(procedural=2, views=2, stride=8, trees=2, depth=6, progress=False)
    a = build.train_category(None, "chair", tmp_path / "a.isa", **kw)
    b = build.train_category(None, "chair", tmp_path / "b.isa", shards=tmp_path / "shards", **kw)
    assert a.read_bytes() == b.read_bytes()
    manifest = (tmp_path / "shards" / MANIFEST).read_text()
    assert shard_name(1) in manifest and shard_name(2) in manifest


def test_scale_flags_are_checked_before_any_work(tmp_path, capsys):
    from isa.forest import build

    out = tmp_path / "m.isa"
    for argv, expect in [(["--cluster"], "need --shards"), (["--workers", "2"], "need --shards"),
                         (["--shards", "s", "--workers", "2"], "apply with --cluster"),
                         (["--shards", "s", "--cluster", "--scheduler", "tcp://x:1", "--workers", "2"], "has its own"),
                         (["--shards", "s", "--mirror"], "not supported with --shards")]:
        with pytest.raises(SystemExit):
            build.main(["--procedural", "2", "--category", "chair", "-o", str(out), *argv])
        assert expect in capsys.readouterr().err
    assert not out.exists()
