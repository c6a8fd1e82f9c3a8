"""EEVEE legacy (Blender 2.80–4.1): the separable kernel of ``compute_sss_kernel``.

blender/blender ``source/blender/gpu/intern/gpu_material.c`` (2.80–3.x; the same code in the legacy EEVEE of later
versions), ``compute_sss_kernel``: ``l = 0.25/pi * radius``; ``A = 1.0f``; ``s = 1.9 - A + 3.5 (A - 0.8)^2``;
``d = l * 0.6 / s`` ("XXX 0.6f Out of nowhere to match cycles! Empirical!").
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ._base import AbstractEngine, Flag
from ._blender import EEVEE_FLAGS, parse_version
from ._common import FOUR_PI, count, material, piecewise_masses, rgb, s_fit, scalar

_EEVEE_EMPIRICAL = 0.6
EEVEE_DEFAULT_SAMPLES = 7  # scene.eevee.sss_samples default
LAST_LEGACY = (4, 1)


def _factor() -> float:
    return _EEVEE_EMPIRICAL / (FOUR_PI * float(s_fit("diffuse_transmission", 1.0)))


def _check_version(params_or_version) -> None:
    version = parse_version(params_or_version)
    if version > LAST_LEGACY:
        raise ValueError(f"blender_version {version[0]}.{version[1]}: EEVEE legacy ends with 4.1; Blender 4.2 and "
                         "later have EEVEE Next (engine 'eevee-next')")


def eevee_masses(d_eevee: np.ndarray, samples: int, edges: np.ndarray) -> np.ndarray:
    """``compute_sss_kernel``'s separable kernel as footprint masses: offsets ``sign(o) o^2``, o uniform in [-1, 1],
    times ``max_radius = 16 max(d)``; weight i is the 32-point midpoint integral of ``(exp(-x/d) + exp(-x/(3d))) /
    (4d)`` (the RADIAL pdf 2 pi r R(r) used as a 1D kernel) over the tap's footprint, normalised per channel."""
    n = int(samples)
    o = np.arange(n) * (2.0 / (n - 1)) - 1.0
    k = np.where(o < 0, -1.0, 1.0) * np.abs(o**2.0)
    max_radius = 16.0 * float(np.max(d_eevee))
    x0 = np.r_[k[0] - abs(k[0] - k[1]) / 2.0, (k[:-1] + k[1:]) / 2.0] * max_radius
    x1 = np.r_[(k[:-1] + k[1:]) / 2.0, k[-1] + abs(k[-2] - k[-1]) / 2.0] * max_radius
    t = (np.arange(32) + 0.5) / 32
    xs = x0[:, None] + (x1 - x0)[:, None] * t[None, :]  # (n, 32)
    weights = np.empty((n, 3))
    for c in range(3):
        dc = max(float(d_eevee[c]), 1e-15)
        ax = np.abs(xs)
        prof = (np.exp(-ax / dc) + np.exp(-ax / (3 * dc))) / (4 * dc) / 0.9963790093708328
        weights[:, c] = np.sum(prof, axis=1) * (x1 - x0) / 32
    weights = weights / np.sum(weights, axis=0)
    return piecewise_masses(x0, x1, weights, edges)


class Eevee(AbstractEngine):
    """EEVEE legacy: ``d = 0.6 radius scale / (4 pi s(1))``, the albedo fixed at 1."""

    name: ClassVar[str] = "eevee"
    title: ClassVar[str] = "EEVEE legacy (Blender 2.80-4.1)"
    default_mm_per_unit: ClassVar[float] = 1000.0
    kernel: ClassVar[str | None] = "eevee"
    lossy: ClassVar[str | None] = (
        "EEVEE legacy evaluates s(A) at a fixed A = 1: the radius that gives this d in EEVEE gives another d in "
        "Cycles; its kernel is the radial profile used as a 1D separable kernel (see engine_profile_error)")
    source: ClassVar[str] = ("blender/blender source/blender/gpu/intern/gpu_material.c, compute_sss_kernel "
                             "(2.80-3.x; legacy EEVEE to 4.1)")
    flags: ClassVar[tuple[Flag, ...]] = EEVEE_FLAGS

    def to_engine(self, albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                  samples: int = EEVEE_DEFAULT_SAMPLES, blender_version: str = "4.1") -> dict[str, Any]:
        """The node inputs that give EEVEE legacy's kernel the material's d."""
        _check_version(blender_version)
        albedo, d = material(albedo, d_mm)
        scale = scalar("subsurface_scale", subsurface_scale)
        unit = scalar("mm_per_unit", mm_per_unit)
        samples = count("samples", samples)
        radius = d / (scale * unit * _factor())
        return {"Subsurface Color": albedo.tolist(), "Subsurface Radius": radius.tolist(), "Subsurface Scale": scale,
                "mm_per_unit": unit, "Samples": samples}

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        for key in ("Subsurface Color", "Subsurface Radius"):
            if key not in params:
                raise ValueError(f"eevee parameters need {key!r}")
        _check_version(params.get("blender_version", "4.1"))
        albedo = rgb("subsurface_color", params["Subsurface Color"], lo=0.0, hi=1.0)
        radius = rgb("subsurface_radius", params["Subsurface Radius"], lo=0.0)
        scale = scalar("subsurface_scale", params.get("Subsurface Scale", 1.0), positive=False, lo=0.0)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        return albedo, radius * scale * unit * _factor()

    def marginal(self, albedo, d_mm, edges, params=None):
        samples = EEVEE_DEFAULT_SAMPLES if params is None else count("Samples", params.get("Samples", EEVEE_DEFAULT_SAMPLES))
        return eevee_masses(np.asarray(d_mm, np.float64), samples, edges), np.asarray(albedo)
