"""Jimenez et al.'s separable SSS (iryoku/separable-sss): sssWidth, strength, falloff, and the colour target's alpha.

``Demo/Code/SeparableSSS.cpp`` (``calculateKernel``, ``profile``, ``gaussian``) builds the taps; ``SeparableSSS.h``
(``SSSSBlurPS``): ``finalStep = sssWidth * scale * dir``, ``finalStep *= SSSS_STREGTH_SOURCE`` (the colour's alpha by
default: "Modulate it using the alpha channel"), ``finalStep *= 1.0 / 3.0``; texture coordinates are half of NDC, so
a kernel unit is ``2/3 sssWidth alpha`` scene units. No closed form to Burley: the parameters are a fit.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from ._base import ALBEDO_HELP, MM_PER_UNIT, AbstractEngine, Flag
from ._common import bins, burley_marginal_masses, count, material, piecewise_masses, relative_l2, rgb, scalar

# SeparableSSS.cpp, SeparableSSS::profile: the red channel of d'Eon et al.'s skin fit for every channel, without the
# narrowest Gaussian (0.233 at v = 0.0064, "accounted by the strength parameter").
_JIMENEZ_PROFILE = ((0.100, 0.0484), (0.118, 0.187), (0.113, 0.567), (0.358, 1.99), (0.078, 7.41))
JIMENEZ_DEFAULT_SAMPLES = 17  # SeparableSSS.h, SSSS_QUALITY 1


def _profile(r: np.ndarray, falloff: np.ndarray) -> np.ndarray:
    """SeparableSSS::profile / gaussian: ``sum w exp(-rr^2 / 2v) / (2 * 3.14 * v)``, ``rr = r / (0.001 + falloff)``."""
    rr = r[:, None] / (0.001 + falloff[None, :])
    return sum(w * np.exp(-(rr * rr) / (2.0 * v)) / (2.0 * 3.14 * v) for w, v in _JIMENEZ_PROFILE)


def jimenez_kernel(strength, falloff, *, n_samples: int = JIMENEZ_DEFAULT_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """``SeparableSSS::calculateKernel`` (iryoku/separable-sss Demo/Code/SeparableSSS.cpp) in float64.

    Returns ``offsets (n,)`` in kernel units (``kernel[i].w``, in [-RANGE, RANGE], RANGE = 3 above 20 samples else 2)
    and ``weights (n, 3)``, centre tap first as the shader expects. Weights: ``area * profile(offset)``, normalised
    per channel, then ``lerp(1, k0, strength)`` for the centre and ``k_i * strength`` for the others.
    """
    strength = rgb("strength", strength, lo=0.0, hi=1.0)
    falloff = rgb("falloff", falloff, lo=0.0, hi=1.0)
    n = count("n_samples", n_samples, lo=3)
    if n % 2 == 0:
        raise ValueError(f"n_samples must be an odd number >= 3, got {n_samples!r}")
    rng = 3.0 if n > 20 else 2.0
    exponent = 2.0
    step = 2.0 * rng / (n - 1)
    o = -rng + np.arange(n) * step
    offsets = rng * np.where(o < 0, -1.0, 1.0) * np.abs(o**exponent) / rng**exponent
    left = np.r_[0.0, np.abs(np.diff(offsets))]
    right = np.r_[np.abs(np.diff(offsets)), 0.0]
    area = (left + right) / 2.0
    weights = area[:, None] * _profile(offsets, falloff)
    order = np.r_[n // 2, np.delete(np.arange(n), n // 2)]  # "we want the offset 0.0 to come first"
    offsets, weights = offsets[order], weights[order]
    weights = weights / np.sum(weights, axis=0)
    weights[0] = (1.0 - strength) + strength * weights[0]
    weights[1:] = weights[1:] * strength
    return offsets, weights


def _taps(params: dict[str, Any]) -> int:
    """A parameter block's ``nSamples`` (the default where it has none), checked."""
    return count("nSamples", params.get("nSamples", JIMENEZ_DEFAULT_SAMPLES), lo=3)


def _world_mm(sss_width: float, mm_per_unit: float) -> float:
    # SeparableSSS.h, SSSSBlurPS: finalStep = sssWidth * (1/tan(fovy/2)) / depth * dir / 3 in texture coordinates;
    # a length l at depth z spans 0.5 l / (z tan(fovy/2)) of them (vertical axis), so a kernel unit is 2/3 sssWidth.
    # (The horizontal pass uses the same scale, so on a non-square viewport it is wider by the aspect ratio.)
    return 2.0 / 3.0 * sss_width * mm_per_unit


