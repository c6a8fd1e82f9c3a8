"""What every engine shares: checked per-channel inputs, the memo's s(A) fits in float64, and the 1D-marginal bins
on which every engine's kernel is compared with the Burley reference (host-side NumPy, float64, never traced)."""

from __future__ import annotations

import math

import jax
import numpy as np

from .._checks import check_host_count
from .._profiles import SCALING_FITS, burley_cdf, burley_inverse_cdf

FOUR_PI = 4.0 * math.pi


def s_fit(fit: str, albedo) -> np.ndarray:
    """The memo's s(A) fit from ``_profiles`` (``searchlight``, ``diffuse_transmission``, ``diffuse_mfp``), in float64
    whatever the global x64 setting."""
    with jax.enable_x64(True):
        return np.asarray(SCALING_FITS[fit](np.asarray(albedo, np.float64)), np.float64)


def rgb(name: str, value, *, lo: float | None = 0.0, hi: float | None = None, positive: bool = False) -> np.ndarray:
    """A per-channel parameter as float64 (3,), with its range checked; the error names the parameter."""
    try:
        v = np.broadcast_to(np.asarray(value, np.float64), (3,)).copy()
    except (ValueError, TypeError):
        raise ValueError(f"{name} must be one number or three (R,G,B), got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v.tolist()}")
    if positive and not np.all(v > 0):
        raise ValueError(f"{name} must be > 0, got {v.tolist()}")
    if lo is not None and not np.all(v >= lo):
        raise ValueError(f"{name} must be >= {lo}, got {v.tolist()}")
    if hi is not None and not np.all(v <= hi):
        raise ValueError(f"{name} must be <= {hi}, got {v.tolist()}")
    return v


def scalar(name: str, value, *, positive: bool = True, lo: float | None = None, hi: float | None = None) -> float:
    """A scalar parameter as float, finite (and > 0 unless ``positive=False``; within [lo, hi] if given)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or (positive and not v > 0):
        raise ValueError(f"{name} must be a finite {'positive ' if positive else ''}number, got {value!r}")
    if lo is not None and v < lo:
        raise ValueError(f"{name} must be >= {lo}, got {value!r}")
    if hi is not None and v > hi:
        raise ValueError(f"{name} must be <= {hi}, got {value!r}")
    return v


def count(name: str, value, *, lo: int = 1) -> int:
    """An integer parameter >= ``lo`` (``_checks.check_host_count``; a float with an integer value too, as a
    parameter read from JSON may be), as int; the error names the parameter."""
    return check_host_count(value, name, lo=lo, whole_floats=True)


def material(albedo, d_mm) -> tuple[np.ndarray, np.ndarray]:
    """sss_jax's material (albedo in [0, 1], Burley d >= 0 in mm), checked, as float64 (3,) arrays."""
    return rgb("albedo", albedo, lo=0.0, hi=1.0), rgb("d_mm", d_mm, lo=0.0)


def burley_inverse_cdf_np(u, d) -> np.ndarray:
    """``burley_inverse_cdf`` in float64 on the host (broadcasting ``u`` against ``d``)."""
    with jax.enable_x64(True):
        return np.asarray(burley_inverse_cdf(np.asarray(u, np.float64), np.asarray(d, np.float64)), np.float64)


def unit_burley_inverse_cdf(u: np.ndarray) -> np.ndarray:
    """x = r / d where Burley's CDF ``1 - exp(-x) / 4 - 3 exp(-x / 3) / 4`` reaches ``u`` in [0, 1), by Newton's
    method in NumPy float64 from below the root (the CDF is concave in x, so the iterates rise monotonically to it)."""
    u = np.asarray(u, np.float64)
    x = -3.0 * np.log(np.maximum((1.0 - u) * 4.0 / 3.0, 1e-300))  # 3 exp(-x/3)/4 = 1 - u: at or below the root
    x = np.maximum(x, 0.0)
    for _ in range(60):
        e1, e3 = np.exp(-x), np.exp(-x / 3.0)
        f = 1.0 - 0.25 * e1 - 0.75 * e3 - u
        step = f / (0.25 * e1 + 0.25 * e3)
        x = x - step
        if np.all(np.abs(step) <= 1e-13 * np.maximum(x, 1.0)):
            break
    return x


