"""The base of the detection stages' parameter dataclasses (``PlaneParams``, ``VerifyParams``,
``RefineParams``): each mirrors one section of ``isa._core.DETECT_DEFAULTS``, whose values are its
defaults, and goes to the core as that section's dict. Their field lists (``name: type =
_D["name"]``) look alike by nature: one typed, documented field per core parameter."""

from __future__ import annotations

from dataclasses import asdict


class StageParams:
    """Mixin of a frozen dataclass whose fields are a section of the core's ``DetectParams``."""

    def to_dict(self) -> dict:
        """The core's JSON form of the section."""
        return asdict(self)  # type: ignore[call-overload]
