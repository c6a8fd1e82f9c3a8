"""The random walk against physics it did not produce: energy conservation, the single-scattering integral,
Chandrasekhar's H-function, the diffusion limit, Fresnel."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax._montecarlo import _hg_cos, fresnel_unpolarised, simulate, to_tabulated_profile
from sss_jax.cli import main

FAST = dict(lanes=4096, bins=50, r_max_mfp=10.0)


def chandrasekhar_h(albedo: float, mu: np.ndarray, nodes: int = 200) -> np.ndarray:
    """Chandrasekhar's H-function for isotropic scattering (Radiative Transfer, 1950, ch. V), solved by fixed-point
    iteration of its alternative form ``1/H(mu) = sqrt(1 - a) + (a/2) int_0^1 mu' H(mu') / (mu + mu') dmu'``
    (damped, it converges in ~50 steps even for a = 1) on Gauss-Legendre nodes, then evaluated at ``mu``."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    m, wm = 0.5 * (x + 1), 0.5 * w
    root = math.sqrt(max(1 - albedo, 0.0))
    h = np.ones_like(m)
    for _ in range(5000):
        new = 0.5 * h + 0.5 / (root + 0.5 * albedo * np.sum(wm * m * h / (m[:, None] + m), axis=1))
        if np.max(np.abs(new - h)) < 1e-13:
            break
        h = new
    mu = np.atleast_1d(mu)
    return 1 / (root + 0.5 * albedo * np.sum(wm * m * h / (mu[:, None] + m), axis=1))


def test_h_function_solver_against_published_value():
    # Chandrasekhar's table for conservative isotropic scattering: H(1) = 2.9078; and his moment identity
    # int_0^1 H dmu = (2/a)(1 - sqrt(1 - a))
    assert chandrasekhar_h(1.0, np.array([1.0]))[0] == pytest.approx(2.9078, abs=2e-4)
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1)
    for a in (0.5, 0.9):
        assert np.sum(0.5 * w * chandrasekhar_h(a, mu)) == pytest.approx(2 / a * (1 - math.sqrt(1 - a)), rel=1e-8)


def test_energy_is_conserved_without_absorption():
    # albedo 1, index-matched, semi-infinite: every photon leaves through the top. About 3% of them are still inside
    # after 3000 scatterings (a half-space walk returns after n steps with probability ~ n^-1/2); they are certain to
    # leave and are tallied as reflected, none is dropped
    r = simulate(1.0, photons=20_000, max_events=3000, seed=1, **FAST)
    assert r.total_reflectance == pytest.approx(1.0, abs=1e-5)
    assert r.capped_photons == 0 and r.capped_weight == 0.0
    # a slab with a dielectric boundary: specular + reflected + transmitted + capped = 1 (the cap is counted, so any
    # max_events balances; the lanes, bins and cap of the stability sweep's walks, whose compiled slab walk this shares)
    s = simulate(1.0, photons=20_000, eta=1.4, slab_mfp=1.5, max_events=500, seed=2, lanes=256, bins=8, r_max_mfp=4.0)
    total = s.specular_reflectance + s.total_reflectance + s.total_transmittance + s.capped_weight
    assert total == pytest.approx(1.0, abs=1e-4)
    assert s.specular_reflectance == pytest.approx((0.4 / 2.4) ** 2)


@pytest.fixture(scope="module")
def half_albedo():
    return simulate(0.5, photons=200_000, seed=3, **FAST)


def test_single_scattering_matches_the_analytic_integral(half_albedo):
    # normal incidence, first scatter at depth tau ~ Exp(1), isotropic, escapes along mu with prob. exp(-tau/mu):
    # R1 = a int_0^inf e^-tau int_0^1 (1/2) e^(-tau/mu) dmu dtau = (a/2) int_0^1 mu/(1+mu) dmu = (a/2)(1 - ln 2)
    r = half_albedo
    expected = 0.5 / 2 * (1 - math.log(2))
    assert abs(r.single_scatter_reflectance - expected) < 4 * r.single_scatter_reflectance_stderr + 1e-6


def test_total_reflectance_matches_chandrasekhar(half_albedo):
    # plane albedo of a semi-infinite isotropic medium at normal incidence: 1 - H(1) sqrt(1 - a)
    for r in (half_albedo, simulate(0.9, photons=100_000, seed=4, **FAST)):
        expected = 1 - chandrasekhar_h(r.albedo, np.array([1.0]))[0] * math.sqrt(1 - r.albedo)
        assert abs(r.total_reflectance - expected) < 4 * r.total_reflectance_stderr, (r.albedo, expected)


