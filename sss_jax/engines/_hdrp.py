"""Unity HDRP: a diffusion profile (Scattering Color x Multiplier, World Scale) and the material's Subsurface Mask.

Unity-Technologies/Graphics ``com.unity.render-pipelines.high-definition/Runtime/Material/DiffusionProfile/
DiffusionProfileSettings.cs`` (``UpdateKernel``): ``sd = scatteringDistanceMultiplier * scatteringDistance``,
``shapeParam = 1 / sd`` in mm, i.e. Burley's d directly, no s(A). ``Runtime/Material/SubsurfaceScattering/
SubsurfaceScattering.compute``: ``distScale = sssData.subsurfaceMask``, ``mmPerUnit = MILLIMETERS_PER_METER *
(metersPerUnit * rcp(distScale))`` with ``metersPerUnit`` = World Scale: a profile millimetre covers
``mask / (1000 world_scale)`` scene units, so the Subsurface Mask scales d. The albedo is the Base Color (the profile
is normalised; the shader multiplies by the albedo). The inspector shows Scattering Color gamma-encoded (sRGB) and
stores it linear; the colour/multiplier split is the editor's ``HDUtils.ConvertHDRColorToLDR``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ._base import ALBEDO_HELP, MM_PER_UNIT, AbstractEngine, Flag
from ._common import (burley_cdf_np, burley_inverse_cdf_np, burley_marginal_masses, material, relative_l2, rgb,
                      scalar)


def srgb_encode(linear) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer (Unity's ``Mathf.LinearToGammaSpace``), for colours in [0, 1]."""
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1.0 / 2.4) - 0.055)


