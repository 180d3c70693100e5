"""Where a scene's instances come from: ModelNet10 test meshes (test scenes), the last train-split
meshes (validation scenes, disjoint from the paper protocol's first ones), or procedural meshes
(scenes that need no ``../shared``).

Each source gives instances as training has them (:func:`isa.pipeline.prepare_category`): real
size, object frame z up / front -y, origin at the category's :data:`isa.categories.CENTRE`.
Instances are prepared when first drawn (skeleton matching costs about a second per ModelNet
mesh) and kept. Categories whose origin is the SSC need the SSC the models were trained with: a
ModelNet source fits it on the paper-protocol training instances (as ``isa.experiment`` does), a
procedural one on its own instances; pass ``ssc`` to use another.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from isa import pipeline
from isa.categories import CENTRE, check_category
from isa.exceptions import DataError
from isa.privileged.matching import template_from_ground_truth
from isa.privileged.ssc import CategorySSC, centre_of_mass, select_ssc
from isa.render.dataset import ObjectSpec, modelnet_objects, procedural_objects
from isa.skeleton_graph import SkeletonGraph

#: Procedural instances per category in a procedural source.
PROCEDURAL_INSTANCES = 6


@dataclass(eq=False)
class MeshSource:
    """Instances per category, prepared on first use. ``name`` identifies the source (it goes
    into the dataset's settings, so a resumed run cannot mix sources); ``obj_id`` numbering is
    category-major over ``categories`` in the given order, from 1."""

    name: str
    categories: tuple[str, ...]
    _load: Callable[[str], list[ObjectSpec]]
    _prepare: Callable[[str, ObjectSpec], ObjectSpec]
    _raw: dict[str, list[ObjectSpec]] = field(default_factory=dict)
    _ready: dict[tuple[str, int], ObjectSpec] = field(default_factory=dict)

    def _objects(self, category: str) -> list[ObjectSpec]:
        if category not in self.categories:
            raise DataError(f"source {self.name}: no category {category!r} (has {', '.join(self.categories)})")
        if category not in self._raw:
            objs = self._load(category)
            if not objs:
                raise DataError(f"source {self.name}: no {category} instances")
            self._raw[category] = objs
        return self._raw[category]

    def count(self, category: str) -> int:
        return len(self._objects(category))

    def sources(self, category: str) -> list[str]:
        """Where each instance of ``category`` comes from (file or generator seed), unprepared."""
        return [o.source for o in self._objects(category)]

    def first_obj_id(self, category: str) -> int:
        return 1 + sum(self.count(c) for c in self.categories[: self.categories.index(category)])

    def instance(self, category: str, index: int) -> ObjectSpec:
        """Instance ``index`` of ``category``, prepared (object frame, origin, real size), with its
        source-wide ``obj_id``."""
        key = (category, index)
        if key not in self._ready:
            obj = self._objects(category)[index]
            ready = self._prepare(category, obj)
            ready.obj_id = self.first_obj_id(category) + index
            self._ready[key] = ready
        return self._ready[key]


def _check(categories: Sequence[str]) -> tuple[str, ...]:
    cats = tuple(check_category(c) for c in categories)
    if not cats:
        raise DataError("a mesh source needs at least one category")
    return cats


def _preparer(ssc_for: Callable[[str], CategorySSC | None], use_ground_truth: bool):
    """Prepare one instance with its category's CategorySSC (fitted once, on first use)."""
    cache: dict[str, CategorySSC] = {}

    def prepare(category: str, obj: ObjectSpec) -> ObjectSpec:
        ssc = cache.get(category) or ssc_for(category)
        p = pipeline.prepare_category(category, [obj], ssc=ssc, use_ground_truth=use_ground_truth, progress=False)
        cache.setdefault(category, p.ssc)  # com / box: the origin does not depend on the SSC fitted
        return p.objects[0]

    return prepare


def procedural(categories: Sequence[str], seed: int = 0, n: int = PROCEDURAL_INSTANCES,
               ssc: Mapping[str, CategorySSC] | None = None) -> MeshSource:
    """``n`` procedural instances per category (``isa.procedural.generate(category, (seed, i))``),
    true skeletons; SSC categories fit their SSC on these instances unless ``ssc`` has one."""
    cats = _check(categories)
    raw = {c: procedural_objects(c, n, seed=seed) for c in cats}

    def ssc_for(category: str) -> CategorySSC:
        if ssc and category in ssc:
            return ssc[category]
        return ground_truth_ssc(category, raw[category])

    return MeshSource(f"procedural:{seed}:{n}", cats, lambda c: raw[c], _preparer(ssc_for, True))


def ground_truth_ssc(category: str, objects: Sequence[ObjectSpec]) -> CategorySSC:
    """The CategorySSC that ``prepare_category(category, objects, use_ground_truth=True)`` fits,
    without calibrating the template against skeleton extraction (seconds per category): with
    true skeletons the template lends only its node names and links, so the SSC and every origin
    are the same. A category whose origin is not its SSC (centre of mass, box centre) keeps the SSC
    only as a label, so it is fitted on the first instance alone (a centre of mass each costs a
    voxelisation)."""
    if CENTRE.get(category, "ssc") != "ssc":
        objects = objects[:1]
    template = template_from_ground_truth([o.skeleton for o in objects], [o.mesh.bounds for o in objects])
    matched = [SkeletonGraph(o.skeleton.nodes, template.links, template.names) for o in objects]
    coms = [centre_of_mass(o.mesh) for o in objects]
    return CategorySSC(template, select_ssc(matched, coms), centre=CENTRE.get(category, "ssc"))


def _modelnet_ssc(root, ssc: Mapping[str, CategorySSC] | None):
    def ssc_for(category: str) -> CategorySSC | None:
        if ssc and category in ssc:
            return ssc[category]
        if CENTRE.get(category) != "ssc":
            return None
        train = modelnet_objects(root, category, None, split="train", progress=False)  # the paper protocol's
        return pipeline.prepare_category(category, train, progress=False).ssc

    return ssc_for


def _modelnet_load(root, split: str, n: int | None, seed: int, skip: int = 0):
    """ModelNet instances of a category with a machine-independent ``source``:
    ``modelnet:<split folder>/<file>`` (the contract's ``isa_source``)."""
    def load(category: str) -> list[ObjectSpec]:
        objs = modelnet_objects(root, category, n, split=split, seed=seed, progress=False, skip=skip)
        for o in objs:
            p = Path(o.source)
            o.source = f"modelnet:{p.parent.name}/{p.name}"
        return objs

    return load


def modelnet_test(root, categories: Sequence[str], n: int | None = None, seed: int = 0,
                  ssc: Mapping[str, CategorySSC] | None = None) -> MeshSource:
    """ModelNet10 test-split meshes (the first ``n`` per category, None: all), rescaled to a real
    size seeded per instance from ``seed``: for test scenes."""
    cats = _check(categories)
    return MeshSource(f"modelnet-test:{n}:{seed}", cats, _modelnet_load(root, "test", n, seed),
                      _preparer(_modelnet_ssc(root, ssc), False))


def modelnet_validation(root, categories: Sequence[str], n: int | None = None, seed: int = 0,
                        ssc: Mapping[str, CategorySSC] | None = None, skip: int = 0) -> MeshSource:
    """The LAST ``n`` train-split meshes per category (:func:`isa.data.modelnet.validation_instances`,
    default :data:`isa.data.modelnet.VALIDATION_INSTANCES`), or with ``skip`` the ``n`` before the
    last ``skip``: for validation scenes, never the paper protocol's first instances
    (``DataError`` if they would overlap)."""
    from isa.categories import PAPER_INSTANCES
    from isa.data.modelnet import validation_instances

    cats = _check(categories)
    for c in cats:  # raises when the protocol's training instances and these would overlap
        validation_instances(root, c, n, n_train=PAPER_INSTANCES[c], skip=skip)
    name = f"modelnet-validation:{n}:{seed}" + (f":skip{skip}" if skip else "")
    return MeshSource(name, cats, _modelnet_load(root, "validation", n, seed, skip),
                      _preparer(_modelnet_ssc(root, ssc), False))


def modelnet_protocol(root, categories: Sequence[str], seed: int = 0,
                      ssc: Mapping[str, CategorySSC] | None = None) -> MeshSource:
    """The paper protocol's training meshes (the first train-split files, Table 1's counts), never
    for scenes that score a model trained on them: the reference whose box-relative origins
    :func:`isa.scenes.scan2cad.relative_origin` measures for mesh-less (Scan2CAD) objects."""
    cats = _check(categories)
    return MeshSource(f"modelnet-protocol:{seed}", cats, _modelnet_load(root, "train", None, seed),
                      _preparer(_modelnet_ssc(root, ssc), False))
