"""The stability sweep: every technique, profile and kernel over the cross product of extreme inputs.

For each case the outcome is one of
- ``ok``: output finite, gradients (w.r.t. the material parameters and the irradiance) finite, energy bounded;
- ``handled_error``: the input is invalid and a clear ``ValueError``/``TypeError`` named it (counted as handled);
- ``nonfinite_output`` / ``nonfinite_gradient`` / ``energy_unbounded`` / ``unexpected_error``: a failure.

Invalid inputs go through the same host-side validation the command line and the batch API use
(``validate_buffers``, the materials' constructors), so "handled" means a user would have seen that message.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import time
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import NoSSSPixelsWarning, ReferenceWindowWarning, SamplingWarning
from ._kernels import separable_kernel_from_profile, spiral_samples, two_gaussian_kernel
from ._materials import BurleyMaterial, DirectionalLight, STAParams, TwoGaussianMaterial
from ._profiles import BurleyProfile, burley_cdf, burley_inverse_cdf, burley_R
from ._scene import Buffers, Camera, validate_buffers
from ._techniques import (
    AbstractTechnique,
    Burley,
    EeveeNextPass,
    HdrpPass,
    Reference,
    Separable,
    Translucency,
)

__all__ = ["run_sweep", "sweep_cases", "Case"]

D_MM = (0.0, 1e-6, 1e-3, 1.0, 1e3, 1e6)
ALBEDO = (0.0, 1e-6, 0.5, 1 - 1e-6, 1.0)
SIGMA = (0.0, 1e-8, 1e4)
W = (0.0, 1.0)
STA_POWER = (0.0, 1e3)
DEPTH_SPECIALS = ("plain", "zero", "inf", "nan", "tiny", "huge")
IRRADIANCE = ("plain", "zero", "subnormal", "1e-30", "1e30")
DTYPES = ("float16", "float32", "float64")
SIZES = ((1, 1), (1, 5), (4, 4))

CAMERA = Camera(focal_px=50.0, mm_per_unit=10.0)
_QUICK_DTYPE = {"burley": "float16", "separable_burley": "float32", "reference": "float32",
                "separable_two_gaussian": "float16", "sta": "float32", "hdrp": "float32", "eevee_next": "float16"}
# the passes a Burley material drives, swept over the same extremes (jimenez fits its shader parameters to a
# BurleyMaterial on the host, which a sweep's traced material cannot give: tests/test_engine_passes.py has its)
_BURLEY_DRIVEN = ("burley", "separable_burley", "reference", "hdrp", "eevee_next")


@dataclasses.dataclass
class Case:
    component: str
    params: dict[str, Any]
    outcome: str = ""
    message: str = ""


def _depth(kind: str, shape, dtype) -> np.ndarray:
    z = np.full(shape, 20.0)
    if kind != "plain":
        value = {"zero": 0.0, "inf": np.inf, "nan": np.nan, "tiny": 1e-8, "huge": 1e8}[kind]
        z.flat[:: 2] = value  # every other pixel: specials next to ordinary neighbours
    with np.errstate(over="ignore"):  # 1e8 is inf in float16: a sky pixel, as it should be
        return z.astype(dtype)


def _irradiance(kind: str, shape, dtype) -> np.ndarray:
    rng = np.random.default_rng(0)
    e = rng.uniform(0.1, 1.0, shape + (3,))
    if kind == "zero":
        e[:] = 0.0
    elif kind == "subnormal":
        e[:] = np.finfo(np.dtype(dtype)).smallest_subnormal
    elif kind == "1e-30":
        e *= 1e-30
    elif kind == "1e30":
        e *= 1e30
    with np.errstate(over="ignore"):  # 1e30 overflows float16 to inf on purpose: validation must say so
        return e.astype(dtype)


def sweep_cases(quick: bool = False) -> Iterator[Case]:
    """All cases (``quick``: the technique cases in one dtype per technique (float16 or float32) at 4x4, then every
    7th: ~1/20 of them; one tap count)."""
    big: list[Case] = []
    for tech in _BURLEY_DRIVEN:
        for d, a, dk, ek, dt in itertools.product(D_MM, ALBEDO, DEPTH_SPECIALS, IRRADIANCE, DTYPES):
            big.append(Case(tech, dict(d_mm=d, albedo=a, depth=dk, irradiance=ek, dtype=dt, size=(4, 4))))
        for d, dt, size in itertools.product(D_MM, DTYPES, SIZES[:2]):
            big.append(Case(tech, dict(d_mm=d, albedo=0.5, depth="plain", irradiance="plain", dtype=dt, size=size)))
    for sn, sf, w, dk, ek, dt in itertools.product(SIGMA, SIGMA, W, DEPTH_SPECIALS, IRRADIANCE, DTYPES):
        big.append(Case("separable_two_gaussian", dict(sigma_near_mm=sn, sigma_far_mm=sf, w=w, depth=dk,
                                                       irradiance=ek, dtype=dt, size=(4, 4))))
    for p, dist, thick, dk, ek, dt in itertools.product(STA_POWER, (0.0, 1.0), (1e-6, 1.0, 1e6), DEPTH_SPECIALS,
                                                        IRRADIANCE, DTYPES):
        big.append(Case("sta", dict(power=p, distortion=dist, thickness_mm=thick, depth=dk, irradiance=ek, dtype=dt,
                                    size=(4, 4))))
    if quick:
        # every technique and every kind of extreme at one size and one dtype per technique (float16 for some, whose
        # work dtype is float32, float32 for the others): one compilation per technique. The stride, 7, is coprime
        # to the sizes of the product's axes (2, 3, 5, 6), so the subset still meets every combination of kinds.
        big = [c for c in big
               if c.params["dtype"] == _QUICK_DTYPE[c.component] and tuple(c.params["size"]) == (4, 4)]
        big = big[::7]
    yield from big
    # the profiles, kernels and invalid parameters: small, always all
    for d, r in itertools.product(D_MM, (0.0, 1e-30, 1e-6, 1.0, 1e6, np.inf)):
        yield Case("profile", dict(d_mm=d, r_mm=r))
    tap_counts = (5,) if quick else (1, 5, 25)
    for d, taps in itertools.product(D_MM, tap_counts):
        yield Case("kernel_preintegrated", dict(d_mm=d, taps=taps))
    for sn, sf, w, taps in itertools.product(SIGMA, SIGMA, W, tap_counts):
        yield Case("kernel_two_gaussian", dict(sigma_near_mm=sn, sigma_far_mm=sf, w=w, taps=taps))
    for n in (1, 4, 128):
        yield Case("spiral_samples", dict(n=n))
    for bad in (dict(d_mm=np.nan), dict(d_mm=-1.0), dict(albedo=1.5), dict(albedo=np.nan), dict(d_mm=np.inf)):
        yield Case("invalid_parameter", dict(bad))
    slabs = (None, 1e-6, 1e3)
    for a, slab, eta in itertools.product((0.0, 1.0) if quick else ALBEDO, slabs, (1.0, 1.4)):
        yield Case("montecarlo", dict(albedo=a, slab_mfp=slab, eta=eta))
    for bad in (dict(albedo=-0.1), dict(albedo=np.nan), dict(albedo=0.5, g=1.0), dict(albedo=0.5, eta=0.5),
                dict(albedo=0.5, slab_mfp=0.0)):
        yield Case("montecarlo", bad)
    # limits of value, not only finiteness: d -> 0 is the identity, d -> large spreads the light (no return to the
    # input), edges blur monotonically with d, STA's output stays within its bound
    for tech in ("burley", "separable_burley", "reference"):
        yield Case("limit_identity", dict(technique=tech))
        yield Case("limit_large_d", dict(technique=tech))
        yield Case("limit_monotone_edge", dict(technique=tech))
    for p, thick in itertools.product(STA_POWER, (1e-6, 1.0, 1e6)):
        yield Case("limit_sta_bounded", dict(power=p, thickness_mm=thick))
    for d in ((1e-3,) if quick else D_MM):
        yield Case("fit_two_gaussian", dict(d_mm=d))
    for d in ((1e3,) if quick else D_MM):
        yield Case("fit_sta", dict(d_mm=d))


# ------------------------------------------------------------------------------------------------------------------


def _finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(x, np.float64)))) for x in jax.tree.leaves(tree))


_COMPILED: dict[tuple, Callable] = {}


_burley_material = lambda p: BurleyMaterial(p["albedo"], p["d_mm"])


@dataclasses.dataclass(frozen=True)
class _Component:
    """A technique as the stability sweep runs it: the technique (from the sweep's small counts), the material it
    takes from a case's parameters (traced or not), and those parameters from a case's (host side)."""

    technique: Callable[[int, int, int], AbstractTechnique]  # (samples, taps, radius) -> technique
    material: Callable[[dict], Any]
    params: Callable[[dict], dict]


def _burley_params(p):
    return dict(albedo=np.full((3,), p["albedo"], np.float32), d_mm=np.full((3,), p["d_mm"], np.float32))


def _two_gaussian_params(p):
    return dict(albedo=np.full((3,), 0.7, np.float32), w=np.full((3,), p["w"], np.float32),
                sigma_near_mm=np.full((3,), p["sigma_near_mm"], np.float32),
                sigma_far_mm=np.full((3,), p["sigma_far_mm"], np.float32))


_TECHNIQUE_COMPONENTS: dict[str, _Component] = {
    "burley": _Component(lambda n, taps, radius: Burley(samples=n), _burley_material, _burley_params),
    "separable_burley": _Component(lambda n, taps, radius: Separable(taps=taps), _burley_material, _burley_params),
    "reference": _Component(lambda n, taps, radius: Reference(radius_px=radius, near_subsamples=2), _burley_material,
                            _burley_params),
    "hdrp": _Component(lambda n, taps, radius: HdrpPass(quality="low"), _burley_material, _burley_params),
    "eevee_next": _Component(lambda n, taps, radius: EeveeNextPass(), _burley_material, _burley_params),
    "separable_two_gaussian": _Component(
        lambda n, taps, radius: Separable(taps=taps),
        lambda p: TwoGaussianMaterial(p["albedo"], p["w"], p["sigma_near_mm"], p["sigma_far_mm"]), _two_gaussian_params),
    "sta": _Component(
        lambda n, taps, radius: Translucency(DirectionalLight(jnp.asarray([0.2, -0.3, 0.9], jnp.float32)),
                                             thickness=0.05),
        lambda p: STAParams(distortion=p["distortion"], power=p["power"], scale=1.0, ambient=0.1,
                            thickness_mm=p["thickness_mm"]),
        lambda p: {k: np.asarray(p[k], np.float32) for k in ("power", "distortion", "thickness_mm")}),
}


def _technique_fn(component: str, samples: int = 4, taps: int = 5, radius: int = 3) -> Callable:
    """Batched (irradiance, depth, params) -> ((objective, output), grads w.r.t. irradiance and params): one vmapped
    jitted call serves every case of a (component, dtype, size) group."""
    key = (component, samples, taps, radius)
    if key in _COMPILED:
        return _COMPILED[key]
    spec = _TECHNIQUE_COMPONENTS[component]
    technique = spec.technique(samples, taps, radius)

    def forward(irradiance, depth, params):
        b = Buffers(irradiance=irradiance, depth=depth)
        out = technique(b, spec.material(params), CAMERA)
        # a scale-free objective: finite for inputs of any magnitude
        scale = jax.lax.stop_gradient(1.0 + jnp.max(jnp.abs(irradiance.astype(jnp.float32))))
        return jnp.sum(out.astype(jnp.float32)) / scale, out

    fn = jax.jit(jax.vmap(jax.value_and_grad(forward, argnums=(0, 2), has_aux=True)))
    _COMPILED[key] = fn
    return fn


def _prepare_technique_case(case: Case):
    """Host-side validation as a user would meet it; the arrays of a valid case, or None (outcome recorded)."""
    p = case.params
    dtype = np.dtype(p["dtype"])
    shape = tuple(p["size"])
    e = _irradiance(p["irradiance"], shape, dtype)
    z = _depth(p["depth"], shape, dtype)
    spec = _TECHNIQUE_COMPONENTS[case.component]
    try:
        validate_buffers(Buffers(irradiance=jnp.asarray(e), depth=jnp.asarray(z)))
        params = spec.params(p)
        spec.material(params)  # host-side range checks
    except (ValueError, TypeError) as exc:
        case.outcome, case.message = "handled_error", str(exc)
        return None
    return e, z, params


def _run_technique_group(cases: list[Case]) -> None:
    prepared = [(c, _prepare_technique_case(c)) for c in cases]
    prepared = [(c, x) for c, x in prepared if x is not None]
    if not prepared:
        return
    dtype = np.dtype(prepared[0][0].params["dtype"])
    e = jnp.asarray(np.stack([x[0] for _, x in prepared]))
    z = jnp.asarray(np.stack([x[1] for _, x in prepared]))
    params = {k: jnp.asarray(np.stack([x[2][k] for _, x in prepared])) for k in prepared[0][1][2]}
    (values, outs), grads = _technique_fn(prepared[0][0].component)(e, z, params)
    values, outs = np.asarray(values, np.float64), np.asarray(outs, np.float64)
    grads = jax.tree.map(lambda g: np.asarray(g, np.float64), grads)
    e64 = np.asarray(e, np.float64)
    for i, (case, _) in enumerate(prepared):
        out = outs[i]
        if not np.all(np.isfinite(out)) or not np.isfinite(values[i]):
            case.outcome = "nonfinite_output"
            continue
        if not all(np.all(np.isfinite(g[i])) for g in jax.tree.leaves(grads)):
            case.outcome = "nonfinite_gradient"
            continue
        if _TECHNIQUE_COMPONENTS[case.component].technique(1, 1, 1).conserves_energy:
            # redistribution creates no light: every output is a convex combination of inputs times albedo <= 1,
            # so no pixel exceeds the brightest input, and the total stays within the border effects of a gather
            tol = 2e-2 if dtype == np.float16 else 1e-4
            top, total_in, total_out = e64[i].max(), e64[i].sum(), out.sum()
            if out.max() > top * (1 + tol) + 1e-300 or total_out > 1.25 * total_in + 1e-300:
                case.outcome = "energy_unbounded"
                case.message = f"max out/in {out.max() / max(top, 1e-300):.6g}, total {total_out / max(total_in, 1e-300):.6g}"
                continue
        case.outcome = "ok"


# the small components, jitted so every case of a kind (same shapes) shares one compilation


@jax.jit
def _profile_eval(r, d):
    half = jnp.asarray(0.5, r.dtype)
    vals = (burley_R(r, d), burley_cdf(r, d), burley_inverse_cdf(half, d))
    grads = (jax.grad(burley_cdf, argnums=(0, 1))(r, d), jax.grad(lambda dd: burley_inverse_cdf(half, dd))(d))
    return vals, grads


@functools.partial(jax.jit, static_argnums=1)
def _preintegrated_eval(d, taps):
    kernel = lambda dd: separable_kernel_from_profile(BurleyProfile(dd), taps=taps)
    k = kernel(d)
    return k.offsets_mm, k.weights, jax.grad(lambda dd: jnp.sum(kernel(dd).weights[0] ** 2))(d)


@functools.partial(jax.jit, static_argnums=3)
def _two_gaussian_eval(w, sigma_near, sigma_far, taps):
    kernel = lambda *a: two_gaussian_kernel(*a, taps=taps)
    k = kernel(w, sigma_near, sigma_far)
    grads = jax.grad(lambda *a: jnp.sum(kernel(*a).weights[0] ** 2), argnums=(0, 1, 2))(w, sigma_near, sigma_far)
    return k.offsets_mm, k.weights, grads


def _run_small_case(case: Case) -> None:
    p = case.params
    try:
        if case.component == "profile":
            vals, grads = _profile_eval(jnp.float32(p["r_mm"]), jnp.float32(p["d_mm"]))
            vals = list(vals)
            # R(0) is +inf by definition (the integrable 1/r peak): every other value must be finite
            if p["r_mm"] == 0.0 and p["d_mm"] > 0:
                if not np.isposinf(float(vals[0])):
                    case.outcome = "nonfinite_output"
                    return
                vals = vals[1:]
        elif case.component == "kernel_preintegrated":
            offsets, weights, grads = _preintegrated_eval(jnp.full((3,), p["d_mm"], jnp.float32), p["taps"])
            vals = [offsets, weights, jnp.sum(weights, axis=0) - 1]
        elif case.component == "kernel_two_gaussian":
            args = [jnp.full((3,), p[n], jnp.float32) for n in ("w", "sigma_near_mm", "sigma_far_mm")]
            offsets, weights, grads = _two_gaussian_eval(*args, p["taps"])
            vals = [offsets, weights, jnp.sum(weights, axis=0) - 1]
        elif case.component == "spiral_samples":
            s = spiral_samples(p["n"])
            vals, grads = [s.unit_radii(), s.angles], []
        elif case.component in ("fit_two_gaussian", "fit_sta"):
            from ._fitting import fit_sta, fit_two_gaussian_to_burley

            d = np.full(3, p["d_mm"])
            if case.component == "fit_two_gaussian":
                f = fit_two_gaussian_to_burley(d)
                vals = [np.asarray(f[k]) for k in ("w", "sigma_near_mm", "sigma_far_mm")]
                vals.append(np.asarray(f["fit"]["error_relative_l2"]))
            else:
                f = fit_sta(d, solver="optimistix")
                vals = [np.asarray(f[k]) for k in ("distortion", "power", "scale", "ambient", "thickness_mm")]
                vals.append(np.asarray(f["fit"]["error_relative_l2"]))
            grads = []
        elif case.component == "montecarlo":
            from ._montecarlo import simulate

            kw = {k: v for k, v in p.items() if k != "albedo"}
            r = simulate(p["albedo"], photons=256, lanes=256, bins=8, r_max_mfp=4.0, max_events=500, seed=1, **kw)
            vals = [r.R, r.R_stderr, r.T, np.asarray([r.total_reflectance, r.total_transmittance])]
            grads = []
            total = r.total_reflectance + r.total_transmittance + r.capped_weight
            if not total <= 1 + 1e-4:
                case.outcome, case.message = "energy_unbounded", f"R + T = {total}"
                return
        else:  # invalid_parameter
            BurleyMaterial(p.get("albedo", 0.5), jnp.full((3,), p.get("d_mm", 1.0)))
            case.outcome, case.message = "unexpected_error", "invalid parameter accepted"
            return
    except (ValueError, TypeError) as exc:
        case.outcome, case.message = "handled_error", str(exc)
        return
    if case.component.startswith("kernel") and abs(float(jnp.max(jnp.abs(vals[2])))) > 1e-5:
        case.outcome, case.message = "energy_unbounded", "kernel weights do not sum to 1"
        return
    if not _finite(vals):
        case.outcome = "nonfinite_output"
    elif not _finite(grads):
        case.outcome = "nonfinite_gradient"
    else:
        case.outcome = "ok"


# the limit cases: a step edge on a 12 x 16 plane at 1 px per mm, float64
_LIMIT_CAMERA = Camera(focal_px=1.0, mm_per_unit=1.0)
_LIMIT_D = (1.0, 4.0, 16.0, 64.0, 1e3, 1e6, 1e9)  # mm = px


def _limit_step() -> Buffers:
    e = np.zeros((12, 16, 3))
    e[:, 8:] = 1.0
    e[:, 8:, 2] = 0.5
    return Buffers(irradiance=jnp.asarray(e), depth=jnp.ones((12, 16)))


# the techniques of the limit checks, with light leaving at the frame (the large-d limit is light leaving, not the
# in-frame mean); Burley with four frames of rotations: the sampling noise well below the tolerances
_LIMIT_TECHNIQUES: dict[str, AbstractTechnique] = {
    "burley": Burley(samples=16, frames=4, border="leaves"),
    "separable_burley": Separable(taps=25, border="leaves"),
    "reference": Reference(radius_px=15, near_subsamples=2, border="leaves"),
}


def _limit_run(technique: str, b: Buffers, d_mm: float):
    mat = BurleyMaterial(albedo=(1.0, 1.0, 1.0), d_mm=(d_mm,) * 3)
    return np.asarray(_LIMIT_TECHNIQUES[technique](b, mat, _LIMIT_CAMERA), np.float64)


def _jump(out) -> float:
    return float(np.mean(out[:, 8, 0] - out[:, 7, 0]))


def _run_limit_case(case: Case) -> None:
    """Limits of value: the output a configuration tends to, not only that it is finite."""
    p, b = case.params, _limit_step()
    e = np.asarray(b.irradiance, np.float64)
    problem = ""
    if case.component == "limit_identity":
        for d in (0.0, 1e-6):
            err = np.abs(_limit_run(p["technique"], b, d) - e).max()
            if err > 1e-4:
                problem = f"d = {d} mm: max |out - in| {err:.3g} (identity expected)"
    elif case.component == "limit_large_d":
        # light spreads over the frame and beyond (it leaves through the border): the output tends to 0 like the
        # share of a profile of width d that stays in the frame (~ frame / d), never back to the input
        prev = None
        for d in (1e3, 1e6, 1e9):
            out = _limit_run(p["technique"], b, d)
            if out.sum() > e.sum() * (1 + 1e-6):
                problem = f"d = {d:g} mm: energy out/in {out.sum() / e.sum():.4g} > 1"
            if prev is not None and out.max() > prev * 1.05 + 1e-12:
                problem = f"d = {d:g} mm: the output grows again ({out.max():.3g} after {prev:.3g})"
            prev = out.max()
        if prev > 1e-3:
            problem = problem or f"d = 1e9 mm: max output {prev:.3g}, expected ~ frame / d (light spread over metres)"
    elif case.component == "limit_monotone_edge":
        jumps = [_jump(_limit_run(p["technique"], b, d)) for d in _LIMIT_D]
        bad = [i for i in range(1, len(jumps)) if jumps[i] > jumps[i - 1] + 1e-4]
        if bad:
            problem = "the jump across the edge grows with d: " + ", ".join(f"{j:.4g}" for j in jumps)
    elif case.component == "limit_sta_bounded":
        # out = albedo (E + light A_L t (T_dir + a_T)) with T_dir <= scale, A_L, t <= 1, albedo <= 1
        scale, ambient = np.array([1.0, 0.8, 0.6]), np.array([0.05, 0.05, 0.05])
        sta = STAParams(distortion=0.2, power=p["power"], scale=tuple(scale), ambient=tuple(ambient),
                        thickness_mm=(p["thickness_mm"],) * 3)
        colour = (2.0, 2.0, 2.0)
        for theta in (0.0, 1.0, 2.5):
            lit = DirectionalLight((math.sin(theta), 0.0, math.cos(theta)), colour)
            out = np.asarray(Translucency(lit, thickness=1.0)(b, sta, _LIMIT_CAMERA), np.float64)
            bound = e + 2.0 * (scale + ambient)
            if np.any(out > bound * (1 + 1e-6)) or np.any(out < e * (1 - 1e-6)):
                problem = f"light at {theta} rad: output outside [E, E + light (scale + ambient)]"
    case.outcome, case.message = ("limit_violated", problem) if problem else ("ok", "")


def run_sweep(*, quick: bool = False, progress: bool = True) -> dict[str, Any]:
    """Run the sweep and return the summary with every case (the JSON ``sss-jax stability`` writes).

    The float64 cases must really run in float64: the sweep runs in a local ``jax.enable_x64`` scope, which leaves
    the caller's setting as it was. The techniques' own advice on extreme inputs (a sampling or window warning, a
    kernel reaching far past the frame) and NumPy's word on a float16 overflow the sweep makes on purpose are not
    its findings: they are silenced within it (they printed in Python's raw form between the progress bar's
    lines)."""
    with jax.enable_x64(True), warnings.catch_warnings():
        for category in (SamplingWarning, ReferenceWindowWarning, NoSSSPixelsWarning):
            warnings.simplefilter("ignore", category)
        warnings.filterwarnings("ignore", message="overflow encountered in cast", category=RuntimeWarning)
        return _run_sweep(quick, progress)


def _run_sweep(quick: bool, progress: bool) -> dict[str, Any]:
    cases = list(sweep_cases(quick))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(cases), unit="case", desc="stability sweep")
    t0 = time.perf_counter()
    groups: dict[tuple, list[Case]] = {}
    for case in cases:
        if case.component.startswith("limit_"):
            try:
                _run_limit_case(case)
            except Exception as exc:  # noqa: BLE001 - an unexpected error is a finding, recorded, not a crash
                case.outcome, case.message = "unexpected_error", f"{type(exc).__name__}: {exc}"
            if bar is not None:
                bar.update(1)
        elif case.component in ("profile", "kernel_preintegrated", "kernel_two_gaussian", "spiral_samples",
                                "invalid_parameter", "montecarlo", "fit_two_gaussian", "fit_sta"):
            try:
                _run_small_case(case)
            except Exception as exc:  # noqa: BLE001 - an unexpected error is a finding, recorded, not a crash
                case.outcome, case.message = "unexpected_error", f"{type(exc).__name__}: {exc}"
            if bar is not None:
                bar.update(1)
        else:
            groups.setdefault((case.component, case.params["dtype"], tuple(case.params["size"])), []).append(case)
    for group in groups.values():
        try:
            _run_technique_group(group)
        except Exception as exc:  # noqa: BLE001
            for case in group:
                if not case.outcome:
                    case.outcome, case.message = "unexpected_error", f"{type(exc).__name__}: {exc}"
        if bar is not None:
            bar.update(len(group))
    if bar is not None:
        bar.close()
    count = lambda name: sum(c.outcome == name for c in cases)
    return {
        "cases": len(cases),
        "ok": count("ok"),
        "handled_errors": count("handled_error"),
        "nonfinite_outputs": count("nonfinite_output"),
        "nonfinite_gradients": count("nonfinite_gradient"),
        "energy_unbounded": count("energy_unbounded"),
        "limit_violations": count("limit_violated"),
        "unexpected_errors": count("unexpected_error"),
        "seconds": round(time.perf_counter() - t0, 1),
        "quick": quick,
        "case_list": [dict(component=c.component, params={k: _jsonable(v) for k, v in c.params.items()},
                           outcome=c.outcome, message=c.message[:300]) for c in cases],
    }


def _jsonable(v):
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    if isinstance(v, tuple):
        return list(v)
    return v
