"""Slab transmission of the medium behind a Burley material, from a Monte Carlo table (data/slab_transmittance.json).

The medium: index-matched (eta = 1), isotropic, single-scattering albedo ``alpha`` with ``A = 1 - H(1) sqrt(1 - alpha)``
(Chandrasekhar, Radiative Transfer 1960, Ch. V: the exact plane albedo of the semi-infinite medium under a normal
beam) and mean free path ``l = d s(A)``, ``s(A) = 1.85 - A + 7 |A - 0.8|^3`` (Christensen & Burley 2015, Eq. 6, the
searchlight fit) -- the medium ``_fit_presets.material_source`` derives for artist materials. ``T(alpha, tau)``,
``tau = t / l``, is the total (ballistic + scattered) transmittance of a slab of that medium under a normal pencil beam
(equal, by translation invariance, to that of a uniform normal back-light), tabulated once by
``scripts/slab_transmittance_table.py`` with ``_montecarlo.simulate``.

Table coordinates (``w``, ``v``) in [0, 1]^2, both on uniform grids: ``u = sqrt(1 - alpha) = w^2`` (nodes crowd
towards alpha = 1, where the thick-slab decay rate ~ sqrt(3) u changes fastest) and ``v`` the position of ``log tau``
between ``log tau_min`` and ``log tau_max(u)``; ``tau_max(u)`` stops each row where T is ~3e-4, the depth the Monte
Carlo still resolves to a few per cent. Between nodes: the bicubic (C1) tensor-product not-a-knot spline of ``log T``
(smooth, and exact for the MC values at the nodes). Outside: ``tau < tau_min`` takes ``log T`` linear in tau from the
row's first node to ``log T(0) = 0``; ``tau > tau_max`` continues ``log T`` with the row's last decay rate
``-d log T / d tau`` (exponential extrapolation; the exact asymptote for alpha < 1 is ``C exp(-k tau)``).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from importlib import resources
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ._profiles import scaling_searchlight

__all__ = ["TABLE_PATH", "single_scattering_albedo", "slab_transmittance", "slab_transmittance_mfp", "table_stderr",
           "tau_max"]

TABLE_PATH = "data/slab_transmittance.json"

# grid of the table: tau from TAU_MIN to tau_max(u) = 1 / sqrt(TAU_CAP^-2 + (k(u) / K_TARGET)^2), a smooth minimum of
# TAU_CAP and K_TARGET / k(u), where k(u) = sqrt(3) u / sqrt(1 + 2 u^2) follows the asymptotic decay rate of T
# (diffusion: sqrt(3 (1 - alpha)) = sqrt(3) u near alpha = 1; 1, the ballistic rate, at alpha = 0), so that every row
# ends near T ~ C exp(-K_TARGET)
TAU_MIN = 0.01
TAU_CAP = 60.0
K_TARGET = 8.0


def _decay_rate_guess(u: ArrayLike, xp: Any = np) -> ArrayLike:
    return xp.sqrt(3.0) * u / xp.sqrt(1.0 + 2.0 * u * u)


def tau_max(u: ArrayLike, xp: Any = np) -> ArrayLike:
    """Where the table's row at ``u = sqrt(1 - alpha)`` ends (in mean free paths): ``TAU_CAP`` at alpha = 1, ~8 at 0."""
    return 1.0 / xp.sqrt(TAU_CAP ** -2 + (_decay_rate_guess(u, xp) / K_TARGET) ** 2)


def tau_of(u: ArrayLike, v: ArrayLike, xp: Any = np) -> ArrayLike:
    """Slab thickness (mean free paths) at table coordinate ``v`` in [0, 1] of the row at ``u``."""
    x0 = xp.log(TAU_MIN)
    return xp.exp(x0 + v * (xp.log(tau_max(u, xp)) - x0))


@dataclasses.dataclass(frozen=True)
class _Table:
    w: np.ndarray  # (nw,) uniform in [0, 1]
    v: np.ndarray  # (nv,) uniform in [0, 1]
    logT: np.ndarray  # (nw, nv) and its spline derivatives d/dw, d/dv, d2/dwdv at the nodes
    dw: np.ndarray
    dv: np.ndarray
    dwv: np.ndarray
    map_w: np.ndarray  # (m,) uniform in [0, 1]: A(w) = 1 - H(1) w^2 at alpha = 1 - w^4, decreasing from 1 to 0
    map_A: np.ndarray
    stderr: np.ndarray  # (nw, nv) standard errors of the Monte Carlo values
    meta: dict[str, Any]


def _spline_slopes(y: np.ndarray, x: np.ndarray, axis: int) -> np.ndarray:
    from scipy.interpolate import CubicSpline

    return CubicSpline(x, y, axis=axis, bc_type="not-a-knot")(x, 1)


@functools.lru_cache(maxsize=1)
def _table() -> _Table:
    """The shipped table, read once."""
    return _load(json.loads(resources.files("sss_jax").joinpath(TABLE_PATH).read_text()), TABLE_PATH)


