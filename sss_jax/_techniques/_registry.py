"""The techniques by name: a registry of classes (``TECHNIQUES``), ``technique(name, **options)`` to build one, and
which of them conserve energy (each class says so; ``ENERGY_CONSERVING`` is read from the classes)."""

from __future__ import annotations

from typing import Any

from ._base import AbstractTechnique, check_option_names, check_required_fields
from ._burley_technique import Burley
from ._eevee_next import EeveeNextPass
from ._hdrp import HdrpPass
from ._jimenez import JimenezPass
from ._reference_technique import Reference
from ._separable_technique import Separable
from ._translucency_technique import Translucency

TECHNIQUES: dict[str, type[AbstractTechnique]] = {cls.name: cls for cls in (Translucency, Separable, Burley, Reference,
                                                                           HdrpPass, EeveeNextPass, JimenezPass)}

# Which techniques redistribute light (True) and which add it (False): the report shows this.
ENERGY_CONSERVING: dict[str, bool] = {name: cls.conserves_energy for name, cls in TECHNIQUES.items()}


def get_technique(name: str) -> type[AbstractTechnique]:
    """The technique class registered under ``name``; the error lists the valid names."""
    try:
        return TECHNIQUES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown technique {name!r}; valid techniques: {', '.join(TECHNIQUES)}") from None


def technique(name: str, **options: Any) -> AbstractTechnique:
    """The technique registered under ``name`` with ``options`` (its fields: ``technique("burley", samples=64)``);
    an unknown name or option is an error that lists the valid ones."""
    cls = get_technique(name)
    check_option_names(cls, options)
    check_required_fields(cls, options)
    return cls(**options)
