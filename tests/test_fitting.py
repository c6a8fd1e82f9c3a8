"""Fits recover known parameters from synthetic targets; both solvers agree; the fitted kernels' errors."""

import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax import _fitting as F


def test_profile_fit_recovers_a_known_two_gaussian_with_both_solvers():
    # a target made by the model itself (exact pixel integrals): the optimum is the truth, error 0
    truth = np.array([0.35, 0.4, 1.8])
    grid = np.asarray(F.two_gaussian_pixel_mass(jnp.asarray(truth[:1]), jnp.asarray(truth[1:2]),
                                                jnp.asarray(truth[2:3]), 0.1, 30))[..., 0]
    found = {}
    for solver in F.SOLVERS:
        x, err, outcome, it = F.fit_two_gaussian_grid(grid, 0.1, solver=solver, starts=1)
        np.testing.assert_allclose(x, truth, rtol=1e-3)
        assert err < 1e-4 and outcome == "successful" and it > 0
        found[solver] = x
    np.testing.assert_allclose(found["optimistix"], found["jaxopt"], rtol=1e-3)  # the same optimum
    with pytest.raises(ValueError, match="unknown solver 'newton'; valid solvers: optimistix, jaxopt"):
        F.fit_two_gaussian_grid(grid, 0.1, solver="newton")


def test_burley_fit_is_scale_invariant_and_records_itself():
    # Burley profiles of every d have one shape: the fitted kernel scales with d and the error is the same
    fit = F.fit_two_gaussian_to_burley([4.0, 2.0, 1.0])
    sn, sf = np.asarray(fit["sigma_near_mm"]), np.asarray(fit["sigma_far_mm"])
    np.testing.assert_allclose(sn / [4.0, 2.0, 1.0], sn[0] / 4.0, rtol=1e-3)
    np.testing.assert_allclose(sf / [4.0, 2.0, 1.0], sf[0] / 4.0, rtol=1e-3)
    np.testing.assert_allclose(fit["w"], fit["w"][0], rtol=1e-3)
    assert np.all(sn < sf)
    rec = fit["fit"]
    assert rec["solver"] == "optimistix" and rec["outcome"] == "successful" and rec["seconds"] > 0
    # what separable renders, a(x) a(y), against Burley on pixels of side d (issue #18's goal: <= 0.25; the kernel
    # fitted before, radial and r-weighted, w 0.628, sigma 0.904 d / 3.07 d, was 0.55 on this measure). A separable
    # product cannot be radial, so the error stays well above 0: measured 0.196
    assert 0.1 < rec["error_relative_l2"][0] <= 0.25


def test_fitted_kernel_image_error_is_bounded():
    # bound: 12% relative L2 over the five test patterns (measured 5.7%; 9.5% with the r-weighted fit before). Justification: the point light dominates
    # it (a delta shows the kernel itself, and no separable product matches the radial 1/r peak); the pre-integrated
    # kernel of the same profile, measured beside it, is the best a separable pass does; local shading (no
    # scattering) is at 67%. A kernel within 12% is doing the job; a broken fit is several times worse.
    cam = sj.Camera(focal_px=60.0, mm_per_unit=10.0)  # 0.6 px per mm at depth 10
    target = sj.BurleyMaterial([1.0, 1.0, 1.0], [4.0, 2.5, 1.5])
    fit = F.fit_two_gaussian_to_burley(np.asarray(target.d_mm[0]))
    tg = sj.TwoGaussianMaterial([1, 1, 1], fit["w"], fit["sigma_near_mm"], fit["sigma_far_mm"])
    patterns = F.image_patterns(24)
    # the default radius (99.9% of the energy: 48-50 px here) is wider than the 24-px frame; offsets beyond 23 px
    # land only in the zero padding and add exact zeros, so radius 23 gives the same image, in one compilation
    # for all five patterns and a quarter of the loop
    # image_error's rule: the patterns end at the frame, light leaves there
    refs = [np.asarray(sj.reference(b, target, cam, radius_px=23, border="leaves")) for b in patterns]
    err = F.image_error(tg, target, cam, patterns, references=refs)
    local = np.sqrt(sum(np.sum((np.asarray(b.irradiance) - r) ** 2) for b, r in zip(patterns, refs))
                    / sum(np.sum(r**2) for r in refs))
    pre = sj.separable  # the pre-integrated kernel of the target profile, for comparison
    pre_err = np.sqrt(sum(np.sum((np.asarray(pre(b, target, cam, taps=25, border="leaves")) - r) ** 2) for b, r in zip(patterns, refs))
                      / sum(np.sum(r**2) for r in refs))
    print(f"image-space error: fitted two-Gaussian {err:.4f}, pre-integrated {pre_err:.4f}, local {local:.4f}")
    assert err < 0.12 and local > 5 * err
    assert pre_err < 0.12 and local > 5 * pre_err  # the pre-integrated kernel of the profile does the job as well