def _load(data: dict[str, Any], name: str) -> _Table:
    """A table from its JSON; the spline's node derivatives are computed here (host, float64)."""
    grid = data["grid"]
    if (grid["tau_min"], grid["tau_cap"], grid["k_target"]) != (TAU_MIN, TAU_CAP, K_TARGET):
        raise ValueError(f"{name} was made for another grid ({grid}); regenerate it with "
                         "scripts/slab_transmittance_table.py")
    T = np.asarray(data["T"], np.float64)
    if T.ndim != 2 or min(T.shape) < 4 or not np.all(T > 0):
        raise ValueError(f"{name}: T must be a table of at least 4 x 4 transmittances > 0, got shape {T.shape}")
    w = np.linspace(0.0, 1.0, T.shape[0])
    v = np.linspace(0.0, 1.0, T.shape[1])
    logT = np.log(T)
    dw = _spline_slopes(logT, w, 0)
    dv = _spline_slopes(logT, v, 1)
    dwv = _spline_slopes(dv, w, 0)  # the tensor-product spline's cross derivative
    amap = data["albedo_map"]
    return _Table(w=w, v=v, logT=logT, dw=dw, dv=dv, dwv=dwv, map_w=np.asarray(amap["w"], np.float64),
                  map_A=np.asarray(amap["A"], np.float64),
                  stderr=np.asarray(data["stderr"], np.float64), meta=data)


def _hermite_basis(s: Array) -> tuple[Array, Array, Array, Array]:
    """Cubic Hermite basis on [0, 1]: weights of (y0, y1, h y0', h y1')."""
    s2, s3 = s * s, s * s * s
    return 2 * s3 - 3 * s2 + 1, -2 * s3 + 3 * s2, s3 - 2 * s2 + s, s3 - s2


def _cell(x: Array, n: int) -> tuple[Array, Array]:
    """Cell index and local coordinate of ``x`` in [0, 1] on a uniform grid of n nodes."""
    pos = jnp.clip(x, 0.0, 1.0) * (n - 1)
    i = jnp.clip(jnp.floor(pos), 0, n - 2).astype(jnp.int32)
    return i, pos - i.astype(x.dtype)


def _hermite_w(tab: _Table, y: np.ndarray, dy: np.ndarray, w: Array) -> Array:
    """1D cubic Hermite in w of one column of node values and w-slopes."""
    i, s = _cell(w, tab.w.size)
    h = 1.0 / (tab.w.size - 1)
    a, b, c, d = _hermite_basis(s)
    y, dy = jnp.asarray(y, w.dtype), jnp.asarray(dy, w.dtype)
    return a * y[i] + b * y[i + 1] + h * (c * dy[i] + d * dy[i + 1])


def _bicubic(tab: _Table, w: Array, v: Array) -> Array:
    """The tensor-product spline of log T at (w, v), from node values and derivatives (bicubic Hermite)."""
    i, s = _cell(w, tab.w.size)
    j, t = _cell(v, tab.v.size)
    hw, hv = 1.0 / (tab.w.size - 1), 1.0 / (tab.v.size - 1)
    bw0, bw1, cw0, cw1 = _hermite_basis(s)
    bv0, bv1, cv0, cv1 = _hermite_basis(t)
    # (f, f_w, f_v, f_wv) stacked: one gather per corner
    nodes = jnp.asarray(np.stack([tab.logT, tab.dw, tab.dv, tab.dwv], axis=-1), w.dtype)
    out = jnp.zeros_like(w)
    for di, (pw, qw) in enumerate(((bw0, cw0), (bw1, cw1))):
        for dj, (pv, qv) in enumerate(((bv0, cv0), (bv1, cv1))):
            c = nodes[i + di, j + dj]
            out = out + pw * pv * c[..., 0] + hw * qw * pv * c[..., 1] + hv * pw * qv * c[..., 2] \
                + hw * hv * qw * qv * c[..., 3]
    return out


def _w_from_albedo(albedo: Array, tab: _Table | None = None) -> Array:
    """Table coordinate ``w = (1 - alpha)^(1/4)`` of surface albedo ``A``: linear interpolation of the inverse of a
    1025-node table of ``A(w) = 1 - H(1) w^2`` (H at alpha = 1 - w^4, from ``_fit_presets.chandrasekhar_h``; within
    1e-6 in A) -- differentiable where the host's bisection (``albedo_from_surface_albedo``) is not."""
    tab = tab if tab is not None else _table()
    # the table decreases from A = 1 (w = 0) to A = 0 (w = 1): interpolate on the reversed (increasing) copy
    xp = jnp.asarray(tab.map_A[::-1], albedo.dtype)
    fp = jnp.asarray(tab.map_w[::-1], albedo.dtype)
    return jnp.interp(jnp.clip(albedo, 0.0, 1.0), xp, fp)


def single_scattering_albedo(albedo: ArrayLike) -> Array:
    """``alpha`` with ``1 - H(1) sqrt(1 - alpha) = A`` (index-matched isotropic half-space), elementwise, jit- and
    grad-able; A is clipped to [0, 1]."""
    a = _as_float(albedo)
    w = _w_from_albedo(a)
    return 1.0 - w ** 4