def jimenez_masses(strength, falloff, sss_width, mm_per_unit, n_samples, edges) -> np.ndarray:
    """The calculateKernel taps as 1D bin masses: each tap's weight spread over its footprint, the ``1 - strength``
    part of the centre tap a Dirac at 0; ``sss_width`` is the effective width (sssWidth times alpha)."""
    offsets, weights = jimenez_kernel(strength, falloff, n_samples=n_samples)
    order = np.argsort(offsets)
    w_sorted = offsets[order]
    k = _world_mm(sss_width, mm_per_unit)
    mids = (w_sorted[1:] + w_sorted[:-1]) / 2.0
    lo = np.r_[w_sorted[0], mids] * k
    hi = np.r_[mids, w_sorted[-1]] * k
    strength = rgb("strength", strength)
    spread = weights[order].copy()
    centre = int(np.where(order == 0)[0][0])
    spread[centre] -= 1.0 - strength  # the lerp(1, k0, strength) part is a Dirac: the unblurred pixel
    return piecewise_masses(lo, hi, spread, edges, dirac=1.0 - strength)


def jimenez_comb_masses(strength, falloff, sss_width: float, mm_per_unit: float, n_samples: int,
                        edges: np.ndarray, px_per_mm: float) -> np.ndarray:
    """The comb one Jimenez pass applies at ``px_per_mm``: every tap a bilinear fetch, pixel masses spread over the
    pixels' footprints; ``sss_width`` is the effective width (sssWidth times alpha)."""
    offsets, weights = jimenez_kernel(strength, falloff, n_samples=n_samples)
    t = offsets * _world_mm(sss_width, mm_per_unit) * px_per_mm  # px
    p0 = np.floor(t)
    f = (t - p0)[:, None]
    # the pixels the taps touch (two each), not every pixel the comb spans: a comb as wide as a huge d would
    # allocate one row per pixel it spans (28 GiB at d ~ 6e6 mm); pixels no tap touches hold no mass
    touched, slot = np.unique(np.r_[p0, p0 + 1], return_inverse=True)
    pixel = np.zeros((len(touched), 3))
    np.add.at(pixel, slot, np.r_[(1 - f) * weights, f * weights])
    centres = touched / px_per_mm
    return piecewise_masses(centres - 0.5 / px_per_mm, centres + 0.5 / px_per_mm, pixel, edges)


def _fit(albedo, d, unit, n_samples, masses=jimenez_masses):
    """Least-squares fit of (effective sssWidth, falloff, strength) to the Burley marginal; see ``Jimenez.to_engine``.
    ``masses(strength, falloff, width, unit, n_samples, edges)``: the kernel model fitted (the taps spread over their
    footprints; ``rendered_fit`` passes the comb the shader renders)."""
    from scipy.optimize import least_squares

    edges = bins(d)
    ref = burley_marginal_masses(d, edges)
    norm = np.linalg.norm(ref, axis=1, keepdims=True)

    def residuals(p):
        m = masses(p[4:7], p[1:4], math.exp(p[0]), unit, n_samples, edges)
        return ((m - ref) / norm).ravel()

    best = None
    dmax = float(np.max(d))
    base = dmax / _world_mm(1.0, unit)
    for scale in (1.0, 2.0, 4.0, 8.0):
        # a kernel unit covers 2/3 sssWidth; start with the widest channel's falloff 1 reaching ~scale d
        x0 = np.r_[math.log(scale * base), np.clip(d / dmax, 0.05, 1.0), np.full(3, 0.6)]
        # the width within 1e-3..1e3 of the widest d's (an unbounded log width stepped to exp overflow at d ~50 mm)
        lo = np.r_[math.log(1e-3 * base), np.zeros(6)]
        hi = np.r_[math.log(1e3 * base), np.ones(6)]
        sol = least_squares(residuals, x0, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=400)
        if best is None or sol.cost < best.cost:
            best = sol
    p = best.x
    err = relative_l2(masses(p[4:7], p[1:4], math.exp(p[0]), unit, n_samples, edges), ref)
    return p, best, err


def _comb(px_per_mm: float):
    def masses(strength, falloff, width, unit, n_samples, edges):
        return jimenez_comb_masses(strength, falloff, width, unit, n_samples, edges, px_per_mm)

    return masses