def burley_cdf_np(r, d) -> np.ndarray:
    with jax.enable_x64(True):
        return np.asarray(burley_cdf(np.asarray(r, np.float64), np.asarray(d, np.float64)), np.float64)


# --- 1D marginals: every engine's kernel as bin masses of the 1D marginal (what one separable pass applies) --------


def bins(d: np.ndarray) -> np.ndarray:
    """Per-channel bin edges (3, 162): width d/4 over [-20.125 d, 20.125 d], one bin centred on 0."""
    return d[:, None] * (np.arange(-80, 82) - 0.5)[None, :] / 4.0


def masses_from_cdf(cdf_at_edges: np.ndarray) -> np.ndarray:
    """Bin masses plus the two tails (mass below the first and above the last edge)."""
    return np.concatenate([cdf_at_edges[:, :1], np.diff(cdf_at_edges, axis=1), 1.0 - cdf_at_edges[:, -1:]], axis=1)


def _radial_marginal_cdf(x: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """1D marginal CDF of a radial distribution given by equal-mass radius quantiles ``radii (Q,)``:
    ``P(X <= x) = 1/2 + sign(x)/2 * mean_q P(|r_q cos theta| <= |x|)`` (the same estimator as ``marginal_cdf``)."""
    ax = np.abs(x)[..., None]
    r = radii[None, :]
    inside = np.where(r > ax, (2.0 / math.pi) * np.arcsin(np.clip(ax / np.where(r > 0, r, 1.0), 0.0, 1.0)), 1.0)
    return 0.5 + 0.5 * np.sign(x) * np.mean(inside, axis=-1)


_QUANTILES = (np.arange(8192) + 0.5) / 8192


def burley_marginal_masses(d: np.ndarray, edges: np.ndarray, u_max=None) -> np.ndarray:
    """Bin masses of the 1D marginal of the normalised Burley profile per channel, optionally truncated at the radius
    where its CDF reaches ``u_max`` (3,) and renormalised (what Cycles, HDRP and EEVEE Next render)."""
    u_max = np.ones(3) if u_max is None else np.asarray(u_max, np.float64)
    cdfs = []
    for c in range(3):
        if d[c] <= 0:
            cdfs.append(np.where(edges[c] >= 0, 1.0, 0.0))
            continue
        radii = d[c] * unit_burley_inverse_cdf(_QUANTILES * u_max[c])
        cdfs.append(_radial_marginal_cdf(edges[c], radii))
    return masses_from_cdf(np.stack(cdfs))


def piecewise_masses(lo: np.ndarray, hi: np.ndarray, weights: np.ndarray, edges: np.ndarray,
                     dirac: np.ndarray | None = None) -> np.ndarray:
    """Bin masses of a density that spreads tap ``i``'s weight (n, 3) uniformly over ``[lo_i, hi_i]`` (mm), plus an
    optional Dirac (3,) at 0: the model behind calculateKernel's ``area * profile`` and EEVEE's footprint integrals."""
    width = np.maximum(hi - lo, 1e-300)
    cdfs = []
    for c in range(3):
        x = edges[c][:, None]
        frac = np.clip((x - lo[None, :]) / width[None, :], 0.0, 1.0)
        cdf = frac @ weights[:, c]
        if dirac is not None:
            cdf = cdf + dirac[c] * (edges[c] >= 0)
        cdfs.append(cdf)
    return masses_from_cdf(np.stack(cdfs))


def relative_l2(masses: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-channel ``||m - m_ref|| / ||m_ref||`` over the bins (rows are channels)."""
    return np.linalg.norm(masses - reference, axis=1) / np.linalg.norm(reference, axis=1)