def srgb_decode(encoded) -> np.ndarray:
    """Inverse of ``srgb_encode``: the linear value of a colour typed into a gamma-encoded picker."""
    x = np.clip(np.asarray(encoded, np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


class Hdrp(AbstractEngine):
    """HDRP: ``d = Scattering Color * Multiplier * Subsurface Mask * mm_per_unit / (1000 World Scale)``."""

    name: ClassVar[str] = "hdrp"
    title: ClassVar[str] = "Unity HDRP (diffusion profile)"
    default_mm_per_unit: ClassVar[float] = 1000.0
    kernel: ClassVar[str | None] = "hdrp"
    source: ClassVar[str] = ("Unity-Technologies/Graphics com.unity.render-pipelines.high-definition: "
                             "DiffusionProfileSettings.cs (UpdateKernel), SubsurfaceScattering.compute (distScale = "
                             "subsurfaceMask, mmPerUnit), HDUtils.cs (ConvertHDRColorToLDR)")
    flags: ClassVar[tuple[Flag, ...]] = (
        Flag("--albedo", ALBEDO_HELP, key="Base Color", required=True),
        Flag("--scattering-color", "hdrp: Scattering Color as stored (linear)", key="Scattering Color"),
        Flag("--scattering-color-srgb", "hdrp: Scattering Color as the inspector shows it (sRGB-encoded: R,G,B in "
             "[0, 1], or its hex #RRGGBB)", key="Scattering Color (inspector sRGB)", kind="srgb"),
        Flag("--multiplier", "hdrp: scattering distance Multiplier (default 1)", key="Multiplier", kind="float"),
        Flag("--world-scale", "hdrp: World Scale, metres per unit (default 1, Unity's)", key="World Scale",
             kind="float"),
        Flag("--subsurface-mask", "hdrp: the material's Subsurface Mask, scales d (default 1)",
             key="Subsurface Mask", option="subsurface_mask", kind="float"),
        MM_PER_UNIT,
    )

    def to_engine(self, albedo, d_mm, *, mm_per_unit: float = 1000.0, subsurface_mask: float = 1.0) -> dict[str, Any]:
        """Diffusion profile for ``(albedo, d_mm)`` on a material with ``subsurface_mask``: World Scale states the
        scene unit (``mm_per_unit / 1000`` m); the profile's distance ``d / mask`` (mm) is split into an LDR colour
        and a multiplier as the editor does (``scale = 191 / max``, ``color = scale c / 255``, ``multiplier = 255 /
        scale``). Scattering Color is the stored linear value; the inspector shows its sRGB encoding, also given."""
        albedo, d = material(albedo, d_mm)
        unit = scalar("mm_per_unit", mm_per_unit)
        mask = scalar("subsurface_mask", subsurface_mask, hi=1.0)
        with np.errstate(over="ignore"):
            profile_d = d / mask
        if not np.all(np.isfinite(profile_d)):  # a mask so small that d / mask overflows: no profile holds it
            raise ValueError(f"subsurface_mask {subsurface_mask!r} is too small for d {d.tolist()} mm: the "
                             "profile's distance d / mask overflows")
        peak = float(np.max(profile_d))
        if peak > 0:
            factor = 191.0 / peak  # HDUtils.cs, ConvertHDRColorToLDR (k_MaxByteForOverexposedColor)
            color, mult = np.minimum(191.0, factor * profile_d) / 255.0, 255.0 / factor
        else:
            color, mult = profile_d, 1.0
        shown = srgb_encode(color)
        return {"Base Color": albedo.tolist(), "Scattering Color": color.tolist(),
                "Scattering Color (inspector sRGB)": shown.tolist(),
                "Scattering Color (inspector hex)": "#" + "".join(f"{round(255 * float(v)):02X}" for v in shown),
                "Multiplier": float(mult), "World Scale": unit / 1000.0, "Subsurface Mask": mask, "mm_per_unit": unit,
                "Max Radius (mm)": float(np.max(burley_inverse_cdf_np(0.997, profile_d)))}

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        if "Base Color" not in params:
            raise ValueError("hdrp parameters need 'Base Color'")
        linear, shown = params.get("Scattering Color"), params.get("Scattering Color (inspector sRGB)")
        if linear is None and shown is None:  # both: the stored linear value wins (to_engine writes both)
            raise ValueError("hdrp parameters need 'Scattering Color' (linear, as stored) or 'Scattering Color "
                             "(inspector sRGB)' (as the inspector shows it)")
        albedo = rgb("base_color", params["Base Color"], lo=0.0, hi=1.0)
        if linear is not None:
            color = rgb("scattering_color", linear, lo=0.0)
            if shown is not None:  # both (to_engine writes both): they must be one colour, to the inspector's 8 bits
                encoded = rgb("scattering_color_srgb", shown, lo=0.0, hi=1.0)
                expected = srgb_encode(np.minimum(color, 1.0))
                if np.max(np.abs(expected - encoded)) > 0.5 / 255 + 1e-6:
                    raise ValueError(f"hdrp: Scattering Color {color.tolist()} (linear) and its inspector sRGB "
                                     f"{encoded.tolist()} are two colours (the linear one encodes to "
                                     f"{np.round(expected, 4).tolist()}): give one")
        else:
            color = srgb_decode(rgb("scattering_color_srgb", shown, lo=0.0, hi=1.0))
        mult = scalar("multiplier", params.get("Multiplier", 1.0), positive=False, lo=0.0)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        ws = scalar("world_scale", params.get("World Scale", 1.0))
        mask = scalar("subsurface_mask", params.get("Subsurface Mask", 1.0), positive=False, lo=0.0, hi=1.0)
        return albedo, color * mult * mask * unit / (1000.0 * ws)

    def rendered_fit(self, albedo, d_mm, *, mm_per_unit: float = 1000.0,
                     subsurface_mask: float = 1.0) -> dict[str, Any]:
        """Per quality level, the diffusion profile whose pass (at ``RENDER_PX_PER_MM``, noise-averaged) renders
        closest to the material's Burley marginal (``_rendered.fit_d_through``), beside the exact conversion's
        rendered error: the exact profile is what HDRP's idealised kernel needs, not what its sampled pass needs."""
        from ._common import bins
        from ._rendered import HDRP_BUDGETS, RENDER_PX_PER_MM, fit_d_through, hdrp_masses

        albedo, d = material(albedo, d_mm)
        edges = bins(d)
        ref = burley_marginal_masses(d, edges)
        out = {}
        for quality, budget in HDRP_BUDGETS.items():
            render = lambda dd, budget=budget: hdrp_masses(dd, budget, edges)
            d_fit, err = fit_d_through(render, d, edges, ref)
            params = self.to_engine(albedo, d_fit, mm_per_unit=mm_per_unit, subsurface_mask=subsurface_mask)
            out[quality] = {"budget": budget, "px_per_mm": RENDER_PX_PER_MM, "d_mm": d_fit.tolist(),
                            **{k: params[k] for k in ("Scattering Color", "Scattering Color (inspector sRGB)",
                                                      "Scattering Color (inspector hex)", "Multiplier")},
                            "error_relative_l2": err.tolist(),
                            "error_relative_l2_exact": relative_l2(render(d), ref).tolist()}
        return out

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        """The exact conversion and, beside it, ``rendered_fit`` (the profile fitted through the pass per quality)."""
        out = super().block(albedo, d_mm, **options)
        if np.all(np.asarray(d_mm, np.float64) > 0):
            out["rendered_fit"] = self.rendered_fit(albedo, d_mm, mm_per_unit=out["mm_per_unit"],
                                                    subsurface_mask=out["Subsurface Mask"])
        return out

    def rendered(self, albedo, d_mm, edges, params=None):
        """The pass at each quality level (budget 20/40/80) at ``RENDER_PX_PER_MM``, noise-averaged, for the exact
        profile and for the profile fitted through the pass (``rendered_fit``)."""
        from ._rendered import HDRP_BUDGETS, RENDER_PX_PER_MM, hdrp_masses

        refit = (params or {}).get("rendered_fit") or self.rendered_fit(albedo, d_mm)
        out = {}
        for quality, budget in HDRP_BUDGETS.items():
            what = (f"HDRP's pass, quality {quality} (budget {budget} samples at {RENDER_PX_PER_MM:g} px/mm), "
                    "noise-averaged")
            out[f"hdrp:{quality}"] = (hdrp_masses(d_mm, budget, edges), np.asarray(albedo), what)
            out[f"hdrp:{quality}-refit"] = (hdrp_masses(np.asarray(refit[quality]["d_mm"]), budget, edges),
                                            np.asarray(albedo), what + ", the profile fitted through it")
        return out

    def marginal(self, albedo, d_mm, edges, params=None):
        """Burley truncated at the filter radius (CDF 0.997 of the widest channel, ``UpdateKernel``) and renormalised
        by the shader's weight sum."""
        d = np.asarray(d_mm, np.float64)
        r_filter = float(np.max(burley_inverse_cdf_np(0.997, d)))
        return burley_marginal_masses(d, edges, u_max=burley_cdf_np(np.full(3, r_filter), d)), np.asarray(albedo)