def test_diffusion_limit_for_high_albedo():
    # Jensen et al. 2001 (eq. for total diffuse reflectance of the dipole, index-matched A = 1):
    # Rd = (a/2)(1 + exp(-4/3 sqrt(3(1-a)))) exp(-sqrt(3(1-a))). Diffusion theory is an approximation: near a = 1
    # it agrees with transport to a few percent (Jensen et al., Fig. 4), so the tolerance is 3% (the MC's own
    # standard error is ~0.15% here)
    a = 0.99
    r = simulate(a, photons=50_000, seed=5, **FAST)
    s = math.sqrt(3 * (1 - a))
    dipole = a / 2 * (1 + math.exp(-4 / 3 * s)) * math.exp(-s)
    assert r.total_reflectance == pytest.approx(dipole, rel=0.03)
    assert r.total_reflectance_stderr < 0.005


def test_profile_bins_add_up_and_have_errors(half_albedo):
    r = half_albedo
    area = math.pi * (r.bin_edges_mfp[1:] ** 2 - r.bin_edges_mfp[:-1] ** 2)
    inside = float(np.sum(r.R * area))
    assert inside <= r.total_reflectance + 1e-9 and inside > 0.95 * r.total_reflectance
    assert np.all(r.R_stderr >= 0) and np.all(r.R_stderr[:10] > 0)
    assert r.R[0] > r.R[10] > r.R[30]  # the profile falls off with radius


def test_henyey_greenstein_sampling_mean_cosine():
    # <cos theta> of the Henyey-Greenstein phase function is g
    import jax

    u = jax.random.uniform(jax.random.PRNGKey(0), (400_000,))
    for g in (-0.5, 0.0, 0.3, 0.9):
        assert float(jnp.mean(_hg_cos(u, g))) == pytest.approx(g, abs=3e-3)


def test_fresnel_by_hand():
    # normal incidence ((n1-n2)/(n1+n2))^2; total internal reflection beyond asin(1/1.4) from inside
    assert float(fresnel_unpolarised(1.0, 1.0, 1.4)) == pytest.approx((0.4 / 2.4) ** 2, rel=1e-6)
    assert float(fresnel_unpolarised(math.cos(math.radians(50)), 1.4, 1.0)) == 1.0
    # 45 degrees from air into n = 1.5: Rs = 0.0920, Rp = 0.0085 (textbook values), mean 0.0503
    assert float(fresnel_unpolarised(math.cos(math.pi / 4), 1.0, 1.5)) == pytest.approx(0.0503, abs=3e-4)


def test_reproducible_from_a_seed():
    a = simulate(0.8, photons=5000, seed=7, **FAST)
    b = simulate(0.8, photons=5000, seed=7, **FAST)
    c = simulate(0.8, photons=5000, seed=8, **FAST)
    np.testing.assert_array_equal(a.R, b.R)
    assert a.total_reflectance == b.total_reflectance != c.total_reflectance


@pytest.mark.parametrize("kw, message", [
    # PRNGKey keeps a seed's low 32 bits: before, 2^32 gave seed 0's photons (and -1 seed 2^32 - 1's) while the
    # result recorded the seed as given; a seed past 64 bits was an OverflowError traceback
    ({"seed": 2**32}, "seed must be an integer in"), ({"seed": -1}, "seed must be an integer in"),
    ({"seed": 10**23}, "seed must be an integer in"),
    # the cap was named after an internal argument (max_events_hard), not the flag a user gave
    ({"max_events": 3_000_000_000}, "max_events must be an integer from 1 to 2"),
])
def test_out_of_range_seeds_and_caps_are_refused(kw, message):
    with pytest.raises(ValueError, match=message):
        simulate(0.8, photons=10, **kw)


def test_batches_stream_with_bounded_lanes():
    # 3 calls of 4096 photons each through 1024 lanes: the same physics as one big call, to the statistical error
    small = simulate(0.7, photons=12_288, seed=9, lanes=1024, batch_photons=4096, bins=50, r_max_mfp=10.0)
    big = simulate(0.7, photons=12_288, seed=10, lanes=4096, bins=50, r_max_mfp=10.0)
    err = math.hypot(small.total_reflectance_stderr, big.total_reflectance_stderr)
    assert abs(small.total_reflectance - big.total_reflectance) < 4 * err