def rendered_fit(albedo, d_mm, *, mm_per_unit: float = 1000.0, n_samples: int = JIMENEZ_DEFAULT_SAMPLES,
                 alpha: float = 1.0, px_per_mm: float | None = None) -> dict[str, Any]:
    """The parameters whose comb, as the shader renders it at ``px_per_mm`` (bilinear taps, pixel footprints),
    is closest to the Burley marginal (the objective of ``Jimenez.to_engine`` with the rendered comb in place of
    the taps spread over their footprints), and that error beside the exact conversion's rendered error."""
    from ._rendered import RENDER_PX_PER_MM

    albedo, d = material(albedo, d_mm)
    ppm = RENDER_PX_PER_MM if px_per_mm is None else scalar("px_per_mm", px_per_mm)
    unit = scalar("mm_per_unit", mm_per_unit)
    p, sol, err = _fit(albedo, d, unit, n_samples, masses=_comb(ppm))
    return {"sssWidth": math.exp(p[0]) / alpha, "strength": p[4:7].tolist(), "falloff": p[1:4].tolist(),
            "alpha": alpha, "nSamples": int(n_samples), "mm_per_unit": unit, "px_per_mm": ppm,
            "error_relative_l2": err.tolist(), "status": int(sol.status), "evaluations": int(sol.nfev),
            "metric": "relative L2 of the comb's 1D-marginal bin masses rendered at px_per_mm (bilinear taps, "
                      "pixel footprints) against Burley's, per channel"}


