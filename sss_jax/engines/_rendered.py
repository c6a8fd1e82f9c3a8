"""What each engine's own screen-space pass renders for a material, as 1D-marginal bin masses on the bins of
``engine_marginals`` (host-side NumPy, float64): the kernel the pass applies at its real budget, beside the idealised
kernel of each engine class's ``marginal``. The techniques ``hdrp``, ``eevee-next`` and ``jimenez`` run the same
passes on frames; docs/engines.md cites the sources.

- HDRP (``SubsurfaceScattering.compute``): ``n = min(pi (filter radius px)^2 / 4, budget)`` samples at the widest
  channel's Burley radii for ``u = i/n + 0.5/n``, weighted ``R_c(r) / pdf_max(r)`` and renormalised per channel; the
  rotation hash averages each sample into a ring (noise-averaged; point fetches unrounded), at ``px_per_mm``.
- EEVEE Next (``eevee_subsurface.cc`` ``precompute_samples_location``): per TAA sample 16 samples at ``x = (1 +
  rand_v/16) i/16`` of the truncated CDF of ``d0 max(radius)``, sample 0 at the centre, weighted ``burley_eval(d_c,
  r) pdf_inv`` and renormalised, averaged over ``frames`` TAA samples (rings again: ``rand_u`` turns the pattern).
- Jimenez (``SSSSBlurPS``, ``_jimenez.jimenez_comb_masses``): the comb of ``calculateKernel`` taps at ``offset 2/3 sssWidth alpha`` mm per kernel unit,
  each a bilinear fetch at ``px_per_mm`` (its weight split between two pixels), every pixel's mass spread over its
  footprint; the vertical pass (the horizontal one is W/H wider on a non-square frame).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ._common import masses_from_cdf, unit_burley_inverse_cdf

HDRP_BUDGETS = {"low": 20, "medium": 40, "high": 80}  # DefaultSssSampleBudgetForQualityLevel
HDRP_FILTER_UNITS = float(unit_burley_inverse_cdf(np.array([0.997]))[0])  # UpdateKernel: CDF 0.997 of the widest d
EEVEE_SAMPLE_LEN = 16
EEVEE_TRUNCATE_CDF = 0.9963790093708328
EEVEE_MIN_RADIUS = 1e-4  # convolve shader: a channel's radius is at least 1e-4 of the largest (4.2)
EEVEE_D0 = 0.25 / math.pi / (1.9 - 1.0 + 3.5 * 0.2**2)  # burley_setup(1, 1)
RENDER_PX_PER_MM = 1.0  # the pixel density at which the rendered kernels are stated
EEVEE_FRAMES = 256  # TAA samples of a final EEVEE render (the viewport default is 16)


def ring_masses(radii: np.ndarray, weights: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin masses of the 1D marginal of rings: ring ``i`` of radius ``radii (n,)`` (mm) carries ``weights (n, 3)``
    (each column sums to 1) spread uniformly over its angle; a ring of radius 0 is a Dirac at 0.

    A ring of radius r puts ``(2/pi) arcsin(|x|/r)`` of its mass within ``|x|`` (all of it past r), so its CDF is
    ``1/2 + sign(x)/2`` of that; the arcsines are taken once per distinct ``|x|`` (the bins are symmetric about 0,
    so half of them) and weighted by one product per channel."""
    radii = np.asarray(radii, np.float64)
    weights = np.asarray(weights, np.float64)
    ring = radii > 0
    r = np.where(ring, radii, 1.0)[None, :]
    w_ring = np.where(ring[:, None], weights, 0.0)
    w_dirac = weights[~ring].sum(axis=0)
    cdfs = []
    for c in range(3):
        x = edges[c]
        ax, where = np.unique(np.abs(x), return_inverse=True)
        a = ax[:, None]
        inside = np.where(r > a, (2.0 / math.pi) * np.arcsin(np.clip(a / r, 0.0, 1.0)), 1.0)
        within = (inside @ w_ring[:, c])[where.reshape(-1)]  # mass of the rings within |x|
        cdfs.append(0.5 * w_ring[:, c].sum() + np.where(x >= 0, 0.5, -0.5) * within + np.where(x >= 0, w_dirac[c], 0.0))
    return masses_from_cdf(np.stack(cdfs))


