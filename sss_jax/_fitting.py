"""Fitting the cheap models to physical references: objectives, two solvers, and the inverse fit from images.

Objectives (each a residual vector; the loss is half its squared norm):

- profile space, what ``separable`` renders: ``r_ij = (A_m(x_i, y_j) - R_ij) / ||R||_2`` on a (2N+1)^2 pixel grid of
  side ``pixel_mm``, where ``A_m(x, y) = a_m(x) a_m(y)`` is the outer product of the 1D two-Gaussian kernel (the two
  passes), integrated exactly over each pixel (erf differences), and ``R_ij`` the target profile's mass over pixel
  ij (centre pixel through the CDF, others by an 8x8 midpoint rule): a relative L2 per channel. Presets use pixels
  of side d (``RENDERED_PIXEL_PER_D``: the pixel spans +-d/2 about its centre, a face at ~1 px/mm) on +-20 pixels,
  which hold 99.9% of a Burley profile. The radial two-Gaussian mix ``w G_near + (1 - w) G_far`` (isotropic 2D
  Gaussians) is not what the pass renders: the product adds the cross terms ``w (1 - w) g_near(x) g_far(y)``, so a
  kernel fitted as a radial mix renders a cross-shaped spread (``rendered_kernel_errors`` reports both).
- image space: ``r = (separable(E_k; two-Gaussian) - reference(E_k; target)) / ||reference||`` over test irradiance
  patterns ``E_k`` (shadow edge, thin line, point light, textured, curved surface with depth): the error under
  practical lighting, which is what Jimenez et al. optimised.
- STA: ``r = STA(t, L, V) - T(t) cos(theta_L)`` over slab thicknesses t and light/view angles, with the target
  transmittance ``T(t) = (exp(-t/d) + 3 exp(-t/(3d)))/4`` of the Burley profile through the slab (the complementary
  CDF at r = t: HDRP's thin-object transmission) or a Monte Carlo slab transmittance.

Solvers: ``"optimistix"`` (Levenberg–Marquardt on the residuals, unconstrained log/logit parameters) and ``"jaxopt"``
(bounded L-BFGS-B on the loss in the natural parameters). The profile fits start from the moments of the target
and keep the best of up to four starts; the image and STA fits start once (from the profile fit, and from fixed
values scaled by d). Every fit returns a record: solver, outcome (``AT_SEARCH_BOUND`` where a parameter ended at the
edge of its search range rather than at an optimum), iterations, seconds, final error.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._checks import check_host_count, check_host_range
from ._kernels import _check_taps
from ._materials import BurleyMaterial, STAParams, TwoGaussianMaterial
from ._profiles import AbstractProfile, BurleyProfile
from ._scene import Buffers, Camera
from ._techniques import burley, reference, separable, sta_term, thin_transmittance

__all__ = ["SOLVERS", "RENDERED_PIXEL_PER_D", "RENDERED_HALF_PX", "rendered_kernel_errors", "radial_mix_pixel_mass",
           "fit_two_gaussian_profile", "fit_two_gaussian_to_burley", "fit_two_gaussian_image",
           "fit_sta", "fit_burley_from_image", "image_patterns", "profile_pixel_mass", "two_gaussian_pixel_mass",
           "burley_slab_transmittance", "sta_slab_response"]

SOLVERS = ("optimistix", "jaxopt")


def _check_solver(solver: str) -> None:
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; valid solvers: {', '.join(SOLVERS)}")


# ------------------------------------------------------------------------------------------------------------------
# profile space
# ------------------------------------------------------------------------------------------------------------------


RENDERED_PIXEL_PER_D = 1.0  # pixel side of the rendered-product objective and error, in units of each channel's d
RENDERED_HALF_PX = 20  # +-20 pixels of side d: Burley's CCDF at 20 d is 1e-3


def profile_pixel_mass(profile: AbstractProfile, pixel_mm: float, half: int, *, sub: int = 4) -> np.ndarray:
    """Mass of the normalised profile over each pixel of a (2 half + 1)^2 grid, ``(n, n, C)`` (host, float64): the
    centre pixel exactly through the CDF, the others by a ``sub`` x ``sub`` midpoint rule."""
    n = 2 * half + 1
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    idx = np.arange(-half, half + 1)
    xs = (idx[:, None] + offs[None, :]).reshape(-1) * pixel_mm
    r = np.sqrt(xs[:, None] ** 2 + xs[None, :] ** 2)
    dtype = profile.albedo.dtype
    vals = np.asarray(profile.radial(jnp.asarray(r.reshape(-1), dtype)), np.float64)
    c = vals.shape[-1]
    vals = vals.reshape(n, sub, n, sub, c).mean(axis=(1, 3)) * pixel_mm**2
    # the centre pixel holds the 1/r peak: its exact mass through the CDF, (4/pi) int_0^{pi/4} CDF(a / cos t) dt
    nodes, weights = np.polynomial.legendre.leggauss(24)
    t = (nodes + 1) * math.pi / 8
    cdf = np.asarray(profile.cdf(jnp.asarray(0.5 * pixel_mm / np.cos(t), dtype)), np.float64)
    vals[half, half] = (4 / math.pi) * np.sum(weights[:, None] * cdf, axis=0) * math.pi / 8
    return vals


def _normal_mass_1d(edges: jnp.ndarray, sigma: jnp.ndarray) -> jnp.ndarray:
    cdf = 0.5 * (1 + jax.scipy.special.erf(edges[:, None] / (math.sqrt(2) * sigma[None, :])))
    return cdf[1:] - cdf[:-1]


def two_gaussian_pixel_mass(w, sigma_near, sigma_far, pixel_mm: float, half: int) -> jnp.ndarray:
    """``a_m(x) a_m(y)`` integrated exactly over each pixel: ``(n, n, C)``."""
    edges = (jnp.arange(-half, half + 2) - 0.5) * pixel_mm
    m = w[None, :] * _normal_mass_1d(edges, sigma_near) + (1 - w[None, :]) * _normal_mass_1d(edges, sigma_far)
    return m[:, None, :] * m[None, :, :]


def radial_mix_pixel_mass(w, sigma_near, sigma_far, pixel_mm: float, half: int) -> jnp.ndarray:
    """The radial two-Gaussian mix ``w G_near(r) + (1 - w) G_far(r)`` (isotropic 2D Gaussians of unit mass)
    integrated exactly over each pixel: ``(n, n, C)``. Not what ``separable`` renders (see the module notes)."""
    edges = (jnp.arange(-half, half + 2) - 0.5) * pixel_mm
    mn, mf = _normal_mass_1d(edges, sigma_near), _normal_mass_1d(edges, sigma_far)
    return (w[None, None, :] * mn[:, None, :] * mn[None, :, :]
            + (1 - w[None, None, :]) * mf[:, None, :] * mf[None, :, :])


def rendered_kernel_errors(tg: dict, profile: AbstractProfile, pixel_mm, *, half: int = RENDERED_HALF_PX
                           ) -> dict[str, list[float]]:
    """Relative L2, per channel, of the two-Gaussian kernel ``tg`` (``w``, ``sigma_near_mm``, ``sigma_far_mm``,
    (3,) each) against ``profile`` on pixels of side ``pixel_mm[c]`` (mm, per channel), ``2 half + 1`` of them
    across: ``rendered_product`` is ``a(x) a(y)``, what ``separable`` renders; ``radial_mix`` the radial mix."""
    pix = np.broadcast_to(np.asarray(pixel_mm, np.float64), (profile.num_channels,))
    out: dict[str, list[float]] = {"rendered_product": [], "radial_mix": []}
    with jax.enable_x64(True):
        for c in range(profile.num_channels):
            target = profile_pixel_mass(profile, float(pix[c]), half, sub=8)[..., c]
            args = [jnp.asarray([float(tg[k][c])], _float_dtype()) for k in ("w", "sigma_near_mm", "sigma_far_mm")]
            for key, fn in (("rendered_product", two_gaussian_pixel_mass), ("radial_mix", radial_mix_pixel_mass)):
                model = np.asarray(fn(*args, float(pix[c]), half))[..., 0]
                out[key].append(float(np.linalg.norm(model - target) / np.linalg.norm(target)))
    return out


def _moments_sigma(target: np.ndarray, pixel_mm: float, half: int) -> np.ndarray:
    """Standard deviation of the target's 1D marginal per channel (its second moment along x)."""
    x = np.arange(-half, half + 1) * pixel_mm
    marginal = target.sum(axis=1)  # (n, C)
    total = marginal.sum(axis=0)
    return np.sqrt(np.maximum((marginal * x[:, None] ** 2).sum(axis=0) / np.maximum(total, 1e-30), 1e-12))


