"""The detection stages' parameter classes (``PlaneParams``, ``VerifyParams``, ``RefineParams``,
``ProposalParams``, ``DetectParams``) are made from the core: :func:`core_params` turns a class
that holds only its docstring (and any field the core's JSON cannot give a default for, such as a
nested stage) into a frozen, keyword-only dataclass with one field per key of its section of
``isa._core.DETECT_DEFAULTS``, defaulting to the core's value. So every detection parameter is
defined once, in ``isa_core::params::detect``, and a parameter added there appears here."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping, TypeVar

from isa import _core
from isa.exceptions import InvalidTypeError

T = TypeVar("T")


def _annotation(value: Any) -> Any:
    # The type shown by help() and dataclasses.fields(); None defaults (an optional step or bound)
    # say nothing about the type, so they take Any.
    if value is None:
        return Any
    if isinstance(value, list):
        return tuple
    return type(value)


def _default(value: Any) -> Any:
    # Frozen dataclasses need hashable defaults: the core's JSON lists become tuples; a dict
    # (a free-form section) gets a fresh copy per instance.
    if isinstance(value, dict):
        return field(default_factory=lambda: dict(value))
    return tuple(value) if isinstance(value, list) else value


def core_params(section: str | None) -> Callable[[type[T]], type[T]]:
    """Class decorator: the dataclass of ``DETECT_DEFAULTS[section]`` (the top level for None).
    Fields the class body declares (with a default or default factory) are kept as declared;
    they must be keys of the section too, so that the class cannot drift from the core."""
    defaults: Mapping[str, Any] = _core.DETECT_DEFAULTS if section is None else _core.DETECT_DEFAULTS[section]

    def wrap(cls: type[T]) -> type[T]:
        declared = dict(cls.__dict__.get("__annotations__", {}))
        unknown = set(declared) - set(defaults)
        if unknown:
            raise InvalidTypeError(f"{cls.__name__}: fields {sorted(unknown)} are not core parameters "
                            f"of section {section!r}")
        annotations = dict(declared)
        for name, value in defaults.items():
            if name not in declared:
                annotations[name] = _annotation(value)
                setattr(cls, name, _default(value))
        cls.__annotations__ = annotations
        return dataclass(frozen=True, kw_only=True)(cls)

    return wrap


class StageParams:
    """Mixin of a :func:`core_params` dataclass: its section of the core's ``DetectParams``."""

    def to_dict(self) -> dict:
        """The core's JSON form of the section."""
        return asdict(self)  # type: ignore[call-overload]
