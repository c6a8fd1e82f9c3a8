"""Each cheap model's error against Burley and against Monte Carlo (profiles, rendered kernels, images, STA against
slab transmission, every engine's kernel), with the metric named."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._fitting import (
    RENDERED_HALF_PX,
    RENDERED_PIXEL_PER_D,
    burley_slab_transmittance,
    image_error,
    image_patterns,
    rendered_kernel_errors,
    sta_slab_response,
)
from .._materials import BurleyMaterial, ProfileMaterial, STAParams, TwoGaussianMaterial
from .._metrics import rel_l2
from .._montecarlo import MCResult
from .._profiles import BurleyProfile, burley_R, marginal_cdf
from .._scene import Camera
from .._techniques import reference
from ._sources import IMAGE_PX_PER_D, SLAB_T_OVER_D

# ------------------------------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------------------------------


def _burley_vs_mc(res: MCResult, mfp_mm: float, d_mm: float) -> float:
    """``||r (R_burley - R_mc)|| / ||r R_mc||`` on the run's bins, both profiles of unit energy."""
    r = res.r_mfp * mfp_mm
    R_mc = res.R / (mfp_mm**2) / max(res.total_reflectance, 1e-300)
    return rel_l2(r * np.asarray(burley_R(r, d_mm)), r * R_mc)


def _radial_two_gaussian(tg: dict, r_mm: np.ndarray, angles: int = 64) -> np.ndarray:
    """Azimuthal average of the separable kernel ``a_m(x) a_m(y)`` at radii ``r_mm``, ``(N, 3)`` (1/mm^2): what the
    two passes spread around a point, as a radial profile comparable with R(r)."""
    th = (np.arange(angles) + 0.5) * (2 * np.pi / angles)
    x = r_mm[:, None] * np.cos(th)[None, :]
    y = r_mm[:, None] * np.sin(th)[None, :]
    def g(v, s):
        return np.exp(-0.5 * (v / s) ** 2) / (s * math.sqrt(2 * math.pi))

    out = []
    for c in range(3):
        w, sn, sf = tg["w"][c], tg["sigma_near_mm"][c], tg["sigma_far_mm"][c]
        ax = w * g(x, sn) + (1 - w) * g(x, sf)
        ay = w * g(y, sn) + (1 - w) * g(y, sf)
        out.append((ax * ay).mean(axis=1))
    return np.stack(out, axis=-1)


def profile_errors(d_mm: np.ndarray, mc: list[MCResult], mfp_mm: np.ndarray, tg_burley: dict,
                   tg_mc: dict) -> dict[str, Any]:
    """1D radial errors on the Monte Carlo bins: ``||r (R_model - R_mc)|| / ||r R_mc||`` per channel, every profile
    normalised to unit energy (the albedo is a separate factor), over r < the profile range of the run."""
    out: dict[str, list[float]] = {"burley_vs_montecarlo": [], "two_gaussian_vs_montecarlo": [],
                                   "two_gaussian_vs_burley": [], "two_gaussian_montecarlo_vs_montecarlo": []}
    for c, res in enumerate(mc):
        r = res.r_mfp * mfp_mm[c]
        R_mc = res.R / (mfp_mm[c] ** 2) / max(res.total_reflectance, 1e-300)
        R_b = np.asarray(burley_R(r, float(d_mm[c])))
        R_tg = _radial_two_gaussian(tg_burley, r)[:, c]
        R_tgm = _radial_two_gaussian(tg_mc, r)[:, c]
        out["burley_vs_montecarlo"].append(_burley_vs_mc(res, float(mfp_mm[c]), float(d_mm[c])))
        out["two_gaussian_vs_montecarlo"].append(rel_l2(r * R_tg, r * R_mc))
        out["two_gaussian_vs_burley"].append(rel_l2(r * R_tg, r * R_b))
        out["two_gaussian_montecarlo_vs_montecarlo"].append(rel_l2(r * R_tgm, r * R_mc))
    return out


