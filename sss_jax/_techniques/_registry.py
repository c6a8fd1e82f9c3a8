"""The techniques by name, and which of them conserve energy."""

from __future__ import annotations

from typing import Callable

from ._burley import burley
from ._reference import reference
from ._separable import separable
from ._translucency import translucency

TECHNIQUES: dict[str, Callable] = {
    "sta": translucency,
    "separable": separable,
    "burley": burley,
    "reference": reference,
}

# Which techniques redistribute light (True) and which add it (False): the report shows this.
ENERGY_CONSERVING = {"sta": False, "separable": True, "burley": True, "reference": True}


def get_technique(name: str) -> Callable:
    """The technique registered under ``name``; the error lists the valid names."""
    try:
        return TECHNIQUES[name]
    except KeyError:
        raise ValueError(f"unknown technique {name!r}; valid techniques: {', '.join(TECHNIQUES)}") from None
