"""EEVEE Next (Blender 4.2 and later, the only EEVEE since): screen-space Burley with the normalised albedo.

blender/blender ``source/blender/draw/engines/eevee_next/shaders/eevee_subsurface_convolve_comp.glsl`` (4.2–4.4;
``source/blender/draw/engines/eevee/shaders/`` from 4.5/5.0, same code): ``albedo = closure.color /
max(1e-6, max(closure.color))``, ``d = burley_setup(clamped_sss_radius, albedo)``; ``burley_setup`` in
``eevee_subsurface_shared.hh`` (``eevee_shader_shared.hh`` in 4.2): ``s = 1.9 - A + 3.5 (A - 0.8)^2``,
``l = 0.25 / pi * radius``, ``d = l / s`` (no 0.6). The radius is ``Subsurface Radius * Subsurface Scale``
(``gpu_shader_material_principled.glsl``: ``sss_radius = max(subsurface_radius * subsurface_scale, 0)``), the colour
the Base Color. Samples lie at Burley radii of ``d0 = burley_setup(1, 1)`` up to ``SSS_BURLEY_TRUNCATE`` (16) times
``max(radius)`` (``precompute_samples_location``); each is weighted by ``burley_eval(d, r) / pdf`` and the sum
normalised: Burley truncated at ``16 d0 max(radius)`` and renormalised. Not modelled: a channel whose radius is below
``1e-4`` (4.2; ``min_radius`` later) of the largest is raised to it, and nothing is drawn where the largest radius
spans at most one pixel.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ._base import AbstractEngine, Flag
from ._blender import EEVEE_FLAGS, CURRENT_BLENDER, parse_version, version_warning
from ._common import FOUR_PI, burley_cdf_np, burley_marginal_masses, material, rgb, s_fit, scalar

FIRST_NEXT = (4, 2)


def _s_normalised(albedo: np.ndarray) -> np.ndarray:
    return s_fit("diffuse_transmission", albedo / max(1e-6, float(np.max(albedo))))


def _check_version(version) -> tuple[int, int]:
    v = parse_version(version)
    if v < FIRST_NEXT:
        raise ValueError(f"blender_version {v[0]}.{v[1]}: EEVEE Next starts with 4.2; earlier versions have EEVEE "
                         "legacy (engine 'eevee')")
    return v


class EeveeNext(AbstractEngine):
    """EEVEE Next: ``d = radius scale / (4 pi s_dt(A / max A))``."""

    name: ClassVar[str] = "eevee-next"
    title: ClassVar[str] = "EEVEE Next (Blender 4.2 and later)"
    default_mm_per_unit: ClassVar[float] = 1000.0
    kernel: ClassVar[str | None] = "eevee-next"
    source: ClassVar[str] = ("blender/blender source/blender/draw/engines/eevee_next/shaders/"
                             "eevee_subsurface_convolve_comp.glsl and eevee_subsurface_shared.hh burley_setup "
                             "(4.2-4.4; draw/engines/eevee/ from 4.5), gpu_shader_material_principled.glsl")
    flags: ClassVar[tuple[Flag, ...]] = EEVEE_FLAGS

    def to_engine(self, albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                  blender_version: str = CURRENT_BLENDER) -> dict[str, Any]:
        """Principled BSDF inputs that give EEVEE Next's kernel the material's d (Cycles renders another d)."""
        version = _check_version(blender_version)
        albedo, d = material(albedo, d_mm)
        scale = scalar("subsurface_scale", subsurface_scale)
        unit = scalar("mm_per_unit", mm_per_unit)
        radius = d * FOUR_PI * _s_normalised(albedo) / (scale * unit)
        out = {"Subsurface Color": albedo.tolist(), "Subsurface Radius": radius.tolist(), "Subsurface Scale": scale,
               "mm_per_unit": unit, "blender_version": f"{version[0]}.{version[1]}"}
        warning = version_warning(version)
        if warning:
            out["warnings"] = [warning]
        return out

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        for key in ("Subsurface Color", "Subsurface Radius"):
            if key not in params:
                raise ValueError(f"eevee-next parameters need {key!r}")
        _check_version(params.get("blender_version", CURRENT_BLENDER))
        albedo = rgb("subsurface_color", params["Subsurface Color"], lo=0.0, hi=1.0)
        radius = rgb("subsurface_radius", params["Subsurface Radius"], lo=0.0)
        scale = scalar("subsurface_scale", params.get("Subsurface Scale", 1.0), positive=False)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        return albedo, radius * scale * unit / (FOUR_PI * _s_normalised(albedo))

    def rendered(self, albedo, d_mm, edges, params=None):
        """The pass after ``EEVEE_FRAMES`` TAA samples (16 samples each, sample 0 at the centre), noise-averaged."""
        from ._rendered import EEVEE_FRAMES, eevee_next_weights, ring_masses

        frames = eevee_next_weights(albedo, d_mm, EEVEE_FRAMES)
        masses = sum(ring_masses(r, w, edges) for r, w in frames) / len(frames)
        return {f"eevee-next:taa{EEVEE_FRAMES}": (masses, np.asarray(albedo, np.float64),
                                                  f"EEVEE Next's pass after {EEVEE_FRAMES} TAA samples of 16, "
                                                  "noise-averaged")}

    def marginal(self, albedo, d_mm, edges, params=None):
        albedo = np.asarray(albedo, np.float64)
        d = np.asarray(d_mm, np.float64)
        radius_mm = d * FOUR_PI * _s_normalised(albedo)  # radius * scale * mm_per_unit
        d0 = 1.0 / (FOUR_PI * float(s_fit("diffuse_transmission", 1.0)))
        r_max = 16.0 * d0 * float(np.max(radius_mm))
        return burley_marginal_masses(d, edges, u_max=burley_cdf_np(np.full(3, r_max), d)), albedo