def test_inverse_fit_recovers_d_from_an_image():
    rng = np.random.default_rng(0)
    h = w = 20
    e = np.zeros((h, w, 3))
    e[:, : w // 2] = 1.0
    e += rng.uniform(0, 0.3, (h, w, 3))
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.full((h, w), 10.0))
    cam = sj.Camera(60.0, 10.0)
    truth = np.array([5.0, 3.0, 1.5])
    target = sj.burley(b, sj.BurleyMaterial([1, 1, 1], truth), cam, samples=16)
    fit = F.fit_burley_from_image(b, target, cam, albedo=[1, 1, 1], d0_mm=[2.0, 2.0, 2.0], samples=16)
    np.testing.assert_allclose(fit["d_mm"], truth, rtol=0.01)
    assert fit["fit"]["error_relative_l2"] < 1e-3
    # the documented second solver: jaxopt carried the sample count through its loop as a traced value, and burley
    # refused it ("samples must be a positive integer, got JitTracer"): every call failed
    fit = F.fit_burley_from_image(b, target, cam, albedo=[1, 1, 1], d0_mm=[2.0, 2.0, 2.0], samples=16,
                                  solver="jaxopt")
    np.testing.assert_allclose(fit["d_mm"], truth, rtol=0.01)
    # from 40x too narrow the search (d0 / 20 .. 20 d0) cannot reach the truth: d ends pinned at 20 d0, which read as
    # "successful" (found by a review); that is the search's edge, not an optimum
    fit = F.fit_burley_from_image(b, target, cam, albedo=[1, 1, 1], d0_mm=truth / 40, samples=16)
    np.testing.assert_allclose(fit["d_mm"], truth / 2, rtol=1e-3)
    assert fit["fit"]["outcome"] == F.AT_SEARCH_BOUND


def test_fits_refuse_what_they_cannot_fit_before_solving(as_users_run_it):
    # each fitted quietly: a black, NaN or negative target (the start returned, or garbage "successful"), a float
    # sample count (2.7 ran as 2), a NaN or negative thickness range; others failed deep inside (a target of another
    # shape, starts=0, half=0, taps=0 after the references' renders, size=0, an init without sigmas)
    h = w = 12
    b = sj.Buffers(irradiance=jnp.ones((h, w, 3)), depth=jnp.full((h, w), 10.0))
    cam = sj.Camera(60.0, 10.0)
    target = np.ones((h, w, 3))
    kw = {"albedo": [1, 1, 1], "d0_mm": [2.0, 2.0, 2.0]}
    for bad, message in ((0 * target, "target_image is black"), (-target, "target_image is black"),
                         (np.full_like(target, np.nan), "target_image has 432 non-finite values"),
                         (target[:, :-1], r"target_image is \(12, 11, 3\), the buffers' irradiance \(12, 12, 3\)")):
        with pytest.raises(ValueError, match=message):
            F.fit_burley_from_image(b, bad, cam, samples=4, **kw)
    with pytest.raises(ValueError, match="samples must be a positive integer, got 2.7"):
        F.fit_burley_from_image(b, target, cam, samples=2.7, **kw)
    for rng, message in (((np.nan, 2.0), "thickness_range must be finite and > 0"), ((-1.0, 2.0), "finite and > 0"),
                         ((2.0, 1.0), "lo < hi")):
        with pytest.raises(ValueError, match=message):
            sj.fit_sta([1.0, 0.5, 0.3], thickness_range=rng)
    with pytest.raises(ValueError, match=r"transmittance\(t_mm\) must return \(16, 3\)"):
        sj.fit_sta([1.0, 0.5, 0.3], transmittance=lambda t: np.ones(t.size))
    profile = sj.BurleyProfile([1.0, 0.5, 0.3])
    for kwargs, message in (({"starts": 0}, r"starts must be an integer in \[1, 4\]"), ({"half": 0}, "half must be"),
                            ({"starts": 5}, r"starts must be an integer in \[1, 4\], got 5")):  # 4 ran
        with pytest.raises(ValueError, match=message):
            sj.fit_two_gaussian_profile(profile, **kwargs)
    mat = sj.BurleyMaterial([0.8, 0.6, 0.5], [1.0, 0.5, 0.3])
    for kwargs, message in (({"taps": 0}, "taps must be an odd positive integer"), ({"size": 0}, "size must be"),
                            ({"init": {"w": [0.5]}}, "init must be a dict with w, sigma_near_mm and sigma_far_mm"),
                            # values: they failed inside the solver's loop (or as "sigma_near_mm ... got [nan]")
                            ({"init": {"w": [1.5, 0.5, 0.5], "sigma_near_mm": [1, 1, 1], "sigma_far_mm": [3, 3, 3]}},
                             r"init\['w'\] must be finite and >= 0 and <= 1"),
                            ({"init": {"w": [0.5] * 3, "sigma_near_mm": [0, 0, 0], "sigma_far_mm": [3, 3, 3]}},
                             r"init\['sigma_near_mm'\] must be finite and > 0"),
                            ({"init": {"w": [0.5], "sigma_near_mm": [1] * 3, "sigma_far_mm": [3] * 3}},
                             r"init\['w'\] must be three numbers")):
        with pytest.raises(ValueError, match=message):
            sj.fit_two_gaussian_image(mat, cam, **{"size": 8, **kwargs})