def kernel_errors(d_mm: np.ndarray, mc_profile, tg_burley: dict, tg_mc: dict) -> dict[str, Any]:
    """Each two-Gaussian kernel as ``separable`` renders it (the product ``a(x) a(y)``) and as the radial mix, against
    the Burley and the Monte Carlo profile on pixels of side d per channel (the fit's objective) and of side d/2."""
    burley = BurleyProfile(jnp.asarray(d_mm, jnp.float64))
    out: dict[str, Any] = {
        "metric": "relative L2 per channel of the kernel against the profile, both integrated over the pixels of a "
                  f"{2 * RENDERED_HALF_PX + 1}^2 grid of side pixel_side_over_d x that channel's Burley d; "
                  "rendered_product: a(x) a(y), what separable renders; radial_mix: w G_near(r) + (1 - w) G_far(r)",
        "grid_half_px": RENDERED_HALF_PX,
    }
    for key, scale in (("pixel_d", RENDERED_PIXEL_PER_D), ("pixel_half_d", 0.5 * RENDERED_PIXEL_PER_D)):
        pix = scale * np.asarray(d_mm, np.float64)
        out[key] = {"pixel_side_over_d": scale,
                    "two_gaussian_vs_burley": rendered_kernel_errors(tg_burley, burley, pix),
                    "two_gaussian_vs_montecarlo": rendered_kernel_errors(tg_burley, mc_profile, pix),
                    "two_gaussian_montecarlo_vs_montecarlo": rendered_kernel_errors(tg_mc, mc_profile, pix)}
    return out


def image_errors(albedo, d_mm: np.ndarray, mc_profile, tg_burley: dict, tg_mc: dict, *, taps: int = 25,
                 size: int = 32) -> dict[str, Any]:
    """Image-space relative L2 of ``separable`` (two-Gaussian, ``taps`` per pass) and of ``burley`` against
    ``reference`` with the Burley profile and with the Monte Carlo profile, over the fitting's five test patterns,
    at a scale where the widest channel's d spans ``IMAGE_PX_PER_D`` pixels."""
    px_per_mm = IMAGE_PX_PER_D / float(np.max(d_mm))
    cam = Camera(focal_px=10.0 * px_per_mm, mm_per_unit=1.0)  # the patterns lie at depth 10 units
    patterns = image_patterns(size)
    ones = jnp.ones(3, jnp.float64)
    burley_mat = BurleyMaterial(ones, jnp.asarray(d_mm))
    mc_mat = ProfileMaterial(mc_profile, albedo=ones)
    # one window for every material (one compilation): 20 d of the widest channel holds 99.9% of a Burley profile
    # (its CCDF (e^{-20} + 3 e^{-20/3})/4 = 1e-3)
    radius = math.ceil(20 * IMAGE_PX_PER_D)
    # the patterns are surfaces that end at the frame: light leaves there (image_error's rule too)
    ref_b = [np.asarray(reference(b, burley_mat, cam, radius_px=radius, border="leaves")) for b in patterns]
    ref_mc = [np.asarray(reference(b, mc_mat, cam, radius_px=radius, border="leaves")) for b in patterns]
    mat = lambda tg: TwoGaussianMaterial(ones, tg["w"], tg["sigma_near_mm"], tg["sigma_far_mm"])
    ref_b_on_mc = math.sqrt(sum(np.sum((a - b) ** 2) for a, b in zip(ref_b, ref_mc)) / sum(np.sum(b**2) for b in ref_mc))
    return {
        "metric": f"image-space relative L2 over the five test patterns ({size}x{size}), widest d = "
                  f"{IMAGE_PX_PER_D:g} px, {taps}-tap separable passes, against reference (dense convolution)",
        "px_per_mm": px_per_mm,
        "two_gaussian_vs_burley": image_error(mat(tg_burley), burley_mat, cam, patterns, taps=taps, references=ref_b),
        "two_gaussian_vs_montecarlo": image_error(mat(tg_burley), mc_mat, cam, patterns, taps=taps, references=ref_mc),
        "two_gaussian_montecarlo_vs_montecarlo": image_error(mat(tg_mc), mc_mat, cam, patterns, taps=taps,
                                                             references=ref_mc),
        "burley_reference_vs_montecarlo": ref_b_on_mc,
        # no scattering at all (local shading), for scale: what the cheap models are there to remove
        "local_shading_vs_burley": math.sqrt(sum(np.sum((np.asarray(b.irradiance) - r) ** 2)
                                                 for b, r in zip(patterns, ref_b)) / sum(np.sum(r**2) for r in ref_b)),
    }