def table_stderr(alpha: float, tau: float, *, _tab: _Table | None = None) -> float:
    """Host-side error bar of the table near (alpha, tau): the largest standard error of the enclosing cell's four
    nodes (the interpolant is a local, weight-one blend of them; nearest cell outside the table)."""
    tab = _tab if _tab is not None else _table()
    u = math.sqrt(min(max(1.0 - alpha, 0.0), 1.0))
    v = (math.log(min(max(tau, TAU_MIN), tau_max(u))) - math.log(TAU_MIN)) / (math.log(tau_max(u)) - math.log(TAU_MIN))
    i = min(int(math.sqrt(u) * (tab.w.size - 1)), tab.w.size - 2)
    j = min(int(v * (tab.v.size - 1)), tab.v.size - 2)
    return float(tab.stderr[i:i + 2, j:j + 2].max())


def _as_float(x: ArrayLike, *others: ArrayLike) -> Array:
    dtype = jnp.result_type(jnp.asarray(x).dtype, *(jnp.asarray(o).dtype for o in others), jnp.float32)
    return jnp.asarray(x).astype(dtype)


def _transmittance_w(w: Array, tau: Array, tab: _Table | None = None) -> Array:
    """T at table coordinate w and slab thickness ``tau`` (mean free paths, >= 0, may be inf)."""
    tab = tab if tab is not None else _table()
    u = w * w
    tmax = tau_max(u, jnp)
    finite = jnp.isfinite(tau)
    tau_s = jnp.where(finite, tau, 0.0)  # inf never reaches a formula (its gradient would be NaN)
    x0 = jnp.log(TAU_MIN)
    span = jnp.log(tmax) - x0
    v = (jnp.log(jnp.clip(tau_s, TAU_MIN, tmax)) - x0) / span
    inside = _bicubic(tab, w, v)
    # beyond the row's end: log T falls on at the end's rate -d log T / d tau = -(d log T / dv) / (tau_max span)
    slope_v = _hermite_w(tab, tab.dv[:, -1], tab.dwv[:, -1], w)
    rate = jnp.maximum(-slope_v / (tmax * span), 0.0)  # never rising: T stays monotone in tau
    beyond = inside - rate * jnp.maximum(tau_s - tmax, 0.0)
    # below tau_min: log T linear in tau down to log T(0) = 0 (T = 1 - c tau + O(tau^2 log tau) near 0)
    log_t = jnp.where(tau_s < TAU_MIN, inside * tau_s / TAU_MIN, beyond)
    return jnp.where(finite, jnp.exp(log_t), 0.0)


def slab_transmittance_mfp(alpha: ArrayLike, tau: ArrayLike, *, _tab: _Table | None = None) -> Array:
    """Total transmittance of an index-matched isotropic slab, single-scattering albedo ``alpha`` in [0, 1], thickness
    ``tau`` (mean free paths, >= 0), normal incidence: the Monte Carlo table, interpolated. Elementwise."""
    a, t = jnp.broadcast_arrays(_as_float(alpha, tau), _as_float(tau, alpha))
    # w = (1 - alpha)^(1/4); at alpha = 1, where the fourth root's gradient is infinite, the where makes it zero
    one_minus = jnp.clip(1.0 - a, 0.0, 1.0)
    pos = one_minus > 0
    w = jnp.where(pos, jnp.sqrt(jnp.sqrt(jnp.where(pos, one_minus, 1.0))), 0.0)
    return _transmittance_w(w, jnp.maximum(t, 0.0), _tab)


def slab_transmittance(thickness_mm: ArrayLike, albedo: ArrayLike, d_mm: ArrayLike) -> Array:
    """Back-light through a slab of thickness t of the medium behind a Burley material (surface albedo A, d in mm).

    The total (ballistic + scattered) transmittance ``T(alpha(A), t / (d s(A)))`` of the index-matched isotropic medium
    whose half-space reflects A (module docstring), from a Monte Carlo table: within the table's stated error of
    Monte Carlo for t/d in [0, 28] (docs/engines.md; beyond, exponential extrapolation). Unlike ``thin_transmittance``
    (the profile's CCDF) it follows from transport through the slab. Elementwise with broadcasting; t = 0 gives 1,
    d = 0 gives 0 for t > 0.
    """
    t, A, d = jnp.broadcast_arrays(*(_as_float(x, thickness_mm, albedo, d_mm) for x in (thickness_mm, albedo, d_mm)))
    t = jnp.maximum(t, 0.0)
    mfp = d * scaling_searchlight(A)  # l = d s(A): the searchlight fit, as the presets derive the medium
    ok = mfp > 0
    tau = jnp.where(ok, t / jnp.where(ok, mfp, 1.0), jnp.where(t > 0, jnp.inf, 0.0))
    return _transmittance_w(_w_from_albedo(A), tau)
