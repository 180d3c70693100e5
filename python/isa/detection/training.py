"""Training a small category detector in memory (tests, demo, ``--train-procedural``)."""

from __future__ import annotations

from typing import Sequence

from isa.detection.category_boxes import box_metadata, category_box

__all__ = ["train_detector"]


def train_detector(category: str, objects: Sequence, views: int = 30, stride: int = 6, forest_params=None,
                   use_ground_truth: bool = False, seed: int = 0, progress: bool = False, intrinsics=None,
                   prepared=None):
    """Train a category forest on renders of ``objects`` (:class:`isa.render.dataset.ObjectSpec`) and
    store the category box in its metadata; returns ``(forest, prepared)``.

    Everything is kept in memory (no BOP folder), which suits the small sets of the tests, the
    demo and ``--train-procedural``; :mod:`isa.experiment` is the large-scale path. ``prepared``
    skips the skeleton / SSC step when already done (:func:`isa.pipeline.prepare_category`).
    """
    from isa import __version__, pipeline
    from isa.camera import KINECT_V1
    from isa.forest.model import ForestParams
    from isa.privileged.annotate import Frame, build_training_set
    from isa.render.dataset import default_views
    from isa.render.renderer import DepthRenderer

    intrinsics = intrinsics or KINECT_V1
    if prepared is None:
        prepared = pipeline.prepare_category(category, objects, use_ground_truth=use_ground_truth, progress=progress)
    frames = []
    with DepthRenderer(intrinsics) as r:
        for o in prepared.objects:
            v = default_views(o, views, seed, intrinsics)
            for i in range(len(v)):
                R, t = v[i]
                depth, mask = r.render(o.mesh, R, t)
                if mask.any():
                    frames.append(Frame(depth, mask, R, t, intrinsics, prepared.skeletons[o.obj_id]))
    ts = build_training_set(frames, stride=stride)
    params = forest_params or ForestParams(n_trees=4, max_depth=14, n_candidates=40, seed=seed)
    meta = {"category": category, "ssc": prepared.ssc.ssc.to_dict(), "template": prepared.ssc.template.to_dict(),
            "isa_version": __version__, "quality": params.quality, **box_metadata(category_box(prepared))}
    return pipeline.train_forest(ts, params, metadata=meta), prepared


# ----------------------------------------------------------------------------------------------
# Command line
