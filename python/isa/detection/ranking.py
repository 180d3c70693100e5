"""Ranking: each detection's score as the probability that it is a true object.

The verification score alone ranks a panel that agrees with any box face (a chair seen from
behind, a cabinet under a table hypothesis) above a half-hidden real object. The counts it is
made of, the forest's score, the size fit, the pose and the profile of the surface seen in the
box (``isa_core::scene::profile``: how it fills the box, rises through its height, leans to its
back, and carries on round it) tell them apart better. A
:class:`Ranker` is a logistic model of one category over those features
(``isa._core.RANK_FEATURES``; ``isa_core::scene::ranking``), applied by the core to the
detections NMS keeps; a boosted ranker (:func:`fit_boosted_ranker`, scikit-learn's gradient
boosting, ``pip install 'isa[ranking]'``) adds regression trees to its log-odds. Rankers are
fitted on *validation* rooms (scenes made from train-split meshes, ``python -m isa scenes
make``), never on test rooms:

    python -m isa.detection.ranking --scenes VAL --model chair=chair.isa ... --shapes SHAPES -o DIR

(boosted by default, chosen on validation rooms: docs/experiments.md; ``--kind logistic`` for
the linear model, which suits a few dozen detections better)
writes ``DIR/<category>.ranker.json``; :func:`isa.detection.multi.load_model` reads
``<model>.ranker.json`` beside a model (or ``ranker=``). Give every category a ranker or none:
a probability and a verification score do not rank together.
"""

from __future__ import annotations

import argparse
import inspect
import json
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from scipy.optimize import minimize
from tqdm import tqdm

from isa import _core, atomic
from isa.exceptions import DataError, InvalidValueError, MissingDependencyError

if TYPE_CHECKING:
    from isa.detection.multi import DetectParams

__all__ = ["Ranker", "fit_ranker", "fit_boosted_ranker", "FEATURES"]

FEATURES: tuple[str, ...] = tuple(_core.RANK_FEATURES)


_TREE_KEYS = ("feature", "threshold", "left", "right", "value")