def test_sta_fit_reduces_the_error_against_slab_transmission():
    d = np.array([3.0, 1.5, 0.8])
    fit = F.fit_sta(d, solver="optimistix")
    assert fit["fit"]["outcome"] == "successful"
    # the thickness falloff orders like the scattering distances (red travels furthest)
    assert fit["thickness_mm"][0] > fit["thickness_mm"][1] > fit["thickness_mm"][2]
    assert fit["fit"]["error_relative_l2"] < 0.35
    # target by hand: T(t) = (e^{-t/d} + 3 e^{-t/3d})/4 at t = d is (e^-1 + 3 e^{-1/3})/4
    np.testing.assert_allclose(np.asarray(F.burley_slab_transmittance(np.array([3.0]), d))[0, 0],
                               (np.exp(-1) + 3 * np.exp(-1 / 3)) / 4)


def test_the_default_sta_fit_converges_outside_x64():
    # sj.fit_sta as a user calls it (x64 off, the default L-BFGS-B): before, it ran in float32, could not meet its
    # 1e-9 tolerance and returned max_steps_reached after 1000 iterations; both solvers reach one optimum
    fits = {solver: F.fit_sta(np.array([3.0, 1.4, 0.8]), solver=solver) for solver in ("jaxopt", "optimistix")}
    assert all(f["fit"]["outcome"] == "successful" for f in fits.values()), {k: f["fit"] for k, f in fits.items()}
    np.testing.assert_allclose(fits["jaxopt"]["fit"]["error_relative_l2"],
                               fits["optimistix"]["fit"]["error_relative_l2"], rtol=1e-4)


def test_the_image_fit_checks_its_start():
    # d0 = 0 gave "d_mm ... got [nan]" from deep inside, a negative d0 an EquinoxRuntimeError
    scene = sj.demo_scene(16, 16)
    for d0 in ([0.0, 1.0, 1.0], [-1.0, 1.0, 1.0]):
        with pytest.raises(ValueError, match="d_mm must be 3 finite values > 0"):
            F.fit_burley_from_image(scene.buffers, np.zeros((16, 16, 3)), scene.camera, albedo=[0.5] * 3, d0_mm=d0)


def test_jaxopt_reports_a_nonfinite_solve():
    # a NaN loss stopped L-BFGS-B at its first step, which read as converged ("successful" with NaN parameters);
    # optimistix says "nonfinite" for the same residual
    nan_residual = lambda x, args: x * jnp.nan
    x, outcome, _ = F._solve(nan_residual, np.array([0.5]), np.array([0.0]), np.array([1.0]), "jaxopt")
    assert outcome == "nonfinite"
    with pytest.raises(ValueError, match="pixel_mm must be finite and > 0"):
        F.fit_two_gaussian_profile(sj.BurleyProfile(jnp.asarray([3.0, 1.4, 0.8])), pixel_mm=0.0)


@pytest.mark.parametrize("solver", ["optimistix", "jaxopt"])
def test_a_second_fit_of_the_same_shape_reuses_the_compiled_solver(solver):
    # a fresh closure per fit used to recompile the solver every call (7-10 s each): count XLA compilations
    import jax.monitoring

    F.fit_sta(np.array([3.0, 1.5, 0.8]), solver=solver)
    compiles = []
    listener = lambda name, seconds, **kw: compiles.append(name) if "compile" in name else None
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        fit = F.fit_sta(np.array([2.0, 1.0, 0.5]), solver=solver)  # another material, same shapes
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiles == [] and fit["thickness_mm"][0] > fit["thickness_mm"][2]