def hdrp_samples(d_mm: np.ndarray, budget: int, px_per_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Radii (n,) mm and per-channel weights (n, 3) (columns summing to 1) of HDRP's pass on a flat surface."""
    d = np.asarray(d_mm, np.float64)
    d_max = float(np.max(d))
    filter_px = HDRP_FILTER_UNITS * d_max * px_per_mm
    n = min(int(math.pi * filter_px**2 / 4), int(budget))
    if n < 1:
        return np.zeros(1), np.ones((1, 3))
    u = np.arange(n) / n + 0.5 / n
    radii = d_max * unit_burley_inverse_cdf(u)
    exp_sum = lambda x: np.exp(-x / 3) + np.exp(-x)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        w = s[None, :] * exp_sum(radii[:, None] * s[None, :]) * d_max / exp_sum(radii / d_max)[:, None]
    w = np.where(d[None, :] > 0, w, 0.0)
    w[0, d <= 0] = 1.0  # (a channel without scattering: the technique keeps its own irradiance; drawn as sample 0)
    return radii, w / w.sum(axis=0)


@functools.lru_cache(maxsize=8)
def _eevee_next_unit_rings(frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``(frames, 16)`` radii in units of ``max(radius)`` and their inverse pdf, one row per TAA sample ``k``: they
    depend on nothing but ``k`` (``rand_v``, the base-3 radical inverse of ``k + 1``), so they are computed once per
    frame count, read-only (a rendered fit evaluates the pass for hundreds of d)."""
    rand_v = np.zeros(frames)
    for k in range(frames):
        f, idx = 1.0, k + 1
        while idx > 0:
            f /= 3
            rand_v[k] += f * (idx % 3)
            idx //= 3
    i = np.arange(EEVEE_SAMPLE_LEN)
    x = (1 + rand_v[:, None] / EEVEE_SAMPLE_LEN) * (i[None, :] / EEVEE_SAMPLE_LEN)
    r_unit = EEVEE_D0 * unit_burley_inverse_cdf(x * EEVEE_TRUNCATE_CDF)
    pdf_inv = EEVEE_TRUNCATE_CDF * 8 * math.pi * EEVEE_D0 / (np.exp(-r_unit / EEVEE_D0)
                                                             + np.exp(-r_unit / (3 * EEVEE_D0)))
    r_unit.setflags(write=False)
    pdf_inv.setflags(write=False)
    return r_unit, pdf_inv


def _eevee_next_rings(albedo, d_mm: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``eevee_next_weights`` stacked: radii ``(frames, 16)`` mm and weights ``(frames, 16, 3)``."""
    a = np.asarray(albedo, np.float64)
    a = a / max(1e-6, float(np.max(a)))
    s = 1.9 - a + 3.5 * (a - 0.8) ** 2
    d = np.asarray(d_mm, np.float64)
    radius = d * 4 * math.pi * s
    max_radius = float(np.max(radius))
    d_shader = 0.25 / math.pi * np.maximum(EEVEE_MIN_RADIUS, radius / max_radius) * max_radius / s
    r_unit, pdf_inv = _eevee_next_unit_rings(int(frames))
    r = r_unit * max_radius  # (frames, 16)
    burley = (np.exp(-r[..., None] / d_shader) + np.exp(-r[..., None] / (3 * d_shader))) / (4 * d_shader)
    w = burley * pdf_inv[..., None]
    return r, w / w.sum(axis=1, keepdims=True)  # each TAA sample's weights renormalised per channel


def eevee_next_weights(albedo, d_mm: np.ndarray, frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per TAA sample (``rand_v`` from the base-3 radical inverse of ``k + 1``, as the ``eevee-next`` technique),
    the radii (16,) mm and per-channel weights (16, 3) of EEVEE Next's pass on a flat surface."""
    return list(zip(*_eevee_next_rings(albedo, d_mm, frames)))


def hdrp_masses(d_mm: np.ndarray, budget: int, edges: np.ndarray, px_per_mm: float = RENDER_PX_PER_MM) -> np.ndarray:
    """HDRP's pass at ``budget`` as bin masses (noise-averaged rings)."""
    radii, weights = hdrp_samples(d_mm, budget, px_per_mm)
    return ring_masses(radii, weights, edges)


def eevee_next_masses(albedo, d_mm: np.ndarray, frames: int, edges: np.ndarray) -> np.ndarray:
    """EEVEE Next's pass after ``frames`` TAA samples as bin masses (noise-averaged rings)."""
    r, w = _eevee_next_rings(albedo, d_mm, frames)
    # every frame's rings at once, each frame's weight 1/frames
    return ring_masses(r.reshape(-1), w.reshape(-1, 3) / r.shape[0], edges)


def fit_d_through(render, d_mm: np.ndarray, edges: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The d per channel whose rendered kernel ``render(d) -> masses`` is closest to ``reference`` (the material's
    Burley marginal on ``edges``): ``scipy.optimize.least_squares`` (trf) over ``log(d' / d)`` in [-3, 3] from 0 on
    the residuals ``(m(d') - m_ref) / ||m_ref||`` of the three channels. Returns ``(d', relative L2 per channel)``."""
    from scipy.optimize import least_squares

    from ._common import relative_l2

    d = np.asarray(d_mm, np.float64)
    norm = np.linalg.norm(reference, axis=1, keepdims=True)

    def residuals(p):
        return ((render(d * np.exp(p)) - reference) / norm).ravel()

    sol = least_squares(residuals, np.zeros(3), bounds=(-3.0, 3.0), method="trf", diff_step=1e-4, max_nfev=200)
    d_fit = d * np.exp(sol.x)
    return d_fit, relative_l2(render(d_fit), reference)