@dataclass(frozen=True)
class Ranker:
    """``P(true) = 1 / (1 + exp(-(bias + sum_i weights_i (f_i - mean_i) / scale_i + sum_t
    tree_t(f))))`` over the named ``features`` of a ``category``'s detections; ``trees`` (may be
    empty) are regression trees as flat node arrays (``isa_core::scene::ranking::RankTree``:
    dicts of ``feature``, ``threshold``, ``left``, ``right``, ``value``); ``fitted_on`` says on
    what; ``nms_order`` the :class:`isa.detection.multi.DetectParams` ``nms_order`` of the
    detections it was fitted on (None: not recorded, as in older files), so that detection can
    warn when it runs under another."""

    category: str
    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float
    fitted_on: str = ""
    trees: tuple[dict, ...] = ()
    nms_order: str | None = None

    def to_json(self) -> str:
        """The JSON the core reads (checked by it)."""
        return self._json

    @cached_property
    def _json(self) -> str:
        # Made once: detection hands it to the core on every frame, and building it from a
        # boosted ranker's trees takes longer than ranking does.
        doc = {"format": _core.RANKER_FORMAT, "category": self.category, "features": list(self.features),
               "mean": list(self.mean), "scale": list(self.scale), "weights": list(self.weights),
               "bias": self.bias, "fitted_on": self.fitted_on}
        if self.trees:
            doc["trees"] = [{k: list(t[k]) for k in _TREE_KEYS} for t in self.trees]
        if self.nms_order is not None:
            doc["nms_order"] = self.nms_order
        return _core.check_ranker(json.dumps(doc), f"ranker of {self.category!r}")

    @classmethod
    def from_json(cls, text: str, source: str = "ranker") -> "Ranker":
        d = json.loads(_core.check_ranker(text, source))
        trees = tuple({k: tuple(t[k]) for k in _TREE_KEYS} for t in d.get("trees", ()))
        return cls(d["category"], tuple(d["features"]), tuple(d["mean"]), tuple(d["scale"]), tuple(d["weights"]),
                   float(d["bias"]), d.get("fitted_on", ""), trees, d.get("nms_order"))

    def save(self, path: str | Path) -> None:
        atomic.write_text(Path(path), self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> "Ranker":
        path = Path(path)
        if not path.is_file():
            raise DataError(f"{path}: ranker file not found")
        return cls.from_json(path.read_text(), str(path))

    def probability(self, features: dict[str, float]) -> float:
        """What the core computes, from a detection's ``meta["features"]``."""
        x = [features[f] for f in self.features]
        z = self.bias + sum(w * (v - m) / s for v, m, s, w in zip(x, self.mean, self.scale, self.weights))
        for t in self.trees:
            i = 0
            while t["feature"][i] >= 0:  # compared in float32, as scikit-learn's trees compare
                go_left = float(np.float32(x[t["feature"][i]])) <= t["threshold"][i]
                i = t["left"][i] if go_left else t["right"][i]
            z += t["value"][i]
        return float(1.0 / (1.0 + np.exp(-z)))


def fit_ranker(category: str, features: np.ndarray, labels: np.ndarray, names: Sequence[str] = FEATURES,
               c: float = 1.0, fitted_on: str = "") -> Ranker:
    """A logistic model of ``labels`` (bool, True: a true object) from ``features`` (N, F),
    columns named ``names``; standardised, L2-regularised (``c`` the inverse strength, as
    scikit-learn's ``C``), fitted by L-BFGS."""
    X = np.asarray(features, dtype=float)
    y = np.asarray(labels, dtype=bool)
    _check_training_set(category, X, y, names)
    if not c > 0:
        raise InvalidValueError(f"fit_ranker: c must be positive, got {c!r}")
    mean = X.mean(0)
    scale = X.std(0)
    scale[scale < 1e-9] = 1.0  # a constant feature: its weight goes to 0 under the penalty
    Z = (X - mean) / scale
    s = np.where(y, 1.0, -1.0)

    def loss(wb):
        w, b = wb[:-1], wb[-1]
        m = s * (Z @ w + b)
        # log(1 + exp(-m)) and its gradient, stable for any margin.
        value = c * np.logaddexp(0.0, -m).sum() + 0.5 * w @ w
        g = -c * s / (1.0 + np.exp(m))
        return value, np.append(Z.T @ g + w, g.sum())

    res = minimize(loss, np.zeros(X.shape[1] + 1), jac=True, method="L-BFGS-B")
    w, b = res.x[:-1], res.x[-1]
    return Ranker(category, tuple(names), tuple(mean.tolist()), tuple(scale.tolist()), tuple(w.tolist()), float(b),
                  fitted_on)


def fit_boosted_ranker(category: str, features: np.ndarray, labels: np.ndarray, names: Sequence[str] = FEATURES,
                       n_trees: int = 200, depth: int = 4, learning_rate: float = 0.05, min_leaf: int = 20,
                       seed: int = 0, fitted_on: str = "") -> Ranker:
    """A ranker whose log-odds are a sum of ``n_trees`` regression trees of ``depth`` levels
    (scikit-learn's ``GradientBoostingClassifier``, log-loss; at least ``min_leaf`` detections
    a leaf), exported as flat node arrays with the learning rate folded into the leaves. The
    defaults won on rooms of other shapes with 1,000-3,500 detections a category
    (docs/experiments.md, "Rankers fitted on shapes the scored rooms do not hold"; depth 4 since
    the profile features: "Deeper rankers, more fitting rooms and containment rivals")."""
    try:
        from sklearn.ensemble import GradientBoostingClassifier
    except ImportError as e:
        raise MissingDependencyError("fit_boosted_ranker needs scikit-learn: pip install 'isa[ranking]'") from e

    X = np.asarray(features, dtype=float)
    y = np.asarray(labels, dtype=bool)
    _check_training_set(category, X, y, names)
    for name, value in (("n_trees", n_trees), ("depth", depth), ("min_leaf", min_leaf)):
        if int(value) != value or value < 1:
            raise InvalidValueError(f"fit_boosted_ranker: {name} must be a whole number >= 1, got {value!r}")
    if not 0 < learning_rate <= 1:
        raise InvalidValueError(f"fit_boosted_ranker: learning_rate must be in (0, 1], got {learning_rate!r}")
    gb = GradientBoostingClassifier(n_estimators=n_trees, max_depth=depth, learning_rate=learning_rate,
                                    min_samples_leaf=min_leaf, random_state=seed).fit(X, y)
    trees = []
    for est in gb.estimators_[:, 0]:
        t = est.tree_
        leaf = t.children_left < 0
        trees.append({"feature": tuple(np.where(leaf, -1, t.feature).tolist()),
                      "threshold": tuple(np.where(leaf, 0.0, t.threshold).tolist()),
                      "left": tuple(np.where(leaf, 0, t.children_left).tolist()),
                      "right": tuple(np.where(leaf, 0, t.children_right).tolist()),
                      "value": tuple((learning_rate * t.value[:, 0, 0]).tolist())})
    # The prior's log-odds, as the fitted model has it (sklearn keeps it in a private method):
    # its decision function less the trees, on the first training row.
    x0 = X[:1]
    bias = float(gb.decision_function(x0)[0] - sum(learning_rate * e.predict(x0)[0] for e in gb.estimators_[:, 0]))
    n = len(names)
    return Ranker(category, tuple(names), (0.0,) * n, (1.0,) * n, (0.0,) * n, bias, fitted_on, tuple(trees))


def _check_training_set(category: str, X: np.ndarray, y: np.ndarray, names: Sequence[str]) -> None:
    if X.ndim != 2 or X.shape[1] != len(names) or len(X) != len(y):
        raise InvalidValueError(f"fit_ranker: features {X.shape} for {len(y)} labels and {len(names)} names")
    if y.all() or not y.any():
        raise InvalidValueError(f"fit_ranker({category!r}): needs true and false detections, "
                                f"got {int(y.sum())} true of {len(y)}")


def detection_outcomes(views, models, progress: bool = True,
                       params: DetectParams | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per category, the features (N, F) of every detection the models (rankers dropped) make in
    ``views`` (:class:`isa.scenes.benchmark.View`) with ``params`` (None: the defaults) and
    whether each is a true object (box IoU 0.25, :func:`isa.scenes.scoring.evaluate`; detections
    of objects too hidden to count are left out). With ``nms_order="ranked"`` the detections are
    those ranking sees there: NMS within each category only (``"per_category"``)."""
    from isa.detection.multi import DetectParams, detect
    from isa.scenes.scoring import Detection, evaluate

    use = [replace(m, ranker=None) for m in models]
    params = params or DetectParams()
    if params.nms_order == "ranked":
        params = replace(params, nms_order="per_category")
    feats, dets = [], []
    for f in tqdm(views, desc="detect", unit="frame", disable=not progress):
        res = detect(f.depth, f.intrinsics, use, gravity=f.gravity, params=params)
        feats.append([(d.category, d.meta.get("features")) for d in res.detections])
        dets.append([Detection(d.category, d.R, d.t, d.size, d.score, d.box_centre) for d in res.detections])
    cats = [m.category for m in models]
    sc = evaluate([f.gt for f in views], dets, [f.gravity for f in views], cats)
    out: dict[str, tuple[list, list]] = {c: ([], []) for c in cats}
    for fi, frame in enumerate(feats):
        for i, (cat, fd) in enumerate(frame):
            kind = sc.outcome[fi][i]["box_0.25"]
            if fd is None or kind not in ("tp", "fp"):
                continue
            out[cat][0].append([fd[n] for n in FEATURES])
            out[cat][1].append(kind == "tp")
    return {c: (np.array(x, dtype=float).reshape(-1, len(FEATURES)), np.array(y, dtype=bool))
            for c, (x, y) in out.items()}


def main(argv: list[str] | None = None) -> None:
    from isa.detection.evaluate import models_from_args, with_settings
    from isa.detection.multi import DetectParams
    from isa.scenes.benchmark import scene_views

    p = argparse.ArgumentParser(prog="python -m isa.detection.ranking", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", action="append", required=True, help="validation scene root (repeatable: pooled)")
    p.add_argument("--split", default="val")
    p.add_argument("--model", action="append", required=True, metavar="CATEGORY=PATH")
    p.add_argument("--shapes", type=Path, help="folder of <category>.shapes.isl or .npz (default: beside each model)")
    p.add_argument("--kind", choices=("logistic", "boosted"), default="boosted",
                   help="boosted regression trees (the default; they need a few hundred detections per "
                        "category), or linear log-odds")
    boost = {k: v.default for k, v in inspect.signature(fit_boosted_ranker).parameters.items()}
    p.add_argument("-C", type=float, default=0.1, help="logistic: inverse L2 strength (default 0.1)")
    p.add_argument("--trees", type=int, default=boost["n_trees"],
                   help=f"boosted: number of trees (default {boost['n_trees']})")
    p.add_argument("--depth", type=int, default=boost["depth"], help=f"boosted: levels per tree (default {boost['depth']})")
    p.add_argument("--learning-rate", type=float, default=boost["learning_rate"],
                   help=f"boosted: shrinkage (default {boost['learning_rate']})")
    p.add_argument("--seed", type=int, default=boost["seed"], help=f"boosted: random seed (default {boost['seed']})")
    p.add_argument("--set", metavar="KEY=JSON,...", help="detection parameters to fit under, as evaluate's "
                   "set: variant (e.g. proposals.cell=0.04)")
    p.add_argument("--features", metavar="NAME,...", help="the features to fit on, comma-separated "
                   f"(default: all, {', '.join(FEATURES)})")
    p.add_argument("-o", "--out", type=Path, required=True, help="folder for <category>.ranker.json")
    a = p.parse_args(argv)
    if a.split == "test":
        p.error("--split test: rankers are fitted on validation rooms, never on test rooms")
    names = tuple(a.features.split(",")) if a.features else FEATURES
    unknown = [n for n in names if n not in FEATURES]
    if unknown or len(set(names)) < len(names):
        p.error(f"--features {a.features}: unknown or repeated {', '.join(unknown) or 'names'}; "
                f"known: {', '.join(FEATURES)}")
    columns = [FEATURES.index(n) for n in names]
    models = []
    for item, m in zip(a.model, models_from_args(a.model, a.shapes)):
        if m.shapes is None:
            raise DataError(f"--model {item}: no shape library (ranking reads verification's counts)")
        # As the evaluation's variants: votes unweighted.
        models.append(replace(m, forest=m.forest.with_leaf_weights(None)))
    views = [v for root in a.scenes for v in scene_views(root, a.split)]
    where = " + ".join(f"{r}/{a.split}" for r in a.scenes)
    params = with_settings(DetectParams(), a.set) if a.set else DetectParams()
    data = detection_outcomes(views, models, params=params)
    a.out.mkdir(parents=True, exist_ok=True)
    for cat, (X, y) in data.items():
        X = X[:, columns]
        on = f"{len(views)} views of {where}: {int(y.sum())} true of {len(y)}"
        if a.set:  # the settings a ranker belongs to, for whoever reads the file
            on += f"; settings {a.set}"
        if a.kind == "boosted":
            r = fit_boosted_ranker(cat, X, y, names, n_trees=a.trees, depth=a.depth, learning_rate=a.learning_rate,
                                   seed=a.seed, fitted_on=on)
        else:
            r = fit_ranker(cat, X, y, names, c=a.C, fitted_on=on)
        r = replace(r, nms_order=params.nms_order)
        r.save(a.out / f"{cat}.ranker.json")
        print(f"{cat}: {r.fitted_on} -> {a.out / f'{cat}.ranker.json'}")


if __name__ == "__main__":
    main()
