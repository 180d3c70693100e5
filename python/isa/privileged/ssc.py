"""Semantically Selected Centers (paper Sec. 3.1): one object-frame origin per category.

The paper's procedure, per category:

1. for each instance, its skeleton (here: matched to the category template, so node i is the same
   place on every instance) and its centre of mass (COM); the distances between the nodes and
   the COM;
2. across instances, the most repetitive node: the node that is closest to the COM on the most
   instances (the paper notes it is also the node closest to the COMs);
3. if several nodes tie, the SSC interpolates between them (equal weights).

The SSC is then a fixed convex combination of template nodes, ``weights @ matched.nodes``, so it
is defined on every instance, seen or unseen, as soon as its skeleton is matched. It replaces the
bounding-box centre of :func:`isa.data.meshes.object_origin`: :meth:`CategorySSC.origin` is the drop-in
(``mesh -> (3,) point in the mesh's coordinates``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from isa import atomic
from isa.exceptions import InvalidValueError
from isa.privileged.matching import match_skeleton
from isa.privileged.skeleton import extract_skeleton, solid_centre_of_mass
from isa.skeleton_graph import SkeletonGraph

__all__ = ["centre_of_mass", "SSC", "select_ssc", "CENTRES", "CategorySSC", "fit_category_ssc"]


def centre_of_mass(mesh: trimesh.Trimesh, resolution: int = 80, seed: int = 0) -> np.ndarray:
    """COM of ``mesh`` as a uniform solid (robust to open/overlapping ModelNet meshes)."""
    return solid_centre_of_mass(mesh, resolution, seed)


@dataclass
class SSC:
    """The category's SSC as weights over template nodes (one-hot, or equal over tied nodes)."""

    weights: np.ndarray
    votes: np.ndarray
    names: list[str] | None = None
    mean_distance: np.ndarray | None = None  # per node, mean distance to the COM over instances

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, float).reshape(-1)
        self.votes = np.asarray(self.votes, int).reshape(-1)
        if self.weights.shape != self.votes.shape:
            raise InvalidValueError(f"SSC: {self.weights.shape[0]} weights for {self.votes.shape[0]} votes")
        if not np.isclose(self.weights.sum(), 1.0) or np.any(self.weights < 0):
            raise InvalidValueError("SSC: weights must be non-negative and sum to 1")

    @property
    def nodes(self) -> np.ndarray:
        """Indices of the template nodes the SSC is made of."""
        return np.flatnonzero(self.weights > 0)

    def point(self, matched: SkeletonGraph) -> np.ndarray:
        """The SSC of one instance from its matched skeleton (same coordinates as its nodes)."""
        if len(matched.nodes) != len(self.weights):
            raise InvalidValueError(f"matched: has {len(matched.nodes)} nodes, the SSC is over {len(self.weights)} template nodes")
        return self.weights @ matched.nodes

    def to_dict(self) -> dict:
        d = {"weights": self.weights.tolist(), "votes": self.votes.tolist(), "names": self.names}
        if self.mean_distance is not None:
            d["mean_distance"] = np.asarray(self.mean_distance).tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SSC":
        md = d.get("mean_distance")
        return cls(np.array(d["weights"]), np.array(d["votes"]), d.get("names"), None if md is None else np.array(md))


def select_ssc(matched: Sequence[SkeletonGraph], coms: Sequence, tie_tolerance: int = 0) -> SSC:
    """The paper's SSC procedure over a category's instances.

    ``matched``: each instance's skeleton matched to the template (same node count and order);
    ``coms``: each instance's COM in the same coordinates. Nodes marked unmatched in
    ``meta["matched"]`` (a part missing on that instance) do not vote on it. Nodes whose vote count
    is within ``tie_tolerance`` of the top count are tied and share the SSC equally.
    """
    if len(matched) == 0:
        raise InvalidValueError("matched: need at least one instance")
    if len(coms) != len(matched):
        raise InvalidValueError(f"coms: {len(coms)} given for {len(matched)} instances")
    if tie_tolerance < 0:
        raise InvalidValueError(f"tie_tolerance: must be >= 0, got {tie_tolerance}")
    n = len(matched[0].nodes)
    votes = np.zeros(n, int)
    dist_sum = np.zeros(n)
    dist_cnt = np.zeros(n)
    for m, com in zip(matched, coms):
        if len(m.nodes) != n:
            raise InvalidValueError(f"matched: instances have {len(m.nodes)} and {n} nodes; match them to one template first")
        com = np.asarray(com, float).reshape(3)
        d = np.linalg.norm(m.nodes - com, axis=1)
        ok = np.asarray(m.meta.get("matched", [True] * n), bool)
        if not ok.any():
            continue
        dist_sum[ok] += d[ok]
        dist_cnt[ok] += 1
        votes[np.flatnonzero(ok)[np.argmin(d[ok])]] += 1
    if votes.sum() == 0:
        raise InvalidValueError("matched: no instance has a matched node")
    tied = votes >= votes.max() - tie_tolerance
    w = tied / tied.sum()
    md = np.where(dist_cnt > 0, dist_sum / np.maximum(dist_cnt, 1), np.nan)
    return SSC(w, votes, matched[0].names, md)