AT_SEARCH_BOUND = "at_search_bound"
# how near a bound of the search (not of the parameter's own range) a converged value may end and still count as
# found: relative to the bound, or to the span for a bound of 0
_BOUND_RTOL = 1e-3


def _solve(residual_fn: Callable, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, solver: str,
           max_steps: int = 400, args: Any = None, own_lower: Any = False,
           own_upper: Any = False) -> tuple[np.ndarray, str, int]:
    """Minimise ``0.5 ||residual(x, args)||^2`` for x in [lower, upper]; returns (x, outcome, iterations).

    optimistix works on z with x = lower + (upper - lower) sigmoid(z) (unconstrained); jaxopt's L-BFGS-B on x with
    the bounds directly. ``residual_fn`` should be one function object across calls (data in ``args``) so each
    solver compiles once. ``own_lower``/``own_upper`` (per coordinate, or one bool): which bounds are the
    parameter's own range (w in [0, 1]); the others only limit the search, and a value ending at one of them is no
    optimum found but the search's edge: the outcome is then ``AT_SEARCH_BOUND`` (d pinned at 20 d0 read as
    "successful", or as the step limit where the solver crawled towards it)."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    x, outcome, it = _solve_in(residual_fn, x0, lower, upper, solver, max_steps, args)
    if np.all(np.isfinite(x)):  # converged or stopped at max_steps (pinned: the solver crawls towards the bound)
        tol = _BOUND_RTOL * np.where(np.isfinite(upper - lower), upper - lower, 1.0)
        at_low = ~np.broadcast_to(np.asarray(own_lower, bool), x.shape) & (
            x <= lower + np.maximum(_BOUND_RTOL * np.abs(lower), np.where(lower == 0, tol, 0.0)))
        at_high = ~np.broadcast_to(np.asarray(own_upper, bool), x.shape) & (
            x >= upper - np.maximum(_BOUND_RTOL * np.abs(upper), np.where(upper == 0, tol, 0.0)))
        if np.any(at_low | at_high):
            outcome = AT_SEARCH_BOUND
    return x, outcome, it


def _solve_in(residual_fn: Callable, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, solver: str,
              max_steps: int, args: Any) -> tuple[np.ndarray, str, int]:
    if solver == "optimistix":
        import optimistix as optx

        lo, span = jnp.asarray(lower), jnp.asarray(upper - lower)
        p = np.clip((x0 - lower) / (upper - lower), 1e-6, 1 - 1e-6)
        z0 = jnp.asarray(np.log(p / (1 - p)))
        fn = _optx_residual(residual_fn)
        sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10), z0, args=(lo, span, args),
                                 max_steps=max_steps, throw=False)
        outcome = "successful" if sol.result == optx.RESULTS.successful else str(optx.RESULTS[sol.result]).strip()
        return np.asarray(lo + span * jax.nn.sigmoid(sol.value)), outcome, int(sol.stats["num_steps"])
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="JAXopt is no longer maintained", category=DeprecationWarning)
        import jaxopt
    # the data's arrays go through jaxopt's loop; its other leaves (counts: samples, taps) stay Python values, bound
    # into the loss (jaxopt carries its arguments as traced values: a count there was a tracer, and burley refused it)
    arrays, static = eqx.partition(args, eqx.is_array)
    leaves, shape = jax.tree.flatten(static)
    key = ("jaxopt-solver", residual_fn, max_steps, shape, tuple(leaves))
    if key not in _WRAPPED:  # one jitted run per residual: jaxopt's own loop is traced anew on every call otherwise
        loss = _jaxopt_loss(residual_fn)
        opt = jaxopt.LBFGSB(fun=lambda x, a: loss(x, eqx.combine(a, static)), maxiter=max_steps, tol=1e-9)
        _WRAPPED[key] = eqx.filter_jit(opt.run)
    res = _WRAPPED[key](jnp.asarray(x0), (jnp.asarray(lower), jnp.asarray(upper)), arrays)
    it = int(res.state.iter_num)
    # L-BFGS-B stops when its projected gradient's norm is within tol or at maxiter; a NaN norm stops it at once,
    # and the loop's own test then reads as converged: say what happened, as optimistix's result codes do
    finite = bool(np.all(np.isfinite(np.asarray(res.params)))) and bool(np.isfinite(float(res.state.value))) and \
        bool(np.isfinite(float(res.state.error)))
    outcome = ("nonfinite" if not finite else "max_steps_reached" if it >= max_steps else "successful")
    return np.asarray(res.params), outcome, it


# Wrapped residuals and solver objects, one per residual function (module-level, so the cache stays small): a second
# fit of the same shape reuses the compiled solver.
_WRAPPED: dict[tuple, Any] = {}


def _float_dtype():  # read when called: float64 under x64, else float32 (no truncation warning)
    return jnp.result_type(float)


def _optx_residual(fn):
    key = ("optx", fn)
    if key not in _WRAPPED:
        _WRAPPED[key] = lambda z, a: fn(a[0] + a[1] * jax.nn.sigmoid(z), a[2])
    return _WRAPPED[key]


def _jaxopt_loss(fn):
    key = ("jaxopt", fn)
    if key not in _WRAPPED:
        _WRAPPED[key] = lambda x, a: 0.5 * jnp.sum(fn(x, a) ** 2)
    return _WRAPPED[key]


def _profile_residual(x, data):
    """Residual of the profile-space fit for one channel; ``data = (target, weights, norm, pixel_mm)``."""
    target, weights, norm, pixel_mm = data
    half = (target.shape[0] - 1) // 2
    edges = (jnp.arange(-half, half + 2) - 0.5) * pixel_mm
    cdf = lambda s: 0.5 * (1 + jax.scipy.special.erf(edges / (math.sqrt(2) * s)))
    m1 = x[0] * jnp.diff(cdf(x[1])) + (1 - x[0]) * jnp.diff(cdf(x[2]))
    return ((m1[:, None] * m1[None, :] - target) * weights / norm).reshape(-1)


# the starts of the pixel-grid fit, (w, sigma_near, sigma_far) in units of the marginal's spread: the near Gaussian
# inside it, the far one outside
_GRID_STARTS = ((0.5, 0.4, 1.6), (0.3, 0.2, 1.3), (0.7, 0.6, 2.5), (0.6, 0.2, 2.0))


def fit_two_gaussian_grid(target: np.ndarray, pixel_mm: float, *, solver: str = "optimistix",
                          starts: int = 3, weighting: str = "none") -> tuple[np.ndarray, float, str, int]:
    """Fit one channel's ``(w, sigma_near, sigma_far)`` so the product ``a(x) a(y)`` matches a pixel grid of masses
    ``(2 half + 1, 2 half + 1)``; returns (params, relative L2, outcome, iterations). ``weighting``: ``"none"``
    (the rendered pixels as they are) or ``"radius"`` (each pixel times its distance to the centre, the r R(r) of
    the paper's Fig. 4)."""
    _check_solver(solver)
    starts = check_host_count(starts, "starts", hi=len(_GRID_STARTS))  # more were taken and 4 run, in silence
    if weighting not in ("none", "radius"):
        raise ValueError(f"unknown weighting {weighting!r}; valid: none, radius")
    target = np.asarray(target, np.float64)
    half = (target.shape[0] - 1) // 2
    idx = np.arange(-half, half + 1)
    radius = np.hypot(idx[:, None], idx[None, :]) * pixel_mm
    radius[half, half] = pixel_mm / math.sqrt(math.pi)  # the centre pixel's disc of equal area, its mean radius
    if weighting == "none":
        radius = np.ones_like(radius)
    norm = float(np.linalg.norm(target * radius))
    s0 = float(_moments_sigma(target[..., None], pixel_mm, half)[0])
    data = (jnp.asarray(target), jnp.asarray(radius), jnp.asarray(norm), jnp.asarray(pixel_mm))
    lower = np.array([0.0, 1e-3 * s0, 1e-3 * s0])
    upper = np.array([1.0, 10 * s0, 20 * s0])
    best = None
    for w0, fn, ff in _GRID_STARTS[:starts]:
        x, outcome, it = _solve(_profile_residual, np.array([w0, fn * s0, ff * s0]), lower, upper, solver, args=data,
                                own_lower=[True, False, False], own_upper=[True, False, False])
        err = float(jnp.linalg.norm(_profile_residual(jnp.asarray(x), data)))
        if best is None or err < best[1]:
            best = (x, err, outcome, it)
    x, err, outcome, it = best
    if x[1] > x[2]:  # name the narrower Gaussian "near"
        x = np.array([1 - x[0], x[2], x[1]])
    return x, err, outcome, it


def fit_two_gaussian_profile(profile: AbstractProfile, *, pixel_mm=None, half: int = RENDERED_HALF_PX,
                             solver: str = "optimistix", starts: int = 4, weighting: str = "none") -> dict[str, Any]:
    """Fit ``w, sigma_near, sigma_far`` per channel so ``a_m(x) a_m(y)``, the kernel ``separable`` renders, matches
    the profile on a pixel grid: ``||A_m - R|| / ||R||`` over ``(2 half + 1)^2`` pixels, both integrated over each
    pixel (``weighting="radius"``: ``||r (A_m - R)|| / ||r R||`` instead).

    ``pixel_mm``: the side of a pixel in mm, one value or one per channel (presets pass ``RENDERED_PIXEL_PER_D``
    times each channel's Burley d); default per channel: the grid spans 99.9% of that channel's energy, which for a
    Burley profile is a pixel of about d.
    """
    _check_solver(solver)
    half = check_host_count(half, "half")
    starts = check_host_count(starts, "starts", hi=len(_GRID_STARTS))
    out = {"w": [], "sigma_near_mm": [], "sigma_far_mm": []}
    records = []
    t0 = time.perf_counter()
    r999 = np.asarray(profile.radius_for_energy(0.999), np.float64)
    pixels = None if pixel_mm is None else np.broadcast_to(np.asarray(pixel_mm, np.float64), (profile.num_channels,))
    if pixels is not None and not np.all(np.isfinite(pixels) & (pixels > 0)):
        raise ValueError(f"pixel_mm must be finite and > 0 (one value or one per channel), got {pixel_mm!r}")
    for c in range(profile.num_channels):
        pix = float(pixels[c]) if pixels is not None else float(r999[c]) / half
        x, err, outcome, it = fit_two_gaussian_grid(profile_pixel_mass(profile, pix, half, sub=8)[..., c], pix,
                                                    solver=solver, starts=starts, weighting=weighting)
        out["w"].append(float(x[0]))
        out["sigma_near_mm"].append(float(x[1]))
        out["sigma_far_mm"].append(float(x[2]))
        records.append(dict(error=err, outcome=outcome, iterations=it, pixel_mm=pix))
    out["fit"] = {
        "solver": solver,
        "objective": ("rendered product: ||a_m(x)a_m(y) - R|| / ||R||" if weighting == "none" else
                      "profile space: ||r (a_m(x)a_m(y) - R)|| / ||r R||")
        + f" over {2 * half + 1}^2 pixels of side pixel_mm, both integrated over each pixel, per channel",
        "pixel_mm": [r["pixel_mm"] for r in records], "grid_half_px": half,
        "outcome": "successful" if all(r["outcome"] == "successful" for r in records) else
        ";".join(r["outcome"] for r in records),
        "iterations": [r["iterations"] for r in records], "seconds": round(time.perf_counter() - t0, 3),
        "error_relative_l2": [r["error"] for r in records],
    }
    return out


def _check_d(d_mm) -> np.ndarray:
    d = np.asarray(d_mm, np.float64)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.all(d > 0):
        raise ValueError(f"d_mm must be 3 finite values > 0 to fit to (d = 0 is the identity: there is no kernel to "
                         f"fit); got {d.tolist()}")
    return d


def fit_two_gaussian_to_burley(d_mm, *, pixel_mm=None, solver: str = "optimistix") -> dict[str, Any]:
    """Fit of the two-Gaussian kernel, as ``separable`` renders it, to a Burley profile (d in mm, (3,)); pixels of
    side ``RENDERED_PIXEL_PER_D`` d per channel unless ``pixel_mm`` says otherwise. Burley profiles share one shape,
    so the kernel scales with d."""
    d_mm = _check_d(d_mm)
    with jax.enable_x64(True):
        return fit_two_gaussian_profile(BurleyProfile(jnp.asarray(d_mm, _float_dtype())),
                                        pixel_mm=RENDERED_PIXEL_PER_D * d_mm if pixel_mm is None else pixel_mm,
                                        solver=solver)


# ------------------------------------------------------------------------------------------------------------------
# image space
# ------------------------------------------------------------------------------------------------------------------


def image_patterns(size: int = 32, *, depth: float = 10.0) -> list[Buffers]:
    """Test irradiance: shadow edge, thin line, point light, textured, and a curved surface (a bump in depth)."""
    rng = np.random.default_rng(0)
    z = np.full((size, size), depth)
    edge = np.zeros((size, size, 3))
    edge[:, size // 2:] = 1.0
    line = np.full((size, size, 3), 0.05)
    line[:, size // 2] = 1.0
    point = np.zeros((size, size, 3))
    point[size // 2, size // 2] = 20.0
    tex = np.repeat(rng.uniform(0.2, 1.0, (size // 4, size // 4, 1)), 4, 0).repeat(4, 1) * np.ones((1, 1, 3))
    ys, xs = np.mgrid[0:size, 0:size] - size / 2
    curved_z = depth - 0.3 * np.exp(-(xs**2 + ys**2) / (2 * (size / 5) ** 2))
    curved_e = np.clip(0.5 + xs / size, 0, 1)[..., None] * np.ones((1, 1, 3))
    mk = lambda e, zz: Buffers(irradiance=jnp.asarray(e, _float_dtype()), depth=jnp.asarray(zz, _float_dtype()))
    return [mk(edge, z), mk(line, z), mk(point, z), mk(tex, z), mk(curved_e, curved_z)]


def image_error(material: TwoGaussianMaterial, target, camera: Camera, patterns: list[Buffers] | None = None, *,
                taps: int = 25, references: list | None = None, border: str = "leaves") -> float:
    """Relative L2 of ``separable`` with the two-Gaussian kernel against ``reference`` with the target, over the
    patterns (albedo 1)."""
    patterns = patterns or image_patterns()
    # the test patterns are surfaces that end at the frame (``border``: light leaves there), the rule the presets'
    # stored errors were computed with
    refs = references or [np.asarray(reference(b, target, camera, border=border)) for b in patterns]
    outs = [np.asarray(separable(b, material, camera, taps=taps, border=border)) for b in patterns]
    num = sum(np.sum((o - r) ** 2) for o, r in zip(outs, refs))
    return float(np.sqrt(num / sum(np.sum(r**2) for r in refs)))


# The residuals are module-level functions with their data in ``args``: one function object across fits, so a second
# material of the same shape reuses the compiled solver (a fresh closure per call would recompile every time).


def _image_residual(x, data):
    patterns, refs, norm, camera, taps = data
    mat = TwoGaussianMaterial(jnp.ones(3, x.dtype), x[0:3], x[3:6], x[6:9])
    return jnp.concatenate([((separable(b, mat, camera, taps=taps) - r) / norm).reshape(-1)
                            for b, r in zip(patterns, refs)])


def _sta_residual(x, data):
    lights, views, thickness_mm, target = data
    p = STAParams(distortion=x[0], power=x[1], scale=x[2:5], ambient=x[5:8], thickness_mm=x[8:11])
    values = jax.vmap(lambda light, view: sta_slab_response(p, thickness_mm, light, view))(lights, views)
    return (values - target).reshape(-1)


def _burley_image_residual(x, data):
    buffers, target, norm, albedo, camera, samples = data
    out = burley(buffers, BurleyMaterial(albedo, x), camera, samples=samples, interpolation="bilinear")
    return ((out - target) / norm).reshape(-1)


def fit_two_gaussian_image(target: BurleyMaterial, camera: Camera, *, taps: int = 25, init: dict | None = None,
                           solver: str = "optimistix", size: int = 32) -> dict[str, Any]:
    """Image-space fit: separable with the two-Gaussian kernel against reference with the target (one material),
    both at albedo 1 (the kernel's shape is what is fitted; the target's albedo scales both alike). ``init``: the
    start, ``w`` in [0, 1] and ``sigma_near_mm``/``sigma_far_mm`` > 0, three values each (default: the profile
    fit)."""
    _check_solver(solver)
    _check_taps(taps)  # before the references' renders (it was found after them)
    if check_host_count(size, "size") < 8:
        raise ValueError(f"size must be at least 8 pixels (the test patterns' features), got {size}")
    if init is not None and (not isinstance(init, dict) or
                             not {"w", "sigma_near_mm", "sigma_far_mm"} <= set(init)):
        raise ValueError(f"init must be a dict with w, sigma_near_mm and sigma_far_mm, got {init!r:.80}")
    if init is not None:  # before the references' renders (a bad start failed inside the solver's loop)
        for key, high, low_open in (("w", 1.0, False), ("sigma_near_mm", math.inf, True),
                                    ("sigma_far_mm", math.inf, True)):
            try:
                v = np.asarray(init[key], np.float64)
            except (TypeError, ValueError):
                v = None
            if v is None or v.shape != (3,):
                raise ValueError(f"init[{key!r}] must be three numbers (one per channel), got {init[key]!r:.80}")
            check_host_range(v, f"init[{key!r}]", high=high, low_open=low_open)
    patterns = image_patterns(size)
    # the references at albedo 1, as the model renders (with the target's albedo they were darker than any kernel
    # the fit could find: w collapsed and sigma_far ran off, reported "successful"; found by a review)
    unit = BurleyMaterial(jnp.ones_like(jnp.asarray(target.albedo)), target.d_mm)
    refs = [reference(b, unit, camera) for b in patterns]
    norm = float(np.sqrt(sum(np.sum(np.asarray(r) ** 2) for r in refs)))
    if init is None:
        init = fit_two_gaussian_to_burley(np.asarray(target.d_mm[0]))
    x0 = np.concatenate([init["w"], init["sigma_near_mm"], init["sigma_far_mm"]])

    data = (patterns, refs, jnp.asarray(norm), camera, taps)
    residual = lambda x: _image_residual(x, data)
    s = np.concatenate([init["sigma_near_mm"], init["sigma_far_mm"]])
    lower = np.concatenate([np.zeros(3), 1e-3 * s])
    upper = np.concatenate([np.ones(3), 10 * s])
    t0 = time.perf_counter()
    x, outcome, it = _solve(_image_residual, x0, lower, upper, solver, max_steps=100, args=data,
                            own_lower=np.arange(9) < 3, own_upper=np.arange(9) < 3)  # w's range is its own
    err = float(jnp.linalg.norm(residual(jnp.asarray(x))))
    near, far = x[3:6], x[6:9]
    w = np.where(near <= far, x[0:3], 1 - x[0:3])
    return {"w": w.tolist(), "sigma_near_mm": np.minimum(near, far).tolist(),
            "sigma_far_mm": np.maximum(near, far).tolist(),
            "fit": {"solver": solver, "objective": "image-space relative L2 of separable against reference over "
                    "shadow edge, thin line, point light, texture and a curved surface",
                    "outcome": outcome, "iterations": it, "seconds": round(time.perf_counter() - t0, 3),
                    "error_relative_l2": err, "initial_error_relative_l2": float(jnp.linalg.norm(residual(jnp.asarray(x0))))}}


# ------------------------------------------------------------------------------------------------------------------
# STA
# ------------------------------------------------------------------------------------------------------------------


def burley_slab_transmittance(thickness_mm, d_mm):
    """Light through a slab of thickness t from the Burley profile: its complementary CDF at r = t,
    ``(exp(-t/d) + 3 exp(-t/(3d))) / 4`` per channel (HDRP's thin-object transmission for the same profile)."""
    t = jnp.asarray(thickness_mm)[..., None]
    d = jnp.asarray(d_mm)
    return thin_transmittance(t, d.reshape((1,) * (t.ndim - 1) + d.shape))


def sta_slab_response(params: STAParams, thickness_mm, light_dir, view_dir):
    """STA's light through slabs of the given thicknesses, ``(Nt, 3)``: the lit face looks at the camera
    (N = (0, 0, -1) in camera space), ``light_dir`` points from the surface to the light behind the slab and
    ``view_dir`` from the surface to the eye (unit vectors, camera space), the light white and of unit irradiance."""
    from ._materials import DirectionalLight

    tt = jnp.asarray(thickness_mm)
    n = tt.shape[0]
    normal = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0], tt.dtype), (1, n, 3))
    v = jnp.broadcast_to(jnp.asarray(view_dir, tt.dtype), (1, n, 3))
    light = DirectionalLight.__new__(DirectionalLight)  # traced direction: skip the host-side unit-length check
    object.__setattr__(light, "direction", jnp.asarray(light_dir, tt.dtype))
    object.__setattr__(light, "colour", jnp.ones(3, tt.dtype))
    return sta_term(normal, v, light, params, tt[None, :])[0]


def fit_sta(d_mm, *, solver: str = "jaxopt", transmittance: Callable | None = None,
            thickness_range: tuple[float, float] | None = None) -> dict[str, Any]:
    """Fit the STA parameters to slab transmission over thicknesses and light/view angles.

    Target: ``T(t) cos(theta_L)`` (diffuse light through the slab, Lambertian at the back face), T from the Burley
    profile or ``transmittance(t_mm) -> (N, 3)`` (e.g. a Monte Carlo slab). The STA term is evaluated with the back
    face's normal opposite the view plane's, the light behind at theta_L, the view at theta_V. Solved in float64
    (as the two-Gaussian fits are): in float32 L-BFGS-B cannot meet its 1e-9 tolerance and ran to its step limit.
    """
    with jax.enable_x64(True):
        return _fit_sta(d_mm, solver, transmittance, thickness_range)


def _fit_sta(d_mm, solver: str, transmittance: Callable | None, thickness_range) -> dict[str, Any]:
    _check_solver(solver)
    d = _check_d(d_mm)
    if thickness_range is not None:
        if np.shape(thickness_range) != (2,):
            raise ValueError(f"thickness_range must be (lo, hi) in mm, got {thickness_range!r}")
        check_host_range(thickness_range, "thickness_range", low_open=True)
        if not thickness_range[0] < thickness_range[1]:
            raise ValueError(f"thickness_range must be (lo, hi) with lo < hi, got {thickness_range!r}")
    lo, hi = thickness_range or (0.05 * d.min(), 6.0 * d.max())
    t = np.geomspace(lo, hi, 16)
    angles = np.radians([0.0, 30.0, 60.0])
    T = np.asarray(transmittance(t) if transmittance else burley_slab_transmittance(t, d))  # (Nt, 3)
    if T.shape != (t.size, 3) or not np.all(np.isfinite(T)) or np.any(T < 0):
        raise ValueError(f"transmittance(t_mm) must return ({t.size}, 3) finite values >= 0 for the {t.size} "
                         f"thicknesses, got shape {T.shape}"
                         + ("" if T.shape != (t.size, 3) else " with non-finite or negative values"))
    rows = []
    for tl in angles:
        for tv in angles:
            # camera space: view along -z to the camera; the lit surface faces the camera (N = (0,0,-1)),
            # the light is behind the slab at theta_L from the axis, the view leaves at theta_V
            light = np.array([math.sin(tl), 0.0, math.cos(tl)])
            view = np.array([-math.sin(tv), 0.0, -math.cos(tv)])
            rows.append((light, view, math.cos(tl)))
    L = jnp.asarray(np.stack([r[0] for r in rows]))
    V = jnp.asarray(np.stack([r[1] for r in rows]))
    cosl = jnp.asarray([r[2] for r in rows])
    target = jnp.asarray(T)[None, :, :] * cosl[:, None, None]  # (A, Nt, 3)
    tt = jnp.asarray(t)

    data = (L, V, tt, target)
    residual = lambda x: _sta_residual(x, data)
    x0 = np.concatenate([[0.2, 2.0], np.full(3, 1.0), np.full(3, 0.05), d * 2])
    lower = np.concatenate([[0.0, 0.0], np.zeros(3), np.zeros(3), d * 0.01])
    upper = np.concatenate([[1.0, 16.0], np.full(3, 4.0), np.full(3, 2.0), d * 100])
    t0 = time.perf_counter()
    # Levenberg-Marquardt needs ~350 steps here to meet its 1e-8 tolerance (L-BFGS-B ~150); both reach one optimum
    x, outcome, it = _solve(_sta_residual, x0, lower, upper, solver, max_steps=1000, args=data,
                            own_lower=np.arange(11) < 8, own_upper=np.arange(11) < 1)  # distortion in [0, 1]
    err = float(jnp.linalg.norm(residual(jnp.asarray(x))) / jnp.linalg.norm(target))
    return {"distortion": float(x[0]), "power": float(x[1]), "scale": x[2:5].tolist(), "ambient": x[5:8].tolist(),
            "thickness_mm": x[8:11].tolist(),
            "fit": {"solver": solver, "objective": "STA against T(t) cos(theta_L) over 16 thicknesses and 3x3 angles",
                    "outcome": outcome, "iterations": it, "seconds": round(time.perf_counter() - t0, 3),
                    "error_relative_l2": err}}


# ------------------------------------------------------------------------------------------------------------------
# inverse fit from images
# ------------------------------------------------------------------------------------------------------------------


def fit_burley_from_image(buffers: Buffers, target_image, camera: Camera, *, albedo, d0_mm, samples: int = 16,
                          solver: str = "optimistix") -> dict[str, Any]:
    """Recover Burley's d per channel (mm) by differentiating ``burley`` (bilinear, smooth in d) against a target
    image of the same frame, e.g. an offline render; ``albedo (3,)`` is known."""
    _check_solver(solver)
    samples = check_host_count(samples, "samples")  # (2.7 ran 2 samples and fitted d to them)
    check_host_range(albedo, "albedo", high=1.0)
    d0 = _check_d(d0_mm)  # the search spans d0 / 20 .. 20 d0: each channel's start must be finite and > 0
    t = np.asarray(target_image, np.float64)
    shape = tuple(buffers.irradiance.shape)
    if t.shape != shape:
        raise ValueError(f"target_image is {t.shape}, the buffers' irradiance {shape}: the same frame is needed")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"target_image has {int(np.sum(~np.isfinite(t)))} non-finite values (NaN or inf)")
    if not np.sum(t) > 0:
        raise ValueError("target_image is black (or negative) overall: there is no light to fit d to")
    target = jnp.asarray(target_image)
    norm = float(jnp.linalg.norm(target))
    alb = jnp.asarray(albedo, _float_dtype())

    data = (buffers, target, jnp.asarray(norm), alb, camera, samples)
    residual = lambda x: _burley_image_residual(x, data)
    t0 = time.perf_counter()
    x, outcome, it = _solve(_burley_image_residual, d0, d0 / 20, d0 * 20, solver, max_steps=200, args=data)
    return {"d_mm": x.tolist(), "fit": {"solver": solver, "outcome": outcome, "iterations": it,
                                       "seconds": round(time.perf_counter() - t0, 3),
                                       "error_relative_l2": float(jnp.linalg.norm(residual(jnp.asarray(x))))}}
