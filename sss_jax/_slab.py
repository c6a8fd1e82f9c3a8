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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._checks import check_host_range
from ._materials import BurleyMaterial
from ._profiles import scaling_searchlight

__all__ = ["TABLE_PATH", "single_scattering_albedo", "slab_transmittance", "slab_transmittance_mfp", "table_stderr",
           "tau_max", "MEDIUM_TAU_NODES", "MediumMaterial", "medium_slab_table", "unscattered_transmittance_at_zero",
           "slab_diffuse_transmittance", "unscattered_transmittance", "diffuse_exit", "slab_exit", "slab_optical",
           "slab_exit_table", "slab_exit_lookup"]

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
    _check_burley_slab(thickness_mm, albedo, d_mm)
    t, A, d = jnp.broadcast_arrays(*(_as_float(x, thickness_mm, albedo, d_mm) for x in (thickness_mm, albedo, d_mm)))
    return _transmittance_w(_w_from_albedo(A), _tau_of_burley(t, A, d))


def slab_optical(thickness_mm: ArrayLike, albedo: ArrayLike, d_mm: ArrayLike) -> tuple[Array, Array]:
    """``(tau, alpha)`` of the index-matched medium rebuilt from a Burley material (A, d), as
    ``slab_transmittance`` rebuilds it: the slab's thickness in mean free paths and the single-scattering albedo."""
    _check_burley_slab(thickness_mm, albedo, d_mm)
    t, A, d = jnp.broadcast_arrays(*(_as_float(x, thickness_mm, albedo, d_mm) for x in (thickness_mm, albedo, d_mm)))
    return _tau_of_burley(t, A, d), 1.0 - _w_from_albedo(A) ** 4


def _check_burley_slab(thickness_mm, albedo, d_mm) -> None:
    """Host values checked (traced ones are the passes', whose materials are checked): NaN thickness read as 0 (T =
    1) and an albedo past [0, 1] clipped without a word."""
    check_host_range(thickness_mm, "thickness_mm", finite=False)
    check_host_range(albedo, "albedo", high=1.0)
    check_host_range(d_mm, "d_mm")


def _tau_of_burley(t: Array, A: Array, d: Array) -> Array:
    t = jnp.maximum(t, 0.0)
    mfp = d * scaling_searchlight(A)  # l = d s(A): the searchlight fit, as the presets derive the medium
    ok = mfp > 0
    return jnp.where(ok, t / jnp.where(ok, mfp, 1.0), jnp.where(t > 0, jnp.inf, 0.0))


def slab_diffuse_transmittance(thickness_mm: ArrayLike, albedo: ArrayLike, d_mm: ArrayLike) -> Array:
    """The diffusely transmitted part of ``slab_transmittance``: the total less the unscattered beam ``exp(-tau)``.

    The unscattered (collimated) part keeps the light's direction: it reaches a camera only when the camera looks
    into the light, so a back-lit surface seen from any other direction shows only this part. Index-matched medium
    rebuilt from (A, d) as ``slab_transmittance``; elementwise; t = 0 gives 0 (nothing has scattered yet), d = 0
    gives 0; never negative (the table's interpolation error near tau = 0 is clamped)."""
    _check_burley_slab(thickness_mm, albedo, d_mm)
    t, A, d = jnp.broadcast_arrays(*(_as_float(x, thickness_mm, albedo, d_mm) for x in (thickness_mm, albedo, d_mm)))
    tau = _tau_of_burley(t, A, d)
    total = _transmittance_w(_w_from_albedo(A), tau)
    finite = jnp.isfinite(tau)
    ballistic = jnp.where(finite, jnp.exp(-jnp.where(finite, tau, 0.0)), 0.0)
    return jnp.maximum(total - ballistic, 0.0)


def unscattered_transmittance(tau: ArrayLike, eta: ArrayLike) -> Array:
    """The collimated beam through a slab of ``tau`` mean free paths between two faces of relative index ``eta``, at
    normal incidence: ``(1 - R)^2 e / (1 - R^2 e^2)``, ``e = exp(-tau)``, ``R = ((eta - 1) / (eta + 1))^2`` (the
    beam crosses the first face, is attenuated and bounces between the faces; ``unscattered_transmittance_at_zero``
    at tau = 0). Elementwise; inf gives 0."""
    tau_a, eta_a = jnp.broadcast_arrays(_as_float(tau, eta), _as_float(eta, tau))
    finite = jnp.isfinite(tau_a)
    e = jnp.where(finite, jnp.exp(-jnp.where(finite, jnp.maximum(tau_a, 0.0), 0.0)), 0.0)
    r = ((eta_a - 1.0) / (eta_a + 1.0)) ** 2
    return (1.0 - r) ** 2 * e / (1.0 - r * r * e * e)


