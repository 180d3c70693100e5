"""Writes ``model_v1.isa`` and ``model_v1.json``: a model in format version 1 (before the typed
inference defaults) and what that code predicted with it, for ``tests/test_forest.py`` and
``isa-core``'s model_io tests. It was run once, on the commit before format version 2
(``PYTHONPATH=<checkout of 5257ad7>/python python tests/data/make_model_v1.py``); running it on
later code writes a newer format, so do not regenerate it.

The model: 2 trees on the synthetic plates of ``tests/test_vote.py``, metadata holding
``predict_defaults`` (flat keys, as the pipeline stored them), a category and a free-form key.
"""

from __future__ import annotations

import json
import pathlib
import sys

HERE = pathlib.Path(__file__).parent
sys.path.insert(0, str(HERE.parent))

from isa import _core  # noqa: E402
from isa.forest import Forest, ForestParams  # noqa: E402
from test_vote import K, plate, plate_training_set  # noqa: E402

DEFAULTS = {"stride": 3, "position_bandwidth": 0.06, "max_hypotheses": 2}


def main() -> None:
    assert _core.MODEL_FORMAT_VERSION == 1, "run on the code before format version 2"
    images, parts, offsets, rotations = plate_training_set()
    f = Forest(ForestParams(n_trees=2, max_depth=8, n_candidates=20, max_offset=60.0, quality="Q1", seed=3))
    f.fit(images, parts, offsets, rotations,
          metadata={"category": "plate", "ssc": [0.0, 0.0, 0.0], "predict_defaults": DEFAULTS})
    f.save(HERE / "model_v1.isa")
    depth, _ = plate(centre=(0.02, -0.01, 1.5))
    hyps = f.predict(depth, K)
    out = {"centre": [0.02, -0.01, 1.5], "predict_defaults": DEFAULTS,
           "hypotheses": [{"R": h["R"].tolist(), "t": h["t"].tolist(), "score": h["score"],
                           "support": h["support"]} for h in hyps]}
    (HERE / "model_v1.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
