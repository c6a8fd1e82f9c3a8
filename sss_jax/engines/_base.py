"""The engine abstraction: one final class per engine (one file each), all answering the same questions.

``to_engine(albedo, d_mm, **options)`` gives the engine's parameters (by its UI names) for sss_jax's material,
``from_engine(params)`` the material an engine renders for its parameters; ``flags`` says which ``sss-jax convert``
flags carry those parameters, so the command line is built from the registry; ``marginal`` is the engine's own
kernel as 1D-marginal bin masses (``engine_profile_error``, the report); ``lossy``, ``unverified`` and ``source``
are what the output and docs/engines.md say about the conversion.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import numpy as np

from ._common import material


@dataclasses.dataclass(frozen=True)
class Flag:
    """One ``sss-jax convert`` flag of an engine.

    ``key``: the name of the value in the engine's parameter dict (``--from``); ``option``: the keyword of its
    ``to_engine`` (``--to``); either may be None. ``kind``: ``rgb`` (R,G,B or one number), ``srgb`` (that, or a hex
    ``#RRGGBB``), ``float``, ``int`` or
    ``str`` (with ``choices``). Several engines may declare the same flag with the same kind.
    """

    flag: str
    help: str
    key: str | None = None
    option: str | None = None
    kind: str = "rgb"
    required: bool = False
    choices: tuple[str, ...] | None = None

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")

    @property
    def metavar(self) -> str:
        return {"rgb": "R,G,B", "srgb": "R,G,B|#RRGGBB", "float": "X", "int": "N"}.get(self.kind,
                                                                              "|".join(self.choices or ("S",)))


ALBEDO_HELP = "surface albedo R,G,B in [0,1]"
MM_PER_UNIT = Flag("--mm-per-unit", "scene unit in mm (default: the engine's usual unit)", key="mm_per_unit",
                   option="mm_per_unit", kind="float")


class AbstractEngine(eqx.Module):
    """An engine's conversions. Concrete engines are final; the registry holds one instance of each."""

    name: eqx.AbstractClassVar[str]
    title: eqx.AbstractClassVar[str]
    default_mm_per_unit: eqx.AbstractClassVar[float]
    source: eqx.AbstractClassVar[str]
    flags: eqx.AbstractClassVar[tuple[Flag, ...]]
    # why A -> engine -> A can differ (None: exact), and what was not read from the engine's source (None: all was)
    lossy: ClassVar[str | None] = None
    unverified: ClassVar[str | None] = None
    # the key of this engine's kernel in ``engine_marginals`` (None: it has none of its own to draw)
    kernel: ClassVar[str | None] = None

    @abc.abstractmethod
    def to_engine(self, albedo, d_mm, **options) -> dict[str, Any]:
        """The engine's parameters (UI names; lengths as the engine takes them) for ``(albedo, d_mm)``."""

    @abc.abstractmethod
    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(albedo (3,), d_mm (3,)) the engine renders for ``params`` (the names ``to_engine`` writes)."""

    def notes(self, params: dict[str, Any]) -> dict[str, str | None]:
        """What ``convert`` says about this engine's side of a conversion with ``params``: ``lossy``,
        ``unverified`` and a ``note`` (None where there is nothing to say)."""
        return {"lossy": self.lossy, "unverified": self.unverified, "note": None}

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        """The preset block: ``to_engine`` in the engine's usual scene unit, with its lossy/unverified notes."""
        out = self.to_engine(albedo, d_mm, **{"mm_per_unit": self.default_mm_per_unit, **options})
        for note, text in self.notes(out).items():
            if text and note != "note":
                out[note] = text
        return out

    def marginal(self, albedo: np.ndarray, d_mm: np.ndarray, edges: np.ndarray,
                 params: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """The engine's kernel for the material as 1D-marginal bin masses (3, 163) on ``edges`` and the albedo it
        renders; ``params``: its parameters if already known (a preset's block), else ``to_engine``'s. None: the
        engine has no kernel of its own here."""
        return None

    def rendered(self, albedo: np.ndarray, d_mm: np.ndarray, edges: np.ndarray,
                 params: dict[str, Any] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
        """What the engine's own screen-space pass renders (``_rendered``), per configuration: ``{key: (masses
        (3, 163), albedo, what)}`` on ``edges``, ``what`` naming the budget and the model. Empty: no pass of its own
        is modelled."""
        return {}

    # --- the command line -------------------------------------------------------------------------------------

    def params_from_flags(self, values: dict[str, Any]) -> dict[str, Any]:
        """The ``from_engine`` parameters from parsed flag values (by ``Flag.dest``); errors name the flag."""
        params = {}
        for f in self.flags:
            if f.key is None:
                continue
            v = values.get(f.dest)
            if v is None:
                if f.required:
                    raise ValueError(f"--from {self.name} needs {f.flag} {f.metavar}")
                continue
            params[f.key] = list(v) if isinstance(v, tuple) else v
        return params

    def options_from_flags(self, values: dict[str, Any]) -> dict[str, Any]:
        """The ``to_engine`` keywords from parsed flag values; flags not given keep the engine's defaults."""
        return {f.option: (list(values[f.dest]) if isinstance(values[f.dest], tuple) else values[f.dest])
                for f in self.flags if f.option is not None and values.get(f.dest) is not None}


class SssJax(AbstractEngine):
    """sss_jax itself: albedo and Burley's d (mm)."""

    name: ClassVar[str] = "sss_jax"
    title: ClassVar[str] = "sss_jax (albedo, Burley d in mm)"
    default_mm_per_unit: ClassVar[float] = 1.0
    source: ClassVar[str] = "sss_jax: R(r) = A (exp(-r/d) + exp(-r/(3d))) / (8 pi d r), d in mm"
    flags: ClassVar[tuple[Flag, ...]] = (
        Flag("--albedo", ALBEDO_HELP, key="albedo", required=True),
        Flag("--d-mm", "sss_jax: Burley d per channel, mm", key="d_mm"),
        Flag("--mfp-mm", "sss_jax: mean free path per channel, mm (d = mfp / s(A), diffuse-transmission fit)",
             key="mfp_mm"),
    )

    def to_engine(self, albedo, d_mm, **options) -> dict[str, Any]:
        if options:
            raise ValueError(f"sss_jax's parameters take no options, got {', '.join(sorted(options))}")
        a, d = material(albedo, d_mm)
        return {"albedo": a.tolist(), "d_mm": d.tolist()}

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        for key in ("albedo", "d_mm"):
            if key not in params:
                raise ValueError(f"sss_jax parameters need {key!r}")
        return material(params["albedo"], params["d_mm"])

    def params_from_flags(self, values: dict[str, Any]) -> dict[str, Any]:
        params = super().params_from_flags(values)
        if ("d_mm" in params) == ("mfp_mm" in params):
            raise ValueError("--from sss_jax needs exactly one of --d-mm R,G,B or --mfp-mm R,G,B")
        if "mfp_mm" in params:
            from ._common import rgb, s_fit

            mfp = rgb("--mfp-mm", params.pop("mfp_mm"), lo=0.0)
            params["d_mm"] = (mfp / s_fit("diffuse_transmission", rgb("--albedo", params["albedo"]))).tolist()
        return params

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        return self.to_engine(albedo, d_mm)