def test_tabulated_profile_holds_the_histograms_energy(half_albedo):
    # the bins' averages read as values at their centres over-integrated the peak at r = 0 (2.5-4% more energy than
    # the photons left); the TabulatedProfile's docstring: R "integrates to the total reflectance". The histogram's
    # energy, sum_i R_i pi (e_{i+1}^2 - e_i^2) in mean free paths, is independent of the mfp in mm
    held = float(np.sum(half_albedo.R * np.pi * np.diff(half_albedo.bin_edges_mfp ** 2)))
    for mfp in (1.0, 2.5):
        np.testing.assert_allclose(np.asarray(to_tabulated_profile(half_albedo, mfp).albedo), held, rtol=1e-9)
    with pytest.raises(ValueError, match="mfp_mm must be finite and > 0"):
        to_tabulated_profile(half_albedo, 0.0)


def test_tabulated_profile_feeds_the_techniques(half_albedo):
    prof = to_tabulated_profile([half_albedo] * 3, [1.0, 2.0, 3.0])
    assert prof.num_channels == 3
    np.testing.assert_allclose(np.asarray(prof.albedo), half_albedo.total_reflectance, rtol=0.06)
    mat = sj.ProfileMaterial(prof, albedo=jnp.full(3, 0.5))
    b = sj.Buffers(irradiance=jnp.ones((6, 6, 3)), depth=jnp.full((6, 6), 10.0))
    # 2x2 sub-pixel rule near the centre (as in tests/test_techniques.py): normalised weights keep a flat image flat
    # for any rule, and the table's profile is evaluated on the same path, at a fraction of the compile time
    # (the kernel renormalised at the frame's edge: light leaving the frame would darken the border pixels)
    out = sj.reference(b, mat, sj.Camera(20.0, 1.0), radius_px=3, near_subsamples=2, border="renormalise")
    np.testing.assert_allclose(np.asarray(out), 0.5, rtol=1e-6)  # flat stays flat, times the albedo


