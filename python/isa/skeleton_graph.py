"""The skeleton graph data type: nodes in the object frame and links between them.

Procedural meshes carry their true one (with semantic node names); extraction produces one from a
mesh; graph matching maps it onto a category template so that node i means the same place on
every instance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from isa.exceptions import InvalidValueError


@dataclass
class SkeletonGraph:
    """``nodes`` (N, 3) metres in the object frame, ``links`` (E, 2) node indices, optional names."""

    nodes: np.ndarray
    links: np.ndarray
    names: list[str] | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.nodes = np.asarray(self.nodes, dtype=np.float64).reshape(-1, 3)
        self.links = np.asarray(self.links, dtype=np.int64).reshape(-1, 2)
        if self.links.size and (self.links.min() < 0 or self.links.max() >= len(self.nodes)):
            raise InvalidValueError(f"SkeletonGraph: link index out of range for {len(self.nodes)} nodes")
        if self.names is not None and len(self.names) != len(self.nodes):
            raise InvalidValueError(f"SkeletonGraph: {len(self.names)} names for {len(self.nodes)} nodes")

    def adjacency(self, weighted: bool = False) -> np.ndarray:
        """Symmetric (N, N) adjacency; with ``weighted`` the link lengths instead of ones."""
        n = len(self.nodes)
        A = np.zeros((n, n))
        if len(self.links):
            i, j = self.links[:, 0], self.links[:, 1]
            w = np.linalg.norm(self.nodes[i] - self.nodes[j], axis=1) if weighted else 1.0
            A[i, j] = w
            A[j, i] = w
        return A

    def transformed(self, R: np.ndarray, t: np.ndarray) -> "SkeletonGraph":
        """The graph moved by X -> R X + t (with ``meta["members"]``, ground-truth segments, if any)."""
        R, t = np.asarray(R, float), np.asarray(t, float)
        meta = dict(self.meta)
        if "members" in meta:
            m = np.asarray(meta["members"], float).reshape(-1, 2, 3)
            meta["members"] = (m @ R.T + t).tolist()
        return SkeletonGraph(self.nodes @ R.T + t, self.links.copy(), self.names, meta)

    def to_dict(self) -> dict:
        return {"nodes": self.nodes.tolist(), "links": self.links.tolist(), "names": self.names, "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> "SkeletonGraph":
        return cls(np.array(d["nodes"], dtype=float), np.array(d["links"], dtype=np.int64), d.get("names"), d.get("meta", {}))