def sta_errors(sta: dict, d_mm: np.ndarray, slab: dict) -> dict[str, Any]:
    """STA at normal light and view against the Monte Carlo slab transmittance and against Burley's
    ``(e^{-t/d} + 3 e^{-t/3d})/4`` at the Monte Carlo thicknesses; and that Burley slab model against Monte Carlo."""
    params = STAParams(**{k: sta[k] for k in ("distortion", "power", "scale", "ambient", "thickness_mm")},
                       dtype=jnp.float64)
    sta_vals, burley_vals, mc_vals = [], [], []
    for c in range(3):
        t = np.asarray(slab["thickness_mm"][c])
        sta_vals.append(np.asarray(sta_slab_response(params, jnp.asarray(t), jnp.asarray([0.0, 0.0, 1.0]),
                                                     jnp.asarray([0.0, 0.0, -1.0])))[:, c])
        burley_vals.append(np.asarray(burley_slab_transmittance(t, d_mm))[:, c])
        mc_vals.append(np.asarray(slab["T"][c]))
    sta_v, b_v, mc_v = (np.concatenate(v) for v in (sta_vals, burley_vals, mc_vals))
    return {"metric": "relative L2 of slab transmittance at normal light and view, thicknesses "
                      f"t/d = {', '.join(f'{k:g}' for k in SLAB_T_OVER_D)} per channel",
            "sta_vs_burley": rel_l2(sta_v, b_v), "sta_vs_montecarlo": rel_l2(sta_v, mc_v),
            "burley_vs_montecarlo": rel_l2(b_v, mc_v)}


def transmission_curves(preset: dict, slab: dict, *, points: int = 60) -> dict[str, Any]:
    """A preset's slab transmittance at normal light and view from its fitted STA, the closed-form thin model and the
    tabulated slab model, against its cached Monte Carlo ``slab`` block: the values at the Monte Carlo thicknesses,
    their relative L2 over all channels, and fine curves over t/d for plots."""
    from .._slab import slab_transmittance

    sta = preset["sta"]
    f64 = jax.dtypes.canonicalize_dtype(jnp.float64)  # float32 unless x64 is on (the preset script turns it on)
    params = STAParams(**{k: sta[k] for k in ("distortion", "power", "scale", "ambient", "thickness_mm")}, dtype=f64)
    albedo = np.asarray(preset["albedo"], np.float64)
    d = np.asarray(preset["burley"]["d_mm"], np.float64)
    light, view = jnp.asarray([0.0, 0.0, 1.0]), jnp.asarray([0.0, 0.0, -1.0])

    def models(t_mm: np.ndarray, c: int) -> dict[str, np.ndarray]:
        t = jnp.asarray(t_mm, f64)
        return {"sta": np.asarray(sta_slab_response(params, t, light, view))[:, c],
                "thin": np.asarray(burley_slab_transmittance(t, d))[:, c],
                "slab": np.asarray(slab_transmittance(t, albedo[c], d[c]))}

    at_mc = {m: [] for m in ("sta", "thin", "slab")}
    fine_t_over_d = np.geomspace(0.1, 5.0, points)
    fine = {m: [] for m in at_mc}
    for c in range(3):
        for m, v in models(np.asarray(slab["thickness_mm"][c], np.float64), c).items():
            at_mc[m].append(v)
        for m, v in models(fine_t_over_d * d[c], c).items():
            fine[m].append(v.tolist())
    mc = np.concatenate([np.asarray(v, np.float64) for v in slab["T"]])
    return {"t_over_d": [(np.asarray(t) / d[c]).tolist() for c, t in enumerate(slab["thickness_mm"])],
            "montecarlo": slab["T"], "montecarlo_stderr": slab["T_stderr"],
            "models": {m: [v.tolist() for v in vals] for m, vals in at_mc.items()},
            "rel_l2": {m: rel_l2(np.concatenate(vals), mc) for m, vals in at_mc.items()},
            "fine_t_over_d": fine_t_over_d.tolist(), "fine": fine}


def engine_errors(albedo, d_mm: np.ndarray, mc_profile, mc_albedo) -> dict[str, Any]:
    """What each engine renders for the preset (``engines.engine_marginals``: its kernel as that engine builds it)
    against the Burley profile and against the Monte Carlo profile, as 1D-marginal bin masses (bins of d/4 out to
    20 d plus both tails): relative L2 and the fraction of the reference's diffuse reflectance the engine loses."""
    from ..engines._common import masses_from_cdf as _masses_from_cdf
    from ..engines import engine_errors_against, engine_marginals

    marg = engine_marginals(albedo, d_mm)
    edges = marg["edges"]
    cdf = np.stack([np.asarray(marginal_cdf(mc_profile, jnp.asarray(edges[c])))[:, c] for c in range(3)])
    m_mc = _masses_from_cdf(cdf)
    return {"metric": "1D marginal (one separable pass / the projection of a radial kernel) bin masses, bins d/4 "
                      "wide to 20 d plus tails: relative L2 per channel; energy_lost = 1 - A_engine sum(m_engine) / "
                      "(A_ref sum(m_ref))",
            "vs_burley": engine_errors_against(marg, marg["reference"], marg["albedo"]["reference"]),
            "vs_montecarlo": engine_errors_against(marg, m_mc, mc_albedo)}