def _safe_sqrt(x: Array) -> Array:
    """sqrt with a finite (zero) gradient at 0: the double where."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _fresnel(cos_i: Array, eta: Array) -> Array:
    """Unpolarised Fresnel reflectance for light inside a medium of relative index ``eta`` (>= 1) meeting its face at
    ``cos_i``; 1 beyond the critical angle."""
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t > 1.0
    cos_t = _safe_sqrt(jnp.where(tir, 0.0, 1.0 - sin2_t))
    den_s = eta * cos_i + cos_t
    den_p = eta * cos_t + cos_i
    ok = (den_s > 0) & (den_p > 0)
    rs = (eta * cos_i - cos_t) / jnp.where(ok, den_s, 1.0)
    rp = (eta * cos_t - cos_i) / jnp.where(ok, den_p, 1.0)
    # no face at all where eta = 1 (grazing included); grazing at a real face reflects everything
    return jnp.where(eta == 1.0, 0.0, jnp.where(tir | ~ok, 1.0, 0.5 * (rs * rs + rp * rp)))


# Gauss-Legendre nodes on [0, 1] for the exit distribution's normalisation (smooth integrand: 48 nodes reach 1e-7)
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(48)
_GL_X, _GL_W = 0.5 * (_GL_NODES + 1.0), 0.5 * _GL_WEIGHTS


def _nodes(like: Array) -> tuple[Array, Array]:
    """The quadrature nodes and weights on [0, 1], shaped to broadcast against ``like[..., None]`` (same rank)."""
    shape = (1,) * like.ndim + (_GL_X.size,)
    return jnp.asarray(_GL_X, like.dtype).reshape(shape), jnp.asarray(_GL_W, like.dtype).reshape(shape)


def _exit_unnormalised(mu_out: Array, eta: Array) -> Array:
    # outside angle -> inside angle (Snell: sin_in = sin_out / eta); inside radiance of the diffusion approximation
    # at a face with internal diffuse reflectance F_dr: L(mu) ~ 1 + 3 mu / (2 A_b), A_b = (1 + F_dr) / (1 - F_dr)
    mu_in = _safe_sqrt(jnp.clip(1.0 - (1.0 - mu_out * mu_out) / (eta * eta), 0.0, 1.0))
    fdr = _internal_diffuse_reflectance(eta)
    a_b = (1.0 + fdr) / (1.0 - fdr)
    return (1.0 - _fresnel(mu_in, eta)) * (1.0 + 1.5 * mu_in / a_b)


def _extrapolation_mfp(eta: Array) -> Array:
    """The diffusion solution's extrapolation distance at a face of relative index ``eta``, in mean free paths:
    ``2 A_b D``, ``D = 1/3`` mean free path, ``A_b = (1 + F_dr) / (1 - F_dr)``."""
    fdr = _internal_diffuse_reflectance(eta)
    return 2.0 * (1.0 + fdr) / (1.0 - fdr) / 3.0


def _internal_diffuse_reflectance(eta: Array) -> Array:
    """``F_dr = int_0^1 F(mu) 2 mu dmu`` for diffuse light inside the face (quadrature on both sides of the critical
    cosine, where F has a kink)."""
    mu_c = _safe_sqrt(jnp.clip(1.0 - 1.0 / (eta * eta), 0.0, 1.0))[..., None]
    x, w = _nodes(eta)
    above = mu_c + (1.0 - mu_c) * x
    part = jnp.sum(w * _fresnel(above, eta[..., None]) * 2 * above, -1) * (1.0 - mu_c[..., 0])
    return mu_c[..., 0] ** 2 + part  # below the critical cosine F = 1: int_0^mu_c 2 mu dmu


def diffuse_exit(mu_view: ArrayLike, eta: ArrayLike) -> Array:
    """The angular distribution of diffusely transmitted light leaving a face of relative index ``eta`` towards a
    viewer at ``mu_view = cos(angle to the face's normal)``, relative to a Lambertian exit of the same flux
    (``int_0^1 P(mu) 2 mu dmu = 1``; P = 1 is Lambertian).

    Inside the face the diffusion approximation's radiance ``1 + 3 mu / (2 A_b)`` (Farrell, Patterson & Wilson 1992;
    ``A_b = (1 + F_dr) / (1 - F_dr)`` from the face's internal diffuse reflectance F_dr), refracted out through the
    Fresnel transmittance ``1 - F`` (Snell's law maps the inside cosine to ``mu_view``), normalised by Gauss-Legendre
    quadrature. Index-matched (eta = 1): ``(1 + 1.5 mu) / 2``, 1.25 at normal view, 0.5 at grazing. Elementwise,
    jit- and grad-able; mu is clipped to [0, 1]."""
    mu, e = jnp.broadcast_arrays(_as_float(mu_view, eta), _as_float(eta, mu_view))
    mu = jnp.clip(mu, 0.0, 1.0)
    x, w = _nodes(e)
    norm = jnp.sum(w * _exit_unnormalised(x, e[..., None]) * 2 * x, -1)
    return _exit_unnormalised(mu, e) / norm


# The exit distribution of a slab's diffusely transmitted light depends on the slab: a thin slab is limb-brightened
# (its once-scattered light grows with the path length through it, 1 / mu: P -> 1 / (2 mu) as tau -> 0), a thick
# absorbing one is peaked towards the normal (the source decays into the slab: the asymptotic mode 1 / (1 - kappa mu)).
# The radiance leaving the face is the exact emergent integral of the scattering source along the line of sight,
# ``L(mu) = int_0^tau S(z) exp(-(tau - z) / mu) dz / mu``, with S from the collimated beam (exact) and the diffusion
# fluence of the scattered light (one iteration of the source function: within 2-4% of a Monte Carlo walk's radiance
# for tau 0.8-6, scripts/slab_exit.py).
_EXIT_TAU_CAP = 12.0  # beyond 12 mean free paths the source near the exit face no longer depends on the thickness
_U_NODES, _U_WEIGHTS = np.polynomial.legendre.leggauss(20)
_U_X, _U_W = 0.5 * (_U_NODES + 1.0), 0.5 * _U_WEIGHTS
_MU_NODES, _MU_WEIGHTS = np.polynomial.legendre.leggauss(16)
_MU_X, _MU_W = 0.5 * (_MU_NODES + 1.0), 0.5 * _MU_WEIGHTS


def _one_minus_exp_over(x: Array) -> Array:
    """``(1 - e^-x) / x`` for x >= 0, 1 at 0 (the double where: finite gradients)."""
    small = x < 1e-4
    xs = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 - 0.5 * x, -jnp.expm1(-xs) / xs)


def _slab_source(z: Array, tau: Array, alpha: Array, beta: Array, z_b: Array) -> Array:
    """The scattering source (times 4 pi / alpha, per unit beam intensity) at optical depth ``z`` below the lit face of a
    slab ``tau`` thick, isotropic scattering of albedo ``alpha``, a collimated beam at ``1 / beta`` to the normal:
    ``phi_d(z) + e^{-beta z}``, phi_d the diffusion fluence of the scattered light, ``-phi'' / 3 + (1 - alpha)
    phi = alpha e^{-beta z}`` with extrapolated boundaries ``phi = z_b |phi'|`` on both faces. Written in bounded
    terms (no cosh of a thick slab, no 1 / (kappa - beta)): ``phi = K G + A e^{-kappa z} + B e^{-kappa tau}
    sinh(kappa z) / kappa``, ``G = (e^{-beta z} - e^{-kappa z}) / (kappa - beta)``, ``K = 3 alpha / (kappa + beta)``;
    the source divided by alpha (the exit's shape does not see a constant factor), so that alpha -> 0, where only the
    single scattering is left, stays finite."""
    kappa = _safe_sqrt(3.0 * (1.0 - alpha))
    k_lo, gap = jnp.minimum(kappa, beta), jnp.abs(kappa - beta)
    g = lambda x: x * jnp.exp(-k_lo * x) * _one_minus_exp_over(gap * x)  # G, G(0) = 0, G'(0) = 1
    u2 = lambda x: jnp.exp(-kappa * (tau - x)) * x * _one_minus_exp_over(2.0 * kappa * x)
    big_k = 3.0 / (kappa + beta)  # K / alpha: phi_d = alpha * phi below
    e_kt = jnp.exp(-kappa * tau)
    g_t = g(tau)
    a11, a12, r1 = 1.0 + z_b * kappa, -z_b * e_kt, z_b * big_k
    a21 = e_kt * (1.0 - z_b * kappa)
    a22 = u2(tau) + z_b * 0.5 * (1.0 + e_kt * e_kt)
    r2 = -big_k * (g_t * (1.0 - z_b * kappa) + z_b * jnp.exp(-beta * tau))
    det = a11 * a22 - a12 * a21  # > 0 for every alpha, tau
    a = (r1 * a22 - a12 * r2) / det
    b = (a11 * r2 - a21 * r1) / det
    phi = big_k * g(z) + a * jnp.exp(-kappa * z) + b * u2(z)
    return alpha * jnp.maximum(phi, 0.0) + jnp.exp(-beta * z)


def _emergent(mu_in: Array, tau: Array, alpha: Array, beta: Array, z_b: Array) -> Array:
    """Radiance (unnormalised) reaching the exit face from inside at cosine ``mu_in``: the source's integral along the
    line of sight, ``int_0^tau S(tau - s) e^{-s/mu} ds / mu``. The source grows into the slab about as ``e^{kappa s}``
    (kappa the diffusion decay rate), so the integrand falls as ``e^{-lambda s}``, ``lambda = 1/mu - kappa``: the
    depth is drawn as ``s = -ln(1 - u (1 - e^{-lambda tau})) / lambda`` and Gauss-Legendre in u integrates what is
    left, ``S e^{-kappa s}``, smooth and bounded; where lambda tau < 1 (the integrand nearly flat or growing: a low
    albedo seen near the normal) the depth is uniform in u."""
    m = jnp.maximum(mu_in, 1e-3)[..., None]
    t, al, be, zb = (v[..., None] for v in (tau, alpha, beta, z_b))
    shape = (1,) * (m.ndim - 1) + (-1,)
    u, weights = jnp.asarray(_U_X, m.dtype).reshape(shape), jnp.asarray(_U_W, m.dtype).reshape(shape)
    kappa = _safe_sqrt(3.0 * (1.0 - al))
    lam = 1.0 / m - kappa
    mapped = lam * t > 1.0
    lam_s = jnp.where(mapped, lam, 1.0)
    reach = -jnp.expm1(-lam_s * t)  # 1 - e^{-lambda tau}
    s = jnp.where(mapped, -jnp.log1p(-u * reach) / lam_s, u * t)
    src = _slab_source(jnp.clip(t - s, 0.0, t), t, al, be, zb)
    integrand = jnp.where(mapped, src * jnp.exp(-kappa * s) * reach / (lam_s * m), src * jnp.exp(-s / m) * t / m)
    return jnp.sum(weights * integrand, -1)


@jax.jit
def slab_exit(mu_view: ArrayLike, tau: ArrayLike, alpha: ArrayLike, mu_light: ArrayLike, eta: ArrayLike) -> Array:
    """The angular distribution of the light a slab transmits diffusely, leaving its front face towards a viewer at
    ``mu_view`` (cosine to the face's normal), relative to a Lambertian exit of the same flux (``int_0^1 P(mu) 2 mu
    dmu = 1``): the slab ``tau`` mean free paths thick, isotropic scattering of single-scattering albedo ``alpha``,
    lit on its back face by a collimated beam at cosine ``mu_light`` to that face's normal, relative index ``eta`` on
    both faces (refraction and Fresnel transmittance at the exit, Snell's law for the beam).

    Inside, the emergent radiance of the scattering source (the beam's exact single scattering plus the diffusion
    fluence's, see ``_slab_source``) along the line of sight; a thin slab comes out limb-brightened (P(1) -> 1/2 as
    tau -> 0), a thick absorbing one peaked towards the normal (P(1) 1.5 for skin1's blue at 4 mm), a thick
    non-absorbing one near the diffusion approximation's ``diffuse_exit``. Elementwise with broadcasting, jit- and
    grad-able; tau is capped at 12 (the exit face's source no longer depends on it) and floored at 1e-4."""
    dtype = _as_float(mu_view, tau, alpha, mu_light, eta).dtype
    # the slab's arguments broadcast among themselves: the flux (the normalisation) is computed once per slab, not
    # once per view cosine (slab_exit_table asks many views of each slab)
    t, al, ml, e = jnp.broadcast_arrays(*(jnp.asarray(x).astype(dtype) for x in (tau, alpha, mu_light, eta)))
    mu = jnp.clip(jnp.asarray(mu_view).astype(dtype), 0.0, 1.0)
    t = jnp.clip(jnp.where(jnp.isfinite(t), t, _EXIT_TAU_CAP), 1e-4, _EXIT_TAU_CAP)
    al = jnp.clip(al, 0.0, 1.0)
    to_inside = lambda c: _safe_sqrt(jnp.clip(1.0 - (1.0 - c * c) / (e * e), 0.0, 1.0))
    beta = 1.0 / jnp.maximum(to_inside(jnp.clip(ml, 0.0, 1.0)), 0.05)
    z_b = _extrapolation_mfp(e)

    def out(mu_out, *args):  # the radiance outside, unnormalised: refracted, through the Fresnel transmittance
        m_in = _safe_sqrt(jnp.clip(1.0 - (1.0 - mu_out * mu_out) / (args[-1] ** 2), 0.0, 1.0))
        return (1.0 - _fresnel(m_in, args[-1])) * _emergent(m_in, *args[:-1])

    x = jnp.asarray(_MU_X, dtype).reshape((1,) * t.ndim + (-1,))
    wq = jnp.asarray(_MU_W, dtype).reshape(x.shape)
    grid = [v[..., None] for v in (t, al, beta, z_b, e)]
    norm = jnp.sum(wq * out(x, *grid) * 2.0 * x, -1)
    if mu.ndim < t.ndim:  # rank promotion is explicit in this project
        mu = mu.reshape((1,) * (t.ndim - mu.ndim) + mu.shape)
    elif mu.ndim > t.ndim:
        t, al, beta, z_b, e, norm = (v.reshape((1,) * (mu.ndim - t.ndim) + v.shape)
                                     for v in (t, al, beta, z_b, e, norm))
    return out(mu, t, al, beta, z_b, e) / norm


# slab_exit per pixel costs ~340 source evaluations per channel (the view and the flux quadrature): a frame takes it
# from a table per material row and channel instead, over log tau, the light's cosine and the view's cosine
_TABLE_LOG_TAU = np.linspace(np.log(1e-3), np.log(_EXIT_TAU_CAP), 31)
_TABLE_MU_LIGHT = np.linspace(0.05, 1.0, 9)
_TABLE_MU_VIEW = np.linspace(0.0, 1.0, 41)


def slab_exit_table(alpha: Float[Array, "M 3"], eta: Float[Array, " M"]) -> Float[Array, "M 3 T L V"]:
    """``slab_exit`` on a grid per material row and channel: 31 thicknesses log-spaced over [1e-3, 12] mean free
    paths, 9 light cosines over [0.05, 1], 41 view cosines over [0, 1] (``slab_exit_lookup`` interpolates)."""
    dtype = jnp.result_type(alpha.dtype, eta.dtype)
    tau = jnp.exp(jnp.asarray(_TABLE_LOG_TAU, dtype)).reshape(1, 1, -1, 1, 1)
    ml = jnp.asarray(_TABLE_MU_LIGHT, dtype).reshape(1, 1, 1, -1, 1)
    mv = jnp.asarray(_TABLE_MU_VIEW, dtype).reshape(1, 1, 1, 1, -1)
    return slab_exit(mv, tau, alpha[:, :, None, None, None], ml, eta[:, None, None, None, None])


def _grid_cell(x: Array, nodes: np.ndarray) -> tuple[Array, Array]:
    """Cell index and local coordinate of ``x`` on uniform ``nodes`` (clamped to the grid)."""
    n = nodes.size
    pos = (jnp.clip(x, nodes[0], nodes[-1]) - nodes[0]) / (nodes[1] - nodes[0])
    i = jnp.clip(jnp.floor(pos), 0, n - 2).astype(jnp.int32)
    return i, pos - i.astype(x.dtype)


def slab_exit_lookup(table: Float[Array, "M 3 T L V"], rows: Array, tau: Array, mu_light: Array,
                     mu_view: Array) -> Array:
    """``slab_exit`` from ``slab_exit_table``, trilinear in (log tau, light cosine, view cosine): ``rows`` ``(...)``,
    ``tau`` ``(..., 3)``, ``mu_light`` and ``mu_view`` ``(...)``; returns ``(..., 3)``. Within 1.5% of ``slab_exit``
    over the grid's range (a test checks)."""
    dtype = tau.dtype
    finite = jnp.isfinite(tau)
    log_tau = jnp.log(jnp.clip(jnp.where(finite, tau, _EXIT_TAU_CAP), 1e-3, _EXIT_TAU_CAP))
    it, ft = _grid_cell(log_tau, _TABLE_LOG_TAU)  # (..., 3)
    il, fl = _grid_cell(jnp.clip(mu_light, 0.0, 1.0).astype(dtype), _TABLE_MU_LIGHT)  # (...)
    iv, fv = _grid_cell(jnp.clip(mu_view, 0.0, 1.0).astype(dtype), _TABLE_MU_VIEW)
    r = jnp.clip(rows, 0, table.shape[0] - 1)[..., None]
    c = jnp.arange(3).reshape((1,) * rows.ndim + (3,))
    il, fl, iv, fv = (v[..., None] for v in (il, fl, iv, fv))
    tab = table.astype(dtype)
    out = jnp.zeros(tau.shape, dtype)
    for dt, wt in ((0, 1 - ft), (1, ft)):
        for dl, wl in ((0, 1 - fl), (1, fl)):
            for dv, wv in ((0, 1 - fv), (1, fv)):
                out = out + wt * wl * wv * tab[r, c, it + dt, il + dl, iv + dv]
    return out


# ------------------------------------------------------------------------------------------------------------------
# the measured medium itself: its coefficients, its boundaries
# ------------------------------------------------------------------------------------------------------------------
# A preset that carries its medium (reduced scattering and absorption, eta) transmits through that medium, not
# through the index-matched one rebuilt from (A, d) above: ``medium_slab_table`` runs the Monte Carlo walk through
# slabs of it (Fresnel on both faces), ``MediumMaterial`` interpolates that table per pixel.

# slab thicknesses of the table, in mean free paths of each channel (t = 0 is added exactly)
MEDIUM_TAU_NODES = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.0, 16.0)


def unscattered_transmittance_at_zero(eta: float) -> float:
    """A slab of zero thickness between two faces of relative index ``eta``: normal light crosses the first face,
    bounces between both, ``sum_k (1 - R)^2 R^(2k) = (1 - R) / (1 + R)`` with ``R = ((eta - 1)/(eta + 1))^2``."""
    r = ((eta - 1.0) / (eta + 1.0)) ** 2
    return (1.0 - r) / (1.0 + r)


def medium_slab_table(sigma_s_prime_per_mm, sigma_a_per_mm, eta: float, *, photons: int = 10_000, seed: int = 0,
                      tau_nodes=MEDIUM_TAU_NODES) -> dict[str, Any]:
    """Total transmittance (unscattered and scattered) of slabs of a medium, per channel, by the Monte Carlo walk.

    The medium: reduced scattering ``sigma_s'`` and absorption ``sigma_a`` (1/mm, (3,) each), isotropic phase
    function (similarity theory), relative index ``eta`` on both faces. Light: a normal pencil beam (by translation
    invariance the same as a uniform normal back light) entering one face; T: the fraction of it that leaves the
    other face. Thicknesses ``tau_nodes`` mean free paths of each channel, and 0 (``unscattered_transmittance_at_zero``).
    Nodes the walk cannot resolve (T < 50 / photons) are marked in ``resolved`` and extrapolated by
    ``MediumMaterial``. Returns JSON-ready lists, ``(3, N)`` each, thicknesses in mm, and ``albedo``, the
    single-scattering albedo per channel (the exit distribution's, ``slab_exit``)."""
    from ._montecarlo import simulate

    s = np.asarray(sigma_s_prime_per_mm, np.float64)
    a = np.asarray(sigma_a_per_mm, np.float64)
    if s.shape != (3,) or a.shape != (3,) or not np.all((s >= 0) & (a >= 0) & (s + a > 0) & np.isfinite(s + a)):
        raise ValueError(f"sigma_s_prime_per_mm and sigma_a_per_mm must be 3 finite values >= 0 with a positive sum, "
                         f"got {s.tolist()} and {a.tolist()}")
    if not (eta >= 1.0 and math.isfinite(eta)):
        raise ValueError(f"eta must be a finite number >= 1, got {eta}")
    t0 = unscattered_transmittance_at_zero(eta)
    out: dict[str, Any] = {"eta": float(eta), "photons": int(photons), "seed": int(seed),
                           "albedo": [float(v) for v in s / (s + a)],
                           "tau_nodes": [0.0, *map(float, tau_nodes)], "thickness_mm": [], "T": [], "T_stderr": [],
                           "resolved": []}
    for c in range(3):
        mfp = 1.0 / (s[c] + a[c])
        albedo = float(s[c] * mfp)
        runs = [simulate(albedo, photons=photons, eta=eta, slab_mfp=float(tau), seed=seed + 1000 * (c + 1) + i,
                         bins=8, r_max_mfp=1.0) for i, tau in enumerate(tau_nodes)]
        T = [t0] + [r.total_transmittance for r in runs]
        out["thickness_mm"].append([0.0] + [float(tau * mfp) for tau in tau_nodes])
        out["T"].append([float(v) for v in T])
        out["T_stderr"].append([0.0] + [r.total_transmittance_stderr for r in runs])
        out["resolved"].append([True] + [bool(r.total_transmittance > 50.0 / photons) for r in runs])
    return out


def _table_log_T(table: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """``(thickness_mm, log T)``, ``(N, 3)`` each, from a ``medium_slab_table`` result: unresolved nodes continue the
    last resolved segment's log-linear decay (T of a thick slab falls as C exp(-k t))."""
    t = np.asarray(table["thickness_mm"], np.float64).T
    T = np.asarray(table["T"], np.float64).T
    ok = np.asarray(table["resolved"], bool).T & (T > 0)
    logT = np.log(np.where(ok, T, 1.0))
    for c in range(t.shape[1]):
        good = np.flatnonzero(ok[:, c])
        if good.size < 2 or not np.all(good == np.arange(good.size)):
            unresolved = [float(x) for x in t[~ok[:, c], c]][:6]
            raise ValueError(f"medium table: channel {'RGB'[c]} needs resolved transmittance from t = 0 on (finite, "
                             f"> 0, resolved) at two nodes at least; unresolved at t = {unresolved} mm")
        last, prev = good[-1], good[-2]
        rate = min((logT[last, c] - logT[prev, c]) / (t[last, c] - t[prev, c]), 0.0)
        logT[last + 1:, c] = logT[last, c] + rate * (t[last + 1:, c] - t[last, c])
    return t, logT


def _log_sinh_ratio(a: Array, b: Array, k: Array) -> Array:
    """``log(sinh(k a) / sinh(k b))`` for ``0 < a <= b``, ``k >= 0``: ``log(a / b)`` as k -> 0 (a medium that absorbs
    nothing), ``-k (b - a)`` as k a grows, without overflow or 0 / 0.

    Each argument takes its own form of log sinh (the series below 1e-3, the exponential one above): k a can be
    small while k b is not (a long way past the table in a medium that absorbs almost nothing)."""
    small = k * b < 1e-3  # both arguments small: the ratio's own series, which stays exact at k = 0
    series = jnp.log(a / b) + k * k * (a * a - b * b) / 6.0

    def log_sinh(v: Array) -> Array:  # v > 0 where it is selected; the other branch's input kept finite (grad)
        low = v < 1e-3
        v_low, v_high = jnp.maximum(jnp.where(low, v, 1.0), 1e-30), jnp.maximum(v, 1e-3)
        return jnp.where(low, jnp.log(v_low) + v_low * v_low / 6.0,
                         v_high + jnp.log(-jnp.expm1(-2.0 * v_high)) - jnp.log(2.0))

    return jnp.where(small, series, log_sinh(k * a) - log_sinh(k * b))


class MediumMaterial(eqx.Module):
    """A Burley material with the slab transmittance of its own medium (per material row): what
    ``translucency(..., model="slab")`` transmits where a preset carries its medium.

    ``thickness_mm``, ``log_T``: ``(M, N, 3)`` table nodes (increasing thicknesses per row and channel, the first 0);
    between nodes log T is linear in t (exponential decay), beyond the last (16 mean free paths) it follows the
    diffusion solution's shape ``1 / sinh(k (t + 2 z_e))`` from there (``transmittance``).
    ``mfp_mm`` ``(M, 3)``: the medium's mean free path ``1 / (sigma_s' + sigma_a)``, ``eta`` ``(M,)``: its relative
    index on both faces, ``albedo_ss`` ``(M, 3)``: its single-scattering albedo ``sigma_s' / (sigma_s' + sigma_a)``
    -- what the unscattered beam (``unscattered_transmittance``) and the exit distribution (``slab_exit``) need.
    """

    burley: BurleyMaterial
    thickness_mm: Float[Array, "M N 3"]
    log_T: Float[Array, "M N 3"]
    mfp_mm: Float[Array, "M 3"]
    eta: Float[Array, " M"]
    albedo_ss: Float[Array, "M 3"]

    def __check_init__(self):
        m = self.burley.d_mm.shape[0]
        if self.thickness_mm.ndim != 3 or self.thickness_mm.shape != self.log_T.shape or \
                self.thickness_mm.shape[0] not in (1, m) or self.thickness_mm.shape[2] != 3:
            raise ValueError(f"MediumMaterial needs thickness_mm and log_T of shape (M, N, 3) with M = {m} materials; "
                             f"got {self.thickness_mm.shape} and {self.log_T.shape}")
        rows = self.thickness_mm.shape[0]
        if self.mfp_mm.shape != (rows, 3) or self.eta.shape != (rows,) or self.albedo_ss.shape != (rows, 3):
            raise ValueError(f"MediumMaterial needs mfp_mm and albedo_ss of shape ({rows}, 3) and eta of shape "
                             f"({rows},); got {self.mfp_mm.shape}, {self.albedo_ss.shape} and {self.eta.shape}")

    @classmethod
    def from_tables(cls, burley: BurleyMaterial, tables: list[dict[str, Any]]) -> "MediumMaterial":
        """One ``medium_slab_table`` result per material row of ``burley`` (host side). A table without
        ``albedo`` (written before it was kept) takes the single-scattering albedo of the index-matched medium whose
        half-space reflects the row's A (``single_scattering_albedo``)."""
        pairs = [_table_log_T(t) for t in tables]
        if len({p[0].shape for p in pairs}) != 1:
            raise ValueError("medium tables must have the same number of thickness nodes")
        dtype = burley.d_mm.dtype
        mfp, eta, alb = [], [], []
        surface = np.broadcast_to(np.asarray(burley.albedo, np.float64).reshape(-1, 3), (len(tables), 3))
        for i, t in enumerate(tables):
            if "eta" not in t or "tau_nodes" not in t:
                raise ValueError("medium table needs eta and tau_nodes (the medium's index and the thicknesses in "
                                 "mean free paths), as medium_slab_table writes them")
            tau = np.asarray(t["tau_nodes"], np.float64)
            thick = np.asarray(t["thickness_mm"], np.float64)  # (3, N): thickness = tau * mfp per channel
            k = int(np.argmax(tau > 0))
            mfp.append(thick[:, k] / tau[k])
            eta.append(float(t["eta"]))
            alb.append(np.asarray(t["albedo"], np.float64) if "albedo" in t else
                       np.asarray(single_scattering_albedo(surface[i]), np.float64))
        return cls(burley, jnp.asarray(np.stack([p[0] for p in pairs]), dtype),
                   jnp.asarray(np.stack([p[1] for p in pairs]), dtype), jnp.asarray(np.stack(mfp), dtype),
                   jnp.asarray(eta, dtype), jnp.asarray(np.stack(alb), dtype))

    def transmittance(self, thickness_mm: ArrayLike, rows: ArrayLike | None = None) -> Array:
        """T per channel, ``(..., 3)``, at thicknesses ``(...)`` in mm (>= 0) of material rows ``(...)`` (default 0):
        the fraction of a normally incident back light that leaves the front face."""
        t = jnp.asarray(thickness_mm)
        t = jnp.maximum(t.astype(jnp.result_type(t.dtype, self.log_T.dtype)), 0.0)
        rows = jnp.zeros(t.shape, jnp.int32) if rows is None else jnp.asarray(rows)
        rows = jnp.clip(rows, 0, self.log_T.shape[0] - 1)
        x = self.thickness_mm.astype(t.dtype)
        y = self.log_T.astype(t.dtype)
        finite = jnp.isfinite(t)
        t_s = jnp.where(finite, t, 0.0)
        # past the table (16 mean free paths) the diffusion solution's shape, anchored at the last node: a slab of
        # thickness L with extrapolated boundaries z_e = 2 A_b D on both faces transmits ~ 1 / sinh(k (L + 2 z_e)),
        # k = sqrt(3 (1 - alpha)) / mfp, which is 1 / (L + 2 z_e) where nothing is absorbed. The last segment's
        # exponential decay, continued, was 35-60x too low for 10 mm of spectralon and 6x for cream (the tests'
        # Monte Carlo through the same media)
        mfp = self.mfp_mm.astype(t.dtype)  # (M, 3)
        k = jnp.sqrt(3.0 * jnp.clip(1.0 - self.albedo_ss.astype(t.dtype), 0.0, 1.0)) / mfp
        z_e = _extrapolation_mfp(self.eta.astype(t.dtype))[:, None] * mfp

        def one(xm, ym, km, zm):  # (N,), (N,), (), () -> log T at every t
            inside = jnp.interp(t_s, xm, ym)
            a, b = xm[-1] + 2 * zm, jnp.maximum(t_s, xm[-1]) + 2 * zm
            return jnp.where(t_s > xm[-1], ym[-1] + _log_sinh_ratio(a, b, km), inside)

        per = jax.vmap(jax.vmap(one, in_axes=(1, 1, 0, 0)), in_axes=(0, 0, 0, 0))(x, y, k, z_e)  # (M, 3, ...)
        per = jnp.moveaxis(per, 1, -1)  # (M, ..., 3)
        log_t = jnp.take_along_axis(per, rows[None, ..., None], axis=0)[0]
        return jnp.where(finite[..., None], jnp.exp(log_t), 0.0)

    def _rows(self, t: Array, rows: ArrayLike | None) -> Array:
        rows = jnp.zeros(t.shape, jnp.int32) if rows is None else jnp.asarray(rows)
        return jnp.clip(rows, 0, self.log_T.shape[0] - 1)

    def unscattered(self, thickness_mm: ArrayLike, rows: ArrayLike | None = None) -> Array:
        """The collimated part of ``transmittance``, ``(..., 3)``: the beam that crossed without scattering."""
        t = jnp.asarray(thickness_mm)
        t = jnp.maximum(t.astype(jnp.result_type(t.dtype, self.log_T.dtype)), 0.0)
        r = self._rows(t, rows)
        mfp = self.mfp_mm.astype(t.dtype)[r]  # (..., 3)
        eta = self.eta.astype(t.dtype)[r][..., None]
        finite = jnp.isfinite(t)[..., None]
        tau = jnp.where(finite, t[..., None], 0.0) / mfp
        return jnp.where(finite, unscattered_transmittance(tau, eta), 0.0)

    def optical(self, thickness_mm: ArrayLike, rows: ArrayLike | None = None) -> tuple[Array, Array, Array]:
        """``(tau, albedo_ss, eta)`` at thicknesses ``(...)`` mm of rows ``(...)``: ``(..., 3)``, ``(..., 3)``,
        ``(...)``, what ``slab_exit`` takes."""
        t = jnp.asarray(thickness_mm)
        t = jnp.maximum(t.astype(jnp.result_type(t.dtype, self.log_T.dtype)), 0.0)
        r = self._rows(t, rows)
        return t[..., None] / self.mfp_mm.astype(t.dtype)[r], self.albedo_ss.astype(t.dtype)[r], \
            self.eta.astype(t.dtype)[r]

    def diffuse_transmittance(self, thickness_mm: ArrayLike, rows: ArrayLike | None = None) -> Array:
        """The diffusely transmitted part of ``transmittance``, ``(..., 3)``: the total less ``unscattered``, what a
        camera that does not look into the light sees of a back light (never negative; 0 at t = 0)."""
        return jnp.maximum(self.transmittance(thickness_mm, rows) - self.unscattered(thickness_mm, rows), 0.0)
