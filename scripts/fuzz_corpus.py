"""Seed corpus of the fuzzing campaign (scripts/fuzz.sh, docs/fuzzing.md), made from real files
the project writes: a rendered BOP scene (depth PNGs, scene_camera.json), a camera.json, a model
and a training set trained/annotated from those renders, and the committed version-1 model. The
seeds are kept small (crops of 48 x 40 pixels) so the fuzzers run fast; nothing here is
committed (fuzz/corpus is ignored)."""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=ROOT / "fuzz" / "corpus")
    a = ap.parse_args(argv)

    from isa import _core
    from isa.data import bop
    from isa.render.dataset import procedural_objects, render_dataset

    out = a.out
    dirs = {t: out / t for t in ("model_decode", "trainset_decode", "depth_png", "camera_file", "predict_image")}
    for d in dirs.values():
        d.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        render_dataset(root, procedural_objects("chair", 1, seed=1), n_views=3, progress=False)
        scene = bop.scene_dir(root, "train", 1)
        crops = []
        for k, png in enumerate(sorted((scene / "depth").glob("*.png"))):
            depth = bop.read_png(png).astype(np.uint16)
            ys, xs = np.nonzero(depth)
            y0, x0 = max(int(ys.mean()) - 20, 0), max(int(xs.mean()) - 24, 0)
            crop = np.ascontiguousarray(depth[y0:y0 + 40, x0:x0 + 48])
            crops.append(crop)
            Image.fromarray(crop).save(dirs["depth_png"] / f"render{k}.png")
            # predict_image: 8 header bytes (size, camera, stride, bandwidth) then pixels.
            head = bytes([47, 39, 10, 10, 128 + 6, 128 + 5, k, 20])
            (dirs["predict_image"] / f"render{k}.bin").write_bytes(head + crop.astype("<u2").tobytes())
        shutil.copy(scene / "scene_camera.json", dirs["camera_file"] / "scene_camera.json")
        cam = json.loads((scene / "scene_camera.json").read_text())["0"]
        K = cam["cam_K"]
        single = {"fx": K[0], "fy": K[4], "cx": 23.5, "cy": 19.5, "width": 48, "height": 40, "depth_scale": 1.0}
        (dirs["camera_file"] / "camera.json").write_text(json.dumps(single))

    # A training set of the crops and a small forest trained on it.
    parts = _core.sample_parts(crops, stride=3)
    rng = np.random.default_rng(0)
    off = rng.normal(0, 0.05, (len(parts), 3)).astype(np.float32)
    q = rng.normal(size=(len(parts), 4))
    rot = (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)
    _core.TrainSet(crops, parts, off, rot, link_angles=rng.normal(size=(len(parts), 2)).astype(np.float32),
                   metadata='{"category": "chair"}').write(dirs["trainset_decode"] / "crops.isat")
    f = _core.Forest(n_trees=2, max_depth=4, n_candidates=8, min_samples_split=4, min_samples_leaf=2, quality="Q1")
    f.fit(_core.TrainSet(crops, parts, off, rot), metadata='{"category": "chair"}')
    f.save(dirs["model_decode"] / "crops.isa")
    shutil.copy(ROOT / "tests" / "data" / "model_v1.isa", dirs["model_decode"] / "model_v1.isa")
    for t, d in dirs.items():
        files = sorted(d.iterdir())
        print(f"{t}: {len(files)} seeds, {sum(p.stat().st_size for p in files)} bytes")


if __name__ == "__main__":
    main()