def test_cli_writes_json_and_rejects_bad_input(tmp_path, capsys):
    # 4096 photons fill the default 4096 lanes: the slab run below shares its compiled walk with
    # tests/test_engines.py's slab transmission (same lanes, bins and flags)
    out = tmp_path / "mc.json"
    assert main(["montecarlo", "--albedo", "0.8", "--photons", "4096", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    for key in ("total_reflectance", "total_reflectance_stderr", "photons", "seed"):
        assert key in data
    assert len(data["profile"]["r_mfp"]) == len(data["profile"]["rR"]) == len(data["profile"]["rR_stderr"])
    assert main(["montecarlo", "--albedo", "0.8", "--photons", "4096", "--slab-mm", "2", "--json", str(out)]) == 0
    assert "total_transmittance" in json.loads(out.read_text())
    for argv, message in [(["--albedo", "1.5"], r"albedo must lie in \[0, 1\]"), (["--albedo", "0.5", "--g", "1"], "g must"),
                          (["--albedo", "0.5", "--eta", "0.5"], "eta must"), (["--albedo", "0.5", "--photons", "0"], "photons must")]:
        args = ["montecarlo", "--photons", "100"] + argv + ["--json", str(tmp_path / "bad.json")]
        assert main(args) == 2
        assert __import__("re").search(message, capsys.readouterr().err)
        assert not (tmp_path / "bad.json").exists()


def test_azimuth_polynomials_against_numpy():
    # cos/sin of 2 pi u with u from the top 25 bits, against NumPy's float64 cos/sin of the same angle
    import jax

    from sss_jax._montecarlo import _cos_sin_turn

    bits = np.random.default_rng(0).integers(0, 2**32, 1 << 16, dtype=np.uint64).astype(np.uint32)
    c, s = (np.asarray(v, np.float64) for v in jax.jit(_cos_sin_turn)(jnp.asarray(bits)))
    phi = 2 * np.pi * (bits >> 7).astype(np.float64) / 2**25
    np.testing.assert_allclose(c, np.cos(phi), atol=3e-7)
    np.testing.assert_allclose(s, np.sin(phi), atol=3e-7)


def test_generator_matches_the_published_xoroshiro64star():
    # Blackman & Vigna's reference C code (prng.di.unimi.it/xoroshiro64star.c), transcribed to Python integers
    from sss_jax._montecarlo import _xoroshiro_next

    def reference(s0, s1, n):
        out, mask = [], 0xFFFFFFFF
        for _ in range(n):
            out.append((s0 * 0x9E3779BB) & mask)
            s1 ^= s0
            s0 = (((s0 << 26) | (s0 >> 6)) & mask) ^ s1 ^ ((s1 << 9) & mask)
            s1 = ((s1 << 13) | (s1 >> 19)) & mask
        return out

    seeds = [(1, 2), (0xDEADBEEF, 0x12345678), (0xFFFFFFFF, 0)]
    s0 = jnp.asarray([a for a, _ in seeds], jnp.uint32)
    s1 = jnp.asarray([b for _, b in seeds], jnp.uint32)
    got = []
    for _ in range(20):
        out, s0, s1 = _xoroshiro_next(s0, s1)
        got.append(np.asarray(out))
    for lane, (a, b) in enumerate(seeds):
        assert [int(g[lane]) for g in got] == reference(a, b, 20)


def test_numbers_do_not_depend_on_the_thread_count():
    # three batches (so two threads do run side by side) in FAST's lanes and bins: the walk compiled for the other
    # tests at albedo >= 0.8 serves this one too
    kw = dict(photons=3 * 4096, seed=12, batch_photons=4096, **FAST)
    one, two = simulate(0.8, workers=1, **kw), simulate(0.8, workers=2, **kw)
    np.testing.assert_array_equal(one.R, two.R)
    assert one.scattering_events == two.scattering_events


def test_henyey_greenstein_single_scattering_and_diffuse_energy():
    # HG single scattering at normal incidence: the first scatter at depth tau ~ Exp(1) sends the photon back up at
    # cosine mu with density p(-mu), p(c) = (1 - g^2) / (2 (1 + g^2 - 2 g c)^(3/2)); it escapes with prob. exp(-tau/mu):
    # R1 = a int_0^1 p(-mu) mu / (1 + mu) dmu (integrated here with Gauss-Legendre, independently of the walk)
    a, g = 0.6, 0.5
    r = simulate(a, photons=100_000, g=g, seed=13, **FAST)
    x, w = np.polynomial.legendre.leggauss(200)
    mu = 0.5 * (x + 1)
    p = (1 - g * g) / (2 * (1 + g * g + 2 * g * mu) ** 1.5)
    expected = a * np.sum(0.5 * w * p * mu / (1 + mu))
    assert abs(r.single_scatter_reflectance - expected) < 4 * r.single_scatter_reflectance_stderr
    # diffuse incidence through an index-matched slab without absorption: everything leaves one side or the other
    d = simulate(1.0, photons=20_000, g=0.8, slab_mfp=2.0, incidence="diffuse", max_events=3000, seed=14, **FAST)
    assert d.total_reflectance + d.total_transmittance + d.capped_weight == pytest.approx(1.0, abs=1e-4)


# --- the event cap: no photon is dropped, and what crosses it is counted without bias -------------------------------
# With a cap of a few hundred scatterings a large share of the photons of a nearly conservative medium crosses it
# (~5% at 1000 for an index-matched half-space, more with the eta 1.3 boundary's internal reflection), where their
# weight is still far above the roulette's 1e-3: dropping them, as the walk did before, was a bias of several percent.


def test_cap_is_unbiased_against_chandrasekhar():
    # albedo 0.9999, index-matched half-space, pencil beam: plane albedo 1 - H(1) sqrt(1 - a) (Chandrasekhar 1960,
    # Ch. V; H solved above, independently of the walk). The weight at the cap is 0.9999^1000 = 0.90: these photons
    # go on with analog absorption
    a = 0.9999
    r = simulate(a, photons=40_000, max_events=1000, seed=21, **FAST)
    expected = 1 - chandrasekhar_h(a, np.array([1.0]))[0] * math.sqrt(1 - a)
    assert r.capped_weight == 0.0
    assert abs(r.total_reflectance - expected) < 4 * r.total_reflectance_stderr, (r.total_reflectance, expected)


def test_cap_is_unbiased_against_adding_doubling():
    # albedo 0.999, eta 1.3 on top (the measured materials' boundary), against Prahl's adding-doubling (iadpython):
    # iadpython.Sample(a, b, g=0, n=1.3, n_above=1, n_below=1) is a slab of optical thickness b with index 1.3 and no
    # glass slides, lit by collimated light at normal incidence (nu_0 = 1); rt()[0] is the total reflection UR1, the
    # specular reflection of the front face included. b = 500 mfp is semi-infinite here (the diffusion length is
    # 1/sqrt(3 (1 - a)) = 18 mfp), and the walk excludes the specular part (1.3 - 1)^2/(1.3 + 1)^2, so it is
    # subtracted. 16 quadrature points: 32 moves UR1 by 7e-5, a fifth of the walk's standard error
    import iadpython

    a, eta = 0.999, 1.3
    ur1 = iadpython.Sample(a=a, b=500.0, g=0.0, n=eta, n_above=1.0, n_below=1.0, quad_pts=16).rt()[0]
    expected = float(ur1) - ((eta - 1) / (eta + 1)) ** 2
    r = simulate(a, photons=40_000, eta=eta, max_events=300, seed=22, **FAST)
    assert r.capped_weight == 0.0
    assert abs(r.total_reflectance - expected) < 4 * r.total_reflectance_stderr, (r.total_reflectance, expected)


def test_spectralon_keeps_every_photon():
    # spectralon (Jensen et al. 2001: sigma_a = 0): a non-absorbing half-space behind an eta 1.3 face returns all the
    # light that enters it, 1 - ((1.3 - 1)/(1.3 + 1))^2 = 0.98299 (energy conservation and Fresnel at normal
    # incidence); the preset's 0.975 before this fix was 0.8% of its photons dropped at the cap
    r = simulate(1.0, photons=20_000, eta=1.3, max_events=2000, seed=23, **FAST)
    assert r.capped_photons == 0
    assert r.total_reflectance == pytest.approx(1 - (0.3 / 2.3) ** 2, abs=1e-5)


def test_run_options_that_walk_no_photon_or_misplace_them_are_refused(as_users_run_it, tmp_path):
    # lanes=0 looped forever; r_max_mfp=-5 put reflected photons into the transmittance's bins (T 0.09 for a half
    # space); r_max_mfp=0 divided by zero; bins=0 gave an empty profile; a bool counted as 1 photon
    for kwargs, message in (({"lanes": 0}, "lanes must be a positive integer"),
                            ({"lanes": -4}, "lanes must be a positive integer"),
                            ({"r_max_mfp": -5.0}, "r_max_mfp must be a finite positive radius"),
                            ({"r_max_mfp": 0.0}, "r_max_mfp must be"), ({"r_max_mfp": float("nan")}, "r_max_mfp"),
                            ({"bins": 0}, "bins must be a positive integer"), ({"bins": 2.5}, "bins must be"),
                            ({"photons": True}, "photons must be an integer >= 2"),
                            ({"unroll": 0}, "unroll must be a positive integer")):
        with pytest.raises(ValueError, match=message):
            simulate(0.5, **{"photons": 200, **kwargs})
    # diffuse incidence has no specular reflectance (NaN): its JSON says null, as RFC 8259 has no NaN
    r = simulate(0.5, photons=200, incidence="diffuse", bins=10)
    text = json.dumps(r.to_json())
    json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert math.isnan(type(r).from_json(json.loads(text)).specular_reflectance)


def test_tabulated_profile_of_everyday_mean_free_paths_builds_in_float32(half_albedo):
    # mean free paths 1, 0.5 and 0.3 mm put bin centres one float64 ulp apart (0.5 x 0.15 against 0.3 x 0.25): in
    # float32 (JAX's default) they collapsed and TabulatedProfile refused the table, "r_mm must be strictly
    # increasing in float32" (found by a review of the docs' examples). Each channel keeps its histogram's energy
    held = float(np.sum(half_albedo.R * np.pi * np.diff(half_albedo.bin_edges_mfp ** 2)))
    for mfps in ([1.0, 0.5, 0.3], [3.0, 1.4, 0.8], [2.0, 1.0, 0.6]):
        with jax.enable_x64(False):
            prof = to_tabulated_profile([half_albedo] * 3, mfps)
            assert prof.r_mm.dtype == jnp.float32
            np.testing.assert_allclose(np.asarray(prof.albedo), held, rtol=1e-5)