class Jimenez(AbstractEngine):
    """Separable SSS: fitted sssWidth (scene units), strength (3,), falloff (3,); alpha scales the width."""

    name: ClassVar[str] = "jimenez"
    title: ClassVar[str] = "Jimenez et al. separable SSS"
    default_mm_per_unit: ClassVar[float] = 1000.0
    kernel: ClassVar[str | None] = "jimenez"
    lossy: ClassVar[str | None] = (
        "not physical: one d'Eon skin profile shape shared by all channels, scaled by falloff and blended with a "
        "Dirac by strength; the parameters are a least-squares fit to the Burley kernel")
    source: ClassVar[str] = ("iryoku/separable-sss Demo/Code/SeparableSSS.cpp (calculateKernel, profile, gaussian), "
                             "SeparableSSS.h (SSSSBlurPS: finalStep, SSSS_STREGTH_SOURCE)")
    flags: ClassVar[tuple[Flag, ...]] = (
        Flag("--albedo", ALBEDO_HELP, key="albedo", required=True),
        Flag("--sss-width", "jimenez: sssWidth, scene units", key="sssWidth", kind="float", required=True),
        Flag("--strength", "jimenez: strength R,G,B in [0,1]", key="strength", required=True),
        Flag("--falloff", "jimenez: falloff R,G,B in [0,1]", key="falloff", required=True),
        Flag("--alpha", "jimenez: the colour target's alpha (SSSS_STREGTH_SOURCE), scales the width (default 1)",
             key="alpha", option="alpha", kind="float"),
        Flag("--samples", "jimenez: kernel taps (default 17)", key="nSamples", option="n_samples", kind="int"),
        MM_PER_UNIT,
    )

    def to_engine(self, albedo, d_mm, *, mm_per_unit: float = 1000.0, n_samples: int = JIMENEZ_DEFAULT_SAMPLES,
                  alpha: float = 1.0) -> dict[str, Any]:
        """Fitted separable-SSS parameters for ``(albedo, d_mm)`` drawn with colour alpha ``alpha``.

        Objective (also what ``engine_profile_error`` reports): per channel c, the 1D marginal of the Burley profile
        (what one separable pass must apply) and the calculateKernel taps are both turned into masses of 161 bins of
        width d_c/4 centred on 0 plus the two tails beyond +-20.125 d_c; each tap's weight is spread uniformly over
        its footprint, the ``1 - strength`` part of the centre tap is a Dirac. Residuals ``(m_jimenez - m_burley) /
        ||m_burley||`` of the three channels are minimised together by ``scipy.optimize.least_squares`` (trf) over
        ``log(sssWidth alpha)``, falloff and strength in [0, 1], from four starting widths; the best is kept.
        sssWidth is shared by the channels: this is the lossy part.
        """
        albedo, d = material(albedo, d_mm)
        unit = scalar("mm_per_unit", mm_per_unit)
        a = scalar("alpha", alpha, hi=1.0)
        n_samples = count("n_samples", n_samples, lo=3)
        if not np.all(d > 0):
            raise ValueError(f"jimenez needs d_mm > 0 in every channel, got {d.tolist()}")
        p, sol, err = _fit(albedo, d, unit, n_samples)
        return {"sssWidth": math.exp(p[0]) / a, "strength": p[4:7].tolist(), "falloff": p[1:4].tolist(),
                "alpha": a, "nSamples": int(n_samples), "mm_per_unit": unit, "albedo": albedo.tolist(),
                "fit": {"solver": "scipy.optimize.least_squares(trf)", "status": int(sol.status),
                        "evaluations": int(sol.nfev), "error_relative_l2": err.tolist(),
                        "metric": "relative L2 of 1D-marginal bin masses (width d/4, +-20 d, tails), per channel"}}

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """The Burley d per channel closest to the kernel (same objective, one scalar per channel, bins of width d/4
        of the candidate d); separable SSS has no albedo of its own: ``albedo`` is the texture's (default white)."""
        from scipy.optimize import minimize_scalar

        for key in ("sssWidth", "strength", "falloff"):
            if key not in params:
                raise ValueError(f"jimenez parameters need {key!r}")
        albedo = rgb("albedo", params.get("albedo", (1.0, 1.0, 1.0)), lo=0.0, hi=1.0)
        width = scalar("sss_width", params["sssWidth"]) * scalar("alpha", params.get("alpha", 1.0), hi=1.0)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        n_samples = _taps(params)
        strength = rgb("strength", params["strength"], lo=0.0, hi=1.0)
        falloff = rgb("falloff", params["falloff"], lo=0.0, hi=1.0)
        k = _world_mm(width, unit)
        d = np.empty(3)
        for c in range(3):
            if strength[c] == 0:  # the kernel is the centre tap alone, the identity: Burley's d = 0 (the search,
                d[c] = 0.0        # bounded away from 0, landed on 1.97 mm while strength 0.001 gave 0.039)
                continue

            def objective(logd, c=c):
                dc = np.full(3, math.exp(logd))
                edges = bins(dc)
                ref = burley_marginal_masses(dc, edges)[c]
                m = jimenez_masses(strength, falloff, width, unit, n_samples, edges)[c]
                return float(np.sum((m - ref) ** 2) / np.sum(ref**2))

            scale = k * (0.001 + falloff[c])
            sol = minimize_scalar(objective, bounds=(math.log(scale * 1e-3), math.log(scale * 10.0)),
                                  method="bounded", options={"xatol": 1e-6})
            d[c] = math.exp(sol.x)
        return albedo, d

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        """``to_engine``'s fit (the taps spread over their footprints) and, beside it, ``rendered_fit``: the
        parameters fitted through the comb the shader renders at ``RENDER_PX_PER_MM``."""
        if not np.all(np.asarray(d_mm, np.float64) > 0):
            return {"error": "separable SSS needs d_mm > 0 in every channel"}
        out = super().block(albedo, d_mm, **options)
        out["rendered_fit"] = rendered_fit(albedo, d_mm, mm_per_unit=out["mm_per_unit"], n_samples=out["nSamples"],
                                           alpha=out["alpha"])
        return out

    def rendered(self, albedo, d_mm, edges, params=None):
        """The comb at ``RENDER_PX_PER_MM`` for the exact conversion's parameters and for ``rendered_fit``'s."""
        from ._rendered import RENDER_PX_PER_MM

        p = self.to_engine(albedo, d_mm) if params is None or "sssWidth" not in params else params
        refit = p.get("rendered_fit") or rendered_fit(albedo, d_mm, mm_per_unit=p["mm_per_unit"],
                                                      n_samples=_taps(p),
                                                      alpha=float(p.get("alpha", 1.0)))
        out = {}
        for key, q, what in (("jimenez:comb", p, "the fitted kernel's comb"),
                             ("jimenez:comb-refit", refit, "the comb of the parameters fitted through it")):
            width = float(q["sssWidth"]) * float(q.get("alpha", 1.0))
            m = jimenez_comb_masses(q["strength"], q["falloff"], width, q["mm_per_unit"],
                                    _taps(q), edges, RENDER_PX_PER_MM)
            out[key] = (m, np.asarray(albedo), f"Jimenez's pass, {what}, rendered at {RENDER_PX_PER_MM:g} px/mm "
                                               "(bilinear taps)")
        return out

    def marginal(self, albedo, d_mm, edges, params=None):
        p = self.to_engine(albedo, d_mm) if params is None or "sssWidth" not in params else params
        width = float(p["sssWidth"]) * float(p.get("alpha", 1.0))
        return (jimenez_masses(p["strength"], p["falloff"], width, p["mm_per_unit"],
                               _taps(p), edges), np.asarray(albedo))