def _burley_pixels_by_hand(d, pixel, half):
    """Burley's R(r) = (e^{-r/d} + e^{-r/3d}) / (8 pi d r) (Christensen & Burley 2015) integrated over pixels of side
    ``pixel``: 16x16 midpoints per pixel, the centre pixel in polar form through the CDF
    1 - e^{-r/d}/4 - 3 e^{-r/3d}/4 (8 wedges, Gauss-Legendre in the angle). NumPy only."""
    import math

    sub = 16
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    xs = (np.arange(-half, half + 1)[:, None] + offs).reshape(-1) * pixel
    r = np.hypot(xs[:, None], xs[None, :])
    n = 2 * half + 1
    m = ((np.exp(-r / d) + np.exp(-r / (3 * d))) / (8 * math.pi * d * r)).reshape(n, sub, n, sub).mean(axis=(1, 3))
    m *= pixel**2
    t, wt = np.polynomial.legendre.leggauss(48)
    t = (t + 1) * math.pi / 8
    a = 0.5 * pixel / np.cos(t)
    m[half, half] = 8 * np.sum(wt * math.pi / 8 * (1 - np.exp(-a / d) / 4 - 3 * np.exp(-a / (3 * d)) / 4)) / (2 * math.pi)
    return m


def test_rendered_kernel_errors_against_a_hand_computation():
    # the stored errors of a kernel against an independent NumPy integration: the rendered product a(x) a(y) with
    # a(x) = w N(x; sigma_n) + (1 - w) N(x; sigma_f) integrated over each pixel (erf), and the radial mix
    # w N2(r; sigma_n) + (1 - w) N2(r; sigma_f) (isotropic, so also a product of erf differences per Gaussian)
    from math import sqrt

    from scipy.special import erf

    d, half = np.array([2.0, 1.0, 0.5]), 20
    tg = {"w": [0.6, 0.5, 0.4], "sigma_near_mm": [0.9, 0.4, 0.2], "sigma_far_mm": [8.0, 3.0, 1.5]}
    got = F.rendered_kernel_errors(tg, sj.BurleyProfile(jnp.asarray(d)), d, half=half)
    for c in range(3):
        edges = (np.arange(-half, half + 2) - 0.5) * d[c]
        g = lambda s: np.diff(0.5 * (1 + erf(edges / (sqrt(2) * s))))
        w, sn, sf = tg["w"][c], tg["sigma_near_mm"][c], tg["sigma_far_mm"][c]
        a = w * g(sn) + (1 - w) * g(sf)
        product = a[:, None] * a[None, :]
        mix = w * g(sn)[:, None] * g(sn)[None, :] + (1 - w) * g(sf)[:, None] * g(sf)[None, :]
        target = _burley_pixels_by_hand(d[c], d[c], half)
        rel = lambda m: np.linalg.norm(m - target) / np.linalg.norm(target)
        assert got["rendered_product"][c] == pytest.approx(rel(product), abs=2e-3)
        assert got["radial_mix"][c] == pytest.approx(rel(mix), abs=2e-3)


def test_the_image_fit_of_a_kernel_does_not_depend_on_the_targets_albedo(monkeypatch):
    # the references were rendered with the target's albedo and the model at albedo 1: at albedo 0.5 the fit could
    # only darken the kernel's reach (w 0.02-0.09, sigma_far 8-16 mm, error 0.80 against 0.06) and said "successful"
    # (found by a review). The kernel's shape is what is fitted: at one albedo or another the objective is the same.
    # The solver is left out (its start returned as found): the objective at the start is what differed
    monkeypatch.setattr(F, "_solve", lambda fn, x0, *a, **k: (np.asarray(x0), "successful", 0))
    cam = sj.Camera(60.0, 10.0)
    init = {"w": [0.6] * 3, "sigma_near_mm": [1.0, 0.6, 0.4], "sigma_far_mm": [4.0, 2.4, 1.6]}
    errors = [F.fit_two_gaussian_image(sj.BurleyMaterial([a] * 3, [2.0, 1.2, 0.8]), cam, size=16, taps=9,
                                       init=init)["fit"]["initial_error_relative_l2"] for a in (1.0, 0.5)]
    assert errors[1] == pytest.approx(errors[0], rel=1e-6)
    assert errors[0] < 0.5
