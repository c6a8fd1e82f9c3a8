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
        scale = scalar("subsurface_scale", params.get("Subsurface Scale", 1.0), positive=False, lo=0.0)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        return albedo, radius * scale * unit / (FOUR_PI * _s_normalised(albedo))

    def rendered_fit(self, albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                     blender_version: str = CURRENT_BLENDER) -> dict[str, Any]:
        """The Subsurface Radius whose pass after ``EEVEE_FRAMES`` TAA samples renders closest to the material's
        Burley marginal (``_rendered.fit_d_through``: the centre sample's weight makes the exact radius too
        narrow), beside the exact conversion's rendered error."""
        from ._common import bins, relative_l2
        from ._rendered import EEVEE_FRAMES, eevee_next_masses, fit_d_through

        albedo, d = material(albedo, d_mm)
        edges = bins(d)
        ref = burley_marginal_masses(d, edges)
        render = lambda dd: eevee_next_masses(albedo, dd, EEVEE_FRAMES, edges)
        d_fit, err = fit_d_through(render, d, edges, ref)
        params = self.to_engine(albedo, d_fit, subsurface_scale=subsurface_scale, mm_per_unit=mm_per_unit,
                                blender_version=blender_version)
        return {"frames": EEVEE_FRAMES, "d_mm": d_fit.tolist(), "Subsurface Radius": params["Subsurface Radius"],
                "error_relative_l2": err.tolist(), "error_relative_l2_exact": relative_l2(render(d), ref).tolist()}

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        """The exact conversion and, beside it, ``rendered_fit`` (the radius fitted through the pass)."""
        out = super().block(albedo, d_mm, **options)
        if np.all(np.asarray(d_mm, np.float64) > 0):
            out["rendered_fit"] = self.rendered_fit(albedo, d_mm, subsurface_scale=out["Subsurface Scale"],
                                                    mm_per_unit=out["mm_per_unit"],
                                                    blender_version=out["blender_version"])
        return out

    def rendered(self, albedo, d_mm, edges, params=None):
        """The pass after ``EEVEE_FRAMES`` TAA samples (16 samples each, sample 0 at the centre), noise-averaged,
        for the exact radius and for the radius fitted through the pass (``rendered_fit``)."""
        from ._rendered import EEVEE_FRAMES, eevee_next_masses

        refit = (params or {}).get("rendered_fit") or self.rendered_fit(albedo, d_mm)
        what = f"EEVEE Next's pass after {EEVEE_FRAMES} TAA samples of 16, noise-averaged"
        key = f"eevee-next:taa{EEVEE_FRAMES}"
        a = np.asarray(albedo, np.float64)
        return {key: (eevee_next_masses(a, d_mm, EEVEE_FRAMES, edges), a, what),
                key + "-refit": (eevee_next_masses(a, np.asarray(refit["d_mm"]), EEVEE_FRAMES, edges), a,
                                 what + ", the radius fitted through it")}

    def marginal(self, albedo, d_mm, edges, params=None):
        albedo = np.asarray(albedo, np.float64)
        d = np.asarray(d_mm, np.float64)
        radius_mm = d * FOUR_PI * _s_normalised(albedo)  # radius * scale * mm_per_unit
        d0 = 1.0 / (FOUR_PI * float(s_fit("diffuse_transmission", 1.0)))
        r_max = 16.0 * d0 * float(np.max(radius_mm))
        return burley_marginal_masses(d, edges, u_max=burley_cdf_np(np.full(3, r_max), d)), albedo
