"""Profiles: reference values from closed forms and independent SciPy quadrature."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate as si
import scipy.special as sp
from jax.test_util import check_grads

import sss_jax as sj


@pytest.mark.parametrize("d_mm", [1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0, 1e3])
def test_burley_normalised(d_mm):
    # Christensen & Burley 2015: integral_0^inf R(r) 2 pi r dr = 1 for every d > 0. Independent check: SciPy quad of
    # the profile in the scaled variable x = r/d (the 1/r peak cancels against 2 pi r).
    f = lambda x: float(sj.burley_R(jnp.float64(x * d_mm), jnp.float64(d_mm))) * 2 * math.pi * x * d_mm * d_mm
    total = si.quad(f, 0, 10)[0] + si.quad(f, 10, 200)[0]
    assert abs(total - 1.0) < 1e-6


def test_burley_closed_form_values():
    # R(r) = (exp(-r/d) + exp(-r/3d)) / (8 pi d r), evaluated by hand in NumPy
    r, d = np.array([0.1, 1.0, 5.0]), 2.0
    expected = (np.exp(-r / d) + np.exp(-r / (3 * d))) / (8 * np.pi * d * r)
    np.testing.assert_allclose(np.asarray(sj.burley_R(jnp.asarray(r), d)), expected, rtol=1e-12)


@pytest.mark.parametrize("d_mm", [0.01, 1.0, 300.0])
def test_cdf_matches_quadrature_and_inverts(d_mm):
    for r in [0.3 * d_mm, 2 * d_mm, 9 * d_mm]:
        f = lambda s: float(sj.burley_R(jnp.float64(s), jnp.float64(d_mm))) * 2 * math.pi * s
        expected = si.quad(f, 0, r, limit=200)[0]
        assert float(sj.burley_cdf(jnp.float64(r), d_mm)) == pytest.approx(expected, rel=1e-7)
    u = jnp.asarray([1e-6, 0.01, 0.3, 0.5, 0.9, 0.999, 1 - 1e-9])
    r = sj.burley_inverse_cdf(u, d_mm)
    np.testing.assert_allclose(np.asarray(sj.burley_cdf(r, d_mm)), np.asarray(u), rtol=1e-9, atol=1e-12)


def test_inverse_ccdf_is_stable_in_the_tail():
    # CCDF(r) = (y^3 + 3y)/4 with y = exp(-r/3d); for tiny v the root is y ~ 4v/3, so r ~ -3 d log(4v/3)
    v = jnp.asarray([1e-30, 1e-200])
    r = sj.burley_inverse_ccdf(v, 1.0)
    np.testing.assert_allclose(np.asarray(r), -3 * np.log(4 * np.asarray(v) / 3), rtol=1e-12)


def test_scaling_fits_by_hand():
    # Christensen & Burley 2015, Sec. 3: the three fits, at A = 0.5
    assert float(sj.scaling_searchlight(0.5)) == pytest.approx(1.85 - 0.5 + 7 * 0.3**3)
    assert float(sj.scaling_diffuse_transmission(0.5)) == pytest.approx(1.9 - 0.5 + 3.5 * 0.09)
    assert float(sj.scaling_diffuse_mfp(0.5)) == pytest.approx(3.5 + 100 * 0.17**4)
    assert float(sj.d_from_mfp(0.5, 2.0)) == pytest.approx(2.0 / (1.9 - 0.5 + 3.5 * 0.09))
    with pytest.raises(ValueError, match="fit='nope' is not one of"):
        sj.d_from_mfp(0.5, 1.0, fit="nope")


def test_preintegrated_kernel_is_bessel_k0():
    # integral R(sqrt(x^2+y^2)) dy of exp(-r/d)/r is 2 K0(|x|/d): a_p(x) = (K0(|x|/d) + K0(|x|/3d)) / (4 pi d)
    d = np.array([0.5, 1.0, 2.0])
    p = sj.BurleyProfile(jnp.asarray(d))
    x = np.array([0.01, 0.1, 1.0, 3.0, 10.0])
    expected = (sp.k0(x[:, None] / d) + sp.k0(x[:, None] / (3 * d))) / (4 * np.pi * d)
    np.testing.assert_allclose(np.asarray(sj.preintegrate(p, jnp.asarray(x))), expected, rtol=1e-6)


@pytest.mark.parametrize("profile", ["burley", "deon"])
def test_eq2_energy_identity(profile):
    # The paper's Eq. 2: ||a_p||_1 = ||R||_1 (= 1 for normalised profiles). Independent: SciPy quad of a_p over x.
    p = sj.BurleyProfile(jnp.asarray([0.7, 1.3, 2.1])) if profile == "burley" else sj.GaussianSumProfile.deon_skin(jnp.float64)
    pre = jax.jit(lambda x: sj.preintegrate(p, x))
    for c in range(3):
        f = lambda x: float(pre(jnp.asarray([x]))[0, c])
        scale = float(p.radius_for_energy(0.5)[c])
        total = 2 * (si.quad(f, 0, scale, limit=200)[0] + si.quad(f, scale, 80 * scale, limit=200)[0])
        assert total == pytest.approx(1.0, abs=2e-4)


def test_gaussian_sum_against_formula():
    # d'Eon 2007 six-Gaussian skin: R(r) = sum w_k exp(-r^2/2v_k)/(2 pi v_k), normalised by sum w_k
    p = sj.GaussianSumProfile.deon_skin(jnp.float64)
    v = np.array([0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41])
    w = np.array([[0.233, 0.455, 0.649], [0.100, 0.336, 0.344], [0.118, 0.198, 0.0],
                  [0.113, 0.007, 0.007], [0.358, 0.004, 0.0], [0.078, 0.0, 0.0]])
    r = 0.8
    expected = (w * (np.exp(-r * r / (2 * v)) / (2 * np.pi * v))[:, None]).sum(0) / w.sum(0)
    np.testing.assert_allclose(np.asarray(p.radial(jnp.asarray([r])))[0], expected, rtol=1e-10)
    u = jnp.asarray([0.25, 0.5, 0.9])
    r = p.inverse_cdf(u)
    got = np.stack([np.asarray(p.cdf(r[:, c]))[:, c] for c in range(3)], -1)
    np.testing.assert_allclose(got, np.repeat(np.asarray(u)[:, None], 3, 1), atol=1e-9)


def test_tabulated_profile_reproduces_burley():
    d = jnp.asarray([1.0, 2.0, 3.0])
    burley = sj.BurleyProfile(d, jnp.asarray([0.6, 0.7, 0.8]))
    r = np.linspace(0.05, 60.0, 3000)
    table = sj.TabulatedProfile(r, np.asarray(burley.physical(jnp.asarray(r))))
    # the total reflectance of the table is A up to the 1/r peak below the first bin (~R(r0) pi r0^2 vs CDF(r0))
    np.testing.assert_allclose(np.asarray(table.albedo), [0.6, 0.7, 0.8], rtol=0.02)
    # its normalised CDF matches Burley's away from the peak
    q = jnp.asarray([2.0, 6.0, 15.0])
    np.testing.assert_allclose(np.asarray(table.cdf(q)), np.asarray(burley.cdf(q)), atol=0.01)
    mid = table.inverse_cdf(jnp.asarray([0.5]))
    np.testing.assert_allclose(np.asarray(mid)[0], np.asarray(burley.inverse_cdf(jnp.asarray([0.5])))[0], rtol=0.06)


def test_tabulated_rejects_bad_tables():
    with pytest.raises(ValueError, match="strictly increasing"):
        sj.TabulatedProfile([0.0, 2.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="non-negative"):
        sj.TabulatedProfile([0.0, 1.0], [1.0, -1.0])


def test_profile_gradients_finite_at_limits():
    check_grads(lambda d: sj.burley_cdf(jnp.float64(1.3), d), (jnp.float64(0.7),), order=2, modes=["rev"])
    g = jax.grad(lambda d: jnp.sum(sj.burley_R(jnp.asarray([0.0, 1.0, 1e9]), d)))(jnp.float64(0.0))
    assert np.isfinite(float(g))
    g = jax.grad(lambda d: sj.burley_inverse_ccdf(jnp.float64(1e-20), d))(jnp.float64(2.0))
    assert np.isfinite(float(g))


def test_float32_tail_is_finite():
    # in float32, 1 - (1 - 1e-9) is 0: the inverse CCDF must floor v where asinh(2v)/3 is still a normal number
    # (a subnormal is flushed to zero on CPU and log(0) would give r = inf)
    r = sj.burley_inverse_ccdf(jnp.float32(0.0), jnp.float32(2.0))
    assert np.isfinite(float(r)) and float(r) > 100 * 2.0
    p = sj.BurleyProfile(jnp.asarray([3.0, 1.4, 0.8], jnp.float32))
    ap = np.asarray(sj.preintegrate(p, jnp.asarray([0.1, 1.0, 4.0], jnp.float32)))
    assert np.all(np.isfinite(ap)) and np.all(ap > 0)


def test_marginal_half_mass_is_the_exact_marginal_at_every_scale():
    # the 1D marginal's mass over [0, x], against formulas: Burley's marginal density (K0(|x|/d) + K0(|x|/3d)) /
    # (4 pi d) by scipy quadrature; a Gaussian sum's marginal is the same sum of 1D Gaussians, erf(x / (sigma
    # sqrt 2)) / 2 each. From 1e-6 d (where marginal_cdf's 2048 quantiles no longer resolve it) to 30 d.
    from sss_jax._profiles import marginal_half_mass
    x = np.array([1e-6, 1e-3, 0.05, 0.7, 3.0, 30.0])
    d = np.array([1.0, 0.0, 2.5])
    got = np.asarray(marginal_half_mass(sj.BurleyProfile(jnp.asarray(d)), jnp.asarray(x)))
    density = lambda t, dc: (sp.k0(t / dc) + sp.k0(t / (3 * dc))) / (4 * math.pi * dc)
    exact = np.array([[0.5 if dc == 0 else si.quad(density, 0, xx, args=(dc,), limit=400, epsabs=1e-15,
                                                     epsrel=1e-13)[0] for dc in d] for xx in x])
    np.testing.assert_allclose(got, exact, rtol=1e-9, atol=1e-12)  # the rule: ~1e-13 of the whole mass
    w, v = np.array([[0.3, 1.0, 0.5], [0.7, 0.0, 0.5]]), np.array([[0.25, 1.0, 4.0], [9.0, 1.0, 0.01]])
    got = np.asarray(marginal_half_mass(sj.GaussianSumProfile(jnp.asarray(w), jnp.asarray(v)), jnp.asarray(x)))
    exact = np.array([[sum(w[k, c] * math.erf(xx / math.sqrt(2 * v[k, c])) / 2 for k in range(2)) / w[:, c].sum()
                       for c in range(3)] for xx in x])
    np.testing.assert_allclose(got, exact, rtol=1e-9, atol=1e-12)  # the rule: ~1e-13 of the whole mass
def test_the_pre_integrated_kernels_taps_are_the_exact_masses_of_the_marginal_over_their_cells():
    # each tap of separable_kernel_from_profile against the 1D marginal's mass over its cell, from Burley's marginal
    # density (K0(|x|/d) + K0(|x|/3d)) / (4 pi d) by scipy quadrature (cells half way between the taps, the outer
    # ones to infinity). Before: differences of marginal_cdf's 2048 quantiles, off by up to 2.7e-5 (skin).
    d = np.array([3.0, 1.4, 0.8])
    density = lambda t, dc: (sp.k0(abs(t) / dc) + sp.k0(abs(t) / (3 * dc))) / (4 * math.pi * dc)
    mass = lambda a, b, dc: si.quad(density, a, b, args=(dc,), points=[0.0] if a < 0 < b else None, limit=400,
                                    epsabs=1e-15, epsrel=1e-12)[0]
    for taps in (7, 25):
        k = sj.separable_kernel_from_profile(sj.BurleyProfile(jnp.asarray(d)), taps=taps)
        offsets, weights = np.asarray(k.offsets_mm), np.asarray(k.weights)
        order = np.argsort(offsets)
        mids = 0.5 * (offsets[order][1:] + offsets[order][:-1])
        bounds = np.concatenate([[-np.inf], mids, [np.inf]])
        exact = np.array([[mass(max(bounds[i], -300 * dc), min(bounds[i + 1], 300 * dc), dc) for dc in d]
                          for i in range(taps)])
        np.testing.assert_allclose(weights[order], exact, rtol=1e-9, atol=1e-12)
        # float32: the same to its rounding
        k32 = sj.separable_kernel_from_profile(sj.BurleyProfile(jnp.asarray(d, jnp.float32)), taps=taps)
        assert np.abs(np.asarray(k32.weights)[order] - exact).max() < 5e-7




def test_tabulated_inverse_cdf_inverts_the_tables_own_cdf_everywhere():
    # it interpolated on a linspace grid that held none of the knots: 3.6% off at a knot and ~1.8x too small below
    # the first sample (where R is held constant, so the CDF is pi r^2 R0 / total: quadratic). Independent check:
    # the table's model (constant below r0, linear between samples, 0 beyond) integrated by NumPy on a fine grid
    r_k, R_k = np.array([0.5, 0.6, 3.0, 10.0]), np.array([1.0, 0.9, 0.1, 0.001])
    t = sj.TabulatedProfile(r_k, R_k)
    grid = np.linspace(0.0, 10.0, 2_000_001)
    R = np.interp(grid, r_k, R_k, left=R_k[0])
    cdf = si.cumulative_trapezoid(2 * np.pi * grid * R, grid, initial=0.0)
    cdf /= cdf[-1]
    u = np.array([1e-4, 0.01, float(np.interp(0.6, grid, cdf)), 0.3, 0.5, 0.9, 0.999])
    want = np.interp(u, cdf, grid)
    np.testing.assert_allclose(np.asarray(t.inverse_cdf(jnp.asarray(u)))[:, 0], want, rtol=1e-5)
    # below the first sample: r = r0 sqrt(u / CDF(r0)) (written out)
    c0 = np.pi * 0.25 * 1.0 / si.trapezoid(2 * np.pi * grid * R, grid)
    np.testing.assert_allclose(float(t.inverse_cdf(jnp.asarray([0.01]))[0, 0]), 0.5 * np.sqrt(0.01 / c0), rtol=1e-5)


def test_profile_and_kernel_builders_refuse_what_they_cannot_build(as_users_run_it):
    # each returned a plausible result (negative or unnormalised weights, NaN read as 0 or 1, albedo 2) or failed
    # later inside a jitted pass
    p = sj.BurleyProfile(jnp.array([0.5, 1.0, 2.0]))
    cases = [
        (lambda: sj.separable_kernel_from_profile(p, range_mm=-1.0), "range_mm must be finite and >= 0"),
        (lambda: sj.two_gaussian_kernel([0.5] * 3, [0.1] * 3, [1.0] * 3, range_mm=-1.0), "range_mm must be"),
        (lambda: sj.two_gaussian_kernel([0.5] * 3, [np.nan] * 3, [1.0] * 3), "sigma_near_mm must be finite"),
        (lambda: sj.two_gaussian_kernel([0.5] * 3, [0.1] * 3, [np.inf] * 3), "sigma_far_mm must be finite"),
        (lambda: sj.two_gaussian_kernel([2.0] * 3, [0.1] * 3, [1.0] * 3), r"w must be finite and >= 0 and <= 1"),
        (lambda: sj.tap_offsets(5, np.inf), "range_mm must be finite"),
        (lambda: sj.tap_offsets(5, 1.0, exponent=-1.0), "exponent must be finite and > 0"),
        (lambda: sj.tap_offsets(5, 1.0, exponent=0.0), "exponent must be finite and > 0"),
        (lambda: sj.BurleyProfile([np.nan, 1.0, 1.0]), "d_mm must be finite and >= 0"),
        (lambda: sj.BurleyProfile([1.0] * 3, [2.0] * 3), "albedo must be finite and >= 0 and <= 1"),
        (lambda: sj.BurleyProfile.from_mfp([1.5, 0.5, 0.5], [1, 1, 1]), "albedo must be"),
        (lambda: sj.GaussianSumProfile([[1.0, 1.0, 1.0]], [np.nan]), "variances_mm2 must be finite"),
        (lambda: sj.GaussianSumProfile([[-1.0, 1, 1], [2.0, 0, 0]], [1.0, 2.0]), "weights must be finite and >= 0"),
        (lambda: sj.d_from_mfp(2.0, 1.0), "albedo must be"),
        (lambda: sj.d_from_mfp(0.5, -1.0), "mfp_mm must be finite and >= 0"),
        (lambda: sj.preintegrate(p, 1.0, segments=0), "segments must be a positive integer"),
        (lambda: sj.marginal_cdf(p, 1.0, quantiles=1.5), "quantiles must be a positive integer"),
        (lambda: sj.marginal_cdf(p, 1.0, quantiles=True), "quantiles must be a positive integer"),
        (lambda: sj.spiral_samples(3, dtype=jnp.float16), "dtype must be float32 or float64"),
        (lambda: sj.TwoGaussianMaterial([0.5] * 3, [0.5] * 3, [0.1] * 3, [np.inf] * 3), "sigma_far_mm must be finite"),
        (lambda: sj.px_per_mm(2.0, focal_px=-1.0, mm_per_unit=1.0), "focal_px must be finite and > 0"),
        (lambda: sj.px_per_mm(2.0, focal_px=1.0, mm_per_unit=0), "mm_per_unit must be finite and > 0"),
    ]
    for make, message in cases:
        with pytest.raises(ValueError, match=message):
            make()
    with jax.enable_x64(False):  # stored as float32: an overflow and collapsed radii were kept
        with pytest.raises(ValueError, match="R overflows float32"):
            sj.TabulatedProfile([0.0, 1.0], [1e39, 1e39])
        with pytest.raises(ValueError, match="strictly increasing in float32"):
            sj.TabulatedProfile([0.0, 1e-46, 1.0], [1.0, 1.0, 1.0])
    # a_p(inf) is 0 (it was NaN)
    np.testing.assert_array_equal(np.asarray(sj.preintegrate(p, jnp.asarray([np.inf])))[0], 0.0)


def test_lengths_in_pixels_keep_a_fractional_camera_with_an_integer_depth():
    # an integer depth cast focal_px and mm_per_unit to integers: 0.5 -> 0 gave inf px/mm, 1000.7 -> 1000
    # px = L / mm_per_unit * focal_px / depth (the module's formula, written out)
    assert float(sj.px_per_mm(2, focal_px=1000.0, mm_per_unit=0.5)) == pytest.approx(1000.0 / (2 * 0.5))
    assert float(sj.mm_to_px(1.0, 3, focal_px=1000.7, mm_per_unit=1000.0)) == pytest.approx(1000.7 / 3000.0,
                                                                                          rel=1e-6)


def _burley_cdf_root(u: float) -> float:
    """The radius (units of d) holding the fraction u of Burley's energy, by bisection on its CDF written with
    math.expm1 (``1 - exp(-x)/4 - 3 exp(-x/3)/4``, Christensen & Burley 2015) in float64: not the code under test."""
    cdf = lambda x: -math.expm1(-x) / 4 - 3 * math.expm1(-x / 3) / 4
    lo, hi = 0.0, 200.0
    while True:
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            return mid
        lo, hi = (mid, hi) if cdf(mid) < u else (lo, mid)


@pytest.mark.parametrize("u", [1e-30, 1e-20, 1e-12, 1e-8, 1e-6, 1e-4, 0.01, 0.3, 0.49, 0.51, 0.9, 0.99])
def test_burley_inverse_cdf_keeps_its_relative_precision_for_small_u(u):
    # it was burley_inverse_ccdf(1 - u): 1 - u rounds, so float32 gave one radius for every u <= 1e-8 (u = 1e-6 off
    # by 25%, u = 1e-20 by 9e12 in float32 and 1.7e4 in float64); and the pass's truncated sampling took -3 log(1 - s),
    # which rounds the same way (radius 0 below u ~ 1e-8 in float32, 1.7% off at 1e-6)
    from sss_jax._techniques._burley_spec import unit_radius_for_cdf

    r = _burley_cdf_root(u)
    np.testing.assert_allclose(float(sj.burley_inverse_cdf(np.float64(u), 2.0)), 2 * r, rtol=1e-13)
    with jax.enable_x64(False):
        # float32: the closed form near u = 1 is conditioned like 1/(1 - u), a few ulps of it
        tol = 2e-7 if u < 0.5 else 1e-6
        np.testing.assert_allclose(float(sj.burley_inverse_cdf(np.float32(u), np.float32(2.0))), 2 * r, rtol=tol)
        np.testing.assert_allclose(float(unit_radius_for_cdf(jnp.float32(u))), r, rtol=tol)


def test_a_bisected_radius_follows_the_profiles_shape():
    # GaussianSumProfile and TabulatedProfile invert their CDF by bisection, whose derivative moved only with its
    # bracket: d radius_for_energy(0.99) / d weights was 0 (central differences: 0.78), and a separable kernel built
    # from such a profile (its reach) had the wrong gradient in the profile's weights (found by a review). Truth:
    # central differences of the same float64 functions
    import equinox as eqx

    def fd(f, x, e, h):
        return (float(f(x + h * e)) - float(f(x - h * e))) / (2 * h)

    w0 = jnp.asarray([[0.6, 0.5, 0.4], [0.4, 0.5, 0.6]])
    v0 = jnp.asarray([[0.2, 0.1, 0.05], [2.0, 1.0, 0.5]])
    radius = lambda w, v: jnp.sum(sj.GaussianSumProfile(w, v).radius_for_energy(0.99) * jnp.asarray([1.0, 2.0, 3.0]))
    for arg, x in ((0, w0), (1, v0)):
        f = (lambda x: radius(x, v0)) if arg == 0 else (lambda x: radius(w0, x))
        g = jax.grad(f)(x)
        for k, c in ((0, 0), (1, 0), (1, 2)):
            e = jnp.zeros_like(x).at[k, c].set(1.0)
            assert float(g[k, c]) == pytest.approx(fd(f, x, e, 1e-6), rel=1e-5, abs=1e-9), (arg, k, c)
    u_grad = jax.grad(lambda u: sj.GaussianSumProfile(w0, v0).inverse_cdf(u)[0])(jnp.asarray(0.7))
    assert float(u_grad) == pytest.approx(fd(lambda u: sj.GaussianSumProfile(w0, v0).inverse_cdf(u)[0],
                                              jnp.asarray(0.7), 1.0, 1e-6), rel=1e-5)

    rr = jnp.linspace(0.05, 8.0, 40)
    R0 = jnp.stack([jnp.exp(-rr / s) / rr for s in (1.5, 0.8, 0.4)], -1)
    table = sj.TabulatedProfile(rr, R0)  # built from host arrays: the table traced by replacing R
    tab = lambda R: jnp.sum(eqx.tree_at(lambda p: p.R, table, R).radius_for_energy(0.9))
    g = jax.grad(tab)(R0)
    for k in (5, 25):
        e = jnp.zeros_like(R0).at[k, 0].set(float(R0[k, 0]))
        assert float(jnp.vdot(g, e)) == pytest.approx(fd(tab, R0, e, 1e-6), rel=1e-4)

    rng = np.random.default_rng(3)
    b = sj.Buffers(irradiance=jnp.asarray(rng.uniform(0.2, 1.0, (10, 10, 3))), depth=jnp.full((10, 10), 1.0))
    cam, wt = sj.Camera(20.0, 10.0), jnp.asarray(rng.normal(size=(10, 10, 3)))
    sep = lambda w: jnp.sum(sj.separable(b, sj.ProfileMaterial(sj.GaussianSumProfile(w, v0), albedo=(0.8, 0.6, 0.5)),
                                         cam, taps=9) * wt)
    g = jax.grad(sep)(w0)
    for k in (0, 1):
        e = jnp.zeros_like(w0).at[k, 0].set(1.0)
        assert float(g[k, 0]) == pytest.approx(fd(sep, w0, e, 1e-6), rel=1e-4)