#: Object-frame origins a category can use (:attr:`CategorySSC.centre`): ``"ssc"``, the paper's
#: Semantically Selected Center (a matched skeleton node); ``"com"``, the instance's solid centre
#: of mass (:func:`centre_of_mass`); ``"box"``, the centre of its upright bounding box. The pose
#: metric does not depend on the choice (Eq. 14 moves both poses with the origin); how well the
#: forest predicts the centre of an unseen instance does, and where skeleton matching is
#: unreliable the SSC is the hardest to predict. Measured per category on validation instances
#: (docs/experiments.md).
CENTRES: tuple[str, ...] = ("ssc", "com", "box")


@dataclass
class CategorySSC:
    """A category's template, SSC and object-frame origin rule: what turns any instance mesh into
    its object-frame origin. The skeleton (privileged data for Q2/Q3) is matched in either case."""

    template: SkeletonGraph
    ssc: SSC
    extract_kw: dict = field(default_factory=dict)
    centre: str = "ssc"

    def __post_init__(self) -> None:
        if self.centre not in CENTRES:
            raise InvalidValueError(f"centre: must be one of {', '.join(CENTRES)}, got {self.centre!r}")

    def skeleton(self, mesh: trimesh.Trimesh) -> SkeletonGraph:
        """``mesh``'s skeleton matched to the template, in the mesh's coordinates."""
        return match_skeleton(extract_skeleton(mesh, **self.extract_kw), self.template, mesh.bounds)

    def origin_of(self, matched: SkeletonGraph | None, bounds, com) -> np.ndarray:
        """The origin of an instance from its matched skeleton, its mesh's (2, 3) bounds and its
        solid centre of mass (only the one the rule needs is read)."""
        if self.centre == "box":
            return np.asarray(bounds, float).reshape(2, 3).mean(0)
        if self.centre == "com":
            return np.asarray(com, float).reshape(3)
        return self.ssc.point(matched)

    def origin(self, mesh: trimesh.Trimesh) -> np.ndarray:
        """Drop-in for :func:`isa.data.meshes.object_origin`: the origin of ``mesh`` in its coordinates."""
        if self.centre == "box":
            return self.origin_of(None, mesh.bounds, None)
        if self.centre == "com":
            res = self.extract_kw.get("resolution", 80)
            return self.origin_of(None, None, centre_of_mass(mesh, res, self.extract_kw.get("seed", 0)))
        return self.ssc.point(self.skeleton(mesh))

    def save(self, path: str | Path) -> None:
        d = {"template": self.template.to_dict(), "ssc": self.ssc.to_dict(), "extract_kw": self.extract_kw,
             "centre": self.centre}
        atomic.write_text(path, json.dumps(d))

    @classmethod
    def load(cls, path: str | Path) -> "CategorySSC":
        d = json.loads(Path(path).read_text())
        return cls(SkeletonGraph.from_dict(d["template"]), SSC.from_dict(d["ssc"]), d.get("extract_kw", {}),
                   d.get("centre", "ssc"))


def fit_category_ssc(
    meshes: Sequence[trimesh.Trimesh], template: SkeletonGraph, extract_kw: dict | None = None
) -> tuple[CategorySSC, list[SkeletonGraph], np.ndarray]:
    """Skeletons, matching, COMs and the SSC for a category's training meshes.

    Returns the :class:`CategorySSC`, the matched skeletons and the (n, 3) COMs (all in each
    mesh's own coordinates).
    """
    if len(meshes) == 0:
        raise InvalidValueError("meshes: need at least one training mesh")
    kw = dict(extract_kw or {})
    raws = [extract_skeleton(m, **kw) for m in meshes]
    matched = [match_skeleton(r, template, m.bounds) for r, m in zip(raws, meshes)]
    coms = np.array([r.meta["com"] for r in raws])  # same voxelisation as centre_of_mass()
    return CategorySSC(template, select_ssc(matched, coms), kw), matched, coms
