"""The stability sweep (reduced) and its command line; extremes the API fuzz found."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax._stability import run_sweep, sweep_cases
from sss_jax.cli import main


@pytest.fixture(scope="module")
def quick_sweep():
    return run_sweep(quick=True, progress=False)


def test_quick_sweep_has_no_nonfinite_outputs_or_gradients(quick_sweep):
    s = quick_sweep
    assert s["cases"] >= 500
    assert s["nonfinite_outputs"] == 0 and s["nonfinite_gradients"] == 0
    assert s["energy_unbounded"] == 0 and s["unexpected_errors"] == 0
    # limits of value: d -> 0 the identity, d -> large spreads the light (no return to the input), edges blur
    # monotonically with d, STA within its bound; each kind ran for every technique it applies to
    assert s["limit_violations"] == 0, [c for c in s["case_list"] if c["outcome"] == "limit_violated"]
    limits = [c for c in s["case_list"] if c["component"].startswith("limit_")]
    assert {(c["component"], c["params"].get("technique")) for c in limits} >= {
        (k, t) for k in ("limit_identity", "limit_large_d", "limit_monotone_edge")
        for t in ("burley", "separable_burley", "reference")}
    assert sum(c["component"] == "limit_sta_bounded" for c in limits) == 6
    assert s["ok"] + s["handled_errors"] == s["cases"]
    # every component took part, and both kinds of invalid input were caught with a message naming the input
    components = {c["component"] for c in s["case_list"]}
    assert {"burley", "separable_burley", "separable_two_gaussian", "reference", "sta", "profile",
            "kernel_preintegrated", "kernel_two_gaussian", "spiral_samples", "invalid_parameter",
            "montecarlo", "fit_two_gaussian", "fit_sta"} <= components
    messages = [c["message"] for c in s["case_list"] if c["outcome"] == "handled_error"]
    assert any("irradiance has" in m for m in messages)  # 1e30 in float16 is inf: caught, not propagated
    assert any("d_mm must" in m for m in messages) and any("albedo must" in m for m in messages)


def test_full_sweep_is_large_enough():
    cases = list(sweep_cases(quick=False))
    assert len(cases) >= 2000
    # the cross product covers every extreme the issue names
    tech = [c.params for c in cases if c.component == "burley"]
    assert {p["d_mm"] for p in tech} == {0.0, 1e-6, 1e-3, 1.0, 1e3, 1e6}
    assert {p["dtype"] for p in tech} == {"float16", "float32", "float64"}
    assert {tuple(p["size"]) for p in tech} == {(1, 1), (1, 5), (4, 4)}


def test_stability_cli_writes_json(tmp_path, monkeypatch, quick_sweep):
    import sss_jax._stability as stability

    monkeypatch.setattr(stability, "run_sweep", lambda quick, progress: quick_sweep)
    out = tmp_path / "s.json"
    assert main(["stability", "--quick", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    for key in ("cases", "handled_errors", "nonfinite_outputs", "nonfinite_gradients", "case_list"):
        assert key in data
    assert main(["stability", "--json", str(tmp_path / "missing" / "s.json")]) == 2


def test_stability_cli_prints_every_count_that_fails_it(tmp_path, monkeypatch, capsys, quick_sweep):
    # before, a violated limit made the exit status 1 while every count printed read 0 (limits were not printed)
    import sss_jax._stability as stability

    cases = [dict(c) for c in quick_sweep["case_list"]]
    bad = next(i for i, c in enumerate(cases) if c["component"] == "limit_identity")
    cases[bad] = dict(cases[bad], outcome="limit_violated", message="d -> 0 is not the identity (fake)")
    summary = dict(quick_sweep, ok=quick_sweep["ok"] - 1, limit_violations=1, case_list=cases)
    monkeypatch.setattr(stability, "run_sweep", lambda quick, progress: summary)
    assert main(["stability", "--quick", "--json", str(tmp_path / "s.json")]) == 1
    out = capsys.readouterr().out
    assert "limits violated:      1" in out and "limit_violated: limit_identity" in out and "(fake)" in out


# ---- what the API fuzz of stop 51 found at the extremes ----------------------------------------------------------

def test_hdrp_gradient_is_finite_where_a_pixel_takes_fewer_samples_than_the_budget():
    # samples past a pixel's count (masked) evaluated the inverse CDF at u > 1: NaN radii in the masked branch made
    # every gradient in d NaN (forward finite). 8x8 flat plane: focal 1.0 gives 19 samples of a budget of 20.
    b = sj.Buffers(irradiance=jnp.ones((8, 8, 3)), depth=jnp.full((8, 8), 1.0))
    cam = sj.Camera(1.0, 10.0)
    loss = lambda d: jnp.sum(sj.hdrp(b, sj.BurleyMaterial((0.8, 0.5, 0.4), d), cam, quality="low") ** 2)
    g = jax.grad(loss)(jnp.asarray((3.0, 1.4, 0.8)))
    assert np.all(np.isfinite(np.asarray(g)))
    sc = sj.demo_scene(24, 32)
    g = jax.grad(lambda d: jnp.sum(sj.hdrp(sc.buffers, sj.BurleyMaterial((0.8, 0.5, 0.4), d), sc.camera,
                                           quality="low")))(jnp.asarray((3.0, 1.4, 0.8)))
    assert np.all(np.isfinite(np.asarray(g)))


def test_sta_gradient_ignores_infinitely_thick_pixels_and_a_paper_thin_scale_is_allowed():
    # one pixel of infinite thickness (the demo's background has 629) made d/d thickness_mm NaN; thickness_mm = inf,
    # which STAParams allows ("paper-thin"), failed inside JAX
    h, w = 8, 8
    t = np.full((h, w), 0.1, np.float32)
    t[:, 3] = np.inf
    b = sj.Buffers(irradiance=jnp.ones((h, w, 3)), depth=jnp.ones((h, w)), thickness=jnp.asarray(t))
    light, cam = sj.DirectionalLight((0.0, 0.0, 1.0)), sj.Camera(100.0, 10.0)
    loss = lambda tm: jnp.sum(sj.translucency(b, sj.STAParams(thickness_mm=tm), cam, light))
    g = jax.grad(loss)(jnp.asarray(3.0))
    assert np.isfinite(float(g)) and float(g) > 0  # thicker scale, less attenuation, more light
    g_cam = jax.grad(lambda mm: jnp.sum(sj.translucency(b, sj.STAParams(thickness_mm=3.0), sj.Camera(100.0, mm),
                                                        light)))(jnp.asarray(10.0))
    assert np.isfinite(float(g_cam))
    # paper-thin: t = exp(-thickness / inf) = 1 on finite thickness, 0 where infinitely thick
    thin = np.asarray(sj.translucency(b, sj.STAParams(thickness_mm=float("inf"), ambient=0.5, scale=0.0), cam, light))
    # hand value: albedo 1 x (E 1 + light 1 x t x ambient 0.5)
    assert np.allclose(thin[:, [0, 1, 2, 4, 5, 6, 7]], 1.5) and np.allclose(thin[:, 3], 1.0)


def test_jimenez_keeps_finite_where_its_step_overflows():
    # a valid but extreme camera overflowed the step to inf: inf - inf = NaN in the clamped fetch, and inf x 0 in
    # the surface term; now the fetch clamps to the edge as the sampler does
    with jax.enable_x64(False):  # float32, as users run it (the suite enables x64)
        b = sj.Buffers(irradiance=jnp.ones((12, 16, 3)), depth=jnp.full((12, 16), 1e-9))
        mat = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8))
        for cam in (sj.Camera(1e30, 1.0), sj.Camera(3e38, 1e-30)):
            out = np.asarray(sj.jimenez(b, mat, cam))
            assert out.dtype == np.float32 and np.all(np.isfinite(out))
            assert np.allclose(out, (0.8, 0.5, 0.4), rtol=1e-5)  # flat light stays flat: albedo x E


def test_reference_window_past_the_frame_is_the_frames():
    # a window of 100000 px on an 8x8 frame overflowed JAX's argument parsing (40000400001 offsets); a window past
    # the frame reaches no further pixel: the same result as max(H, W) - 1
    sc = sj.demo_scene(8, 8)
    mat = sj.BurleyMaterial((0.8, 0.5, 0.4), (30.0, 14.0, 8.0))
    far = np.asarray(sj.reference(sc.buffers, mat, sc.camera, radius_px=100000))
    assert np.array_equal(far, np.asarray(sj.reference(sc.buffers, mat, sc.camera, radius_px=7)))


def test_burley_float32_gradients_stay_finite_across_a_depth_step():
    # one pixel 200 mm in front of a wall, 8 samples: every sample of that pixel lands on the wall, its weight total
    # is ~1e-27, and the quotient's derivative -num/den^2 overflowed float32: the gradients in d (and 17 in depth)
    # were NaN, the forward pass finite (float64 finite: 9.53, -1.08, 2.65)
    e = np.random.default_rng(26).uniform(0, 2, (24, 24, 3))
    depth = np.full((24, 24), 60.0)
    depth[12, 12] = 40.0
    cam = sj.Camera(focal_px=3000.0, mm_per_unit=10.0)
    grads = {}
    for dt in (np.float32, np.float64):
        def loss(d, z, dt=dt):
            b = sj.Buffers(irradiance=jnp.asarray(e, dt), depth=z)
            return jnp.sum(sj.burley(b, sj.BurleyMaterial(albedo=(0.8, 0.7, 0.6), d_mm=d), cam, samples=8))
        gd, gz = jax.grad(loss, argnums=(0, 1))(jnp.asarray((3.0, 1.4, 0.8), dt), jnp.asarray(depth, dt))
        assert np.all(np.isfinite(np.asarray(gz))), dt
        grads[dt] = np.asarray(gd, np.float64)
    assert np.all(np.isfinite(grads[np.float32]))
    # the forward passes differ at the pixel whose weights float32 cannot hold (it keeps its own light): 2% in d_R
    np.testing.assert_allclose(grads[np.float32], grads[np.float64], rtol=0.05)


def test_burley_a_channel_far_narrower_than_the_widest_scatters_alike_in_float32_and_float64():
    # d_B 1e4 times below d_R, 4 samples: the weights were scaled by a lower bound of the nearest sample's radius,
    # ~10% short, so every weight of B was exp(-83) or less: 0 in float32, where the pixels kept their own light
    # and the gradient was NaN or -48.8 against float64's 0
    cam = sj.Camera(focal_px=100.0, mm_per_unit=10.0)
    e = np.random.default_rng(3).uniform(0, 2, (6, 7, 3))
    depth = np.full((6, 7), 50.0)
    out, grad = {}, {}
    for dt in (np.float32, np.float64):
        b = sj.Buffers(irradiance=jnp.asarray(e, dt), depth=jnp.asarray(depth, dt))
        f = lambda d, b=b, dt=dt: sj.burley(b, sj.BurleyMaterial(albedo=np.ones(3, dt), d_mm=d), cam, samples=4)
        d = jnp.asarray([1.0, 1.0, 1e-4], dt)
        out[dt] = np.asarray(f(d), np.float64)
        grad[dt] = np.asarray(jax.grad(lambda d, f=f: jnp.sum(f(d)))(d), np.float64)
    np.testing.assert_allclose(out[np.float32], out[np.float64], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(grad[np.float32], grad[np.float64], rtol=2e-3, atol=1e-4)


def test_reference_gradients_in_depth_and_focal_length_are_finite_past_six_pixels():
    # the outer ring's one-point rule evaluated the skipped centre at r = 0 (R = inf) and masked it after: 0 inf = NaN
    # in every depth and focal gradient once radius_px > 6 (float64 too)
    e = jnp.ones((12, 12, 3))
    mat = sj.BurleyMaterial((0.8, 0.6, 0.5), (3.0, 1.4, 0.8))

    def loss(z, focal):
        return jnp.sum(sj.reference(sj.Buffers(irradiance=e, depth=z), mat, sj.Camera(focal, 10.0), radius_px=7))

    z = jnp.asarray(50.0 + np.random.default_rng(5).uniform(0, 1, (12, 12)))
    gz, gf = jax.grad(loss, argnums=(0, 1))(z, jnp.asarray(60.0))
    assert np.all(np.isfinite(np.asarray(gz))) and np.isfinite(float(gf))
    # against central differences of the same function (float64)
    h = 1e-4
    step = jnp.zeros_like(z).at[5, 5].set(h)
    fd = (loss(z + step, 60.0) - loss(z - step, 60.0)) / (2 * h)
    assert float(gz[5, 5]) == pytest.approx(float(fd), rel=1e-4, abs=1e-9)
    fd_f = (loss(z, 60.0 + h) - loss(z, 60.0 - h)) / (2 * h)
    assert float(gf) == pytest.approx(float(fd_f), rel=1e-4, abs=1e-9)


def test_sta_gradients_stay_finite_where_the_distorted_light_vanishes():
    # a flat surface facing the camera, the light straight behind it and distortion 1: L + d N = 0. The forward
    # pass gave 0 there, but |L + d N|'s derivative at 0 made every parameter's gradient NaN
    b = sj.Buffers(jnp.full((4, 4, 3), 0.5), jnp.full((4, 4), 2.0))  # normals derived from depth: (0, 0, -1)
    cam, light = sj.Camera(100.0, 10.0), sj.DirectionalLight(jnp.array([0.0, 0.0, 1.0]))

    def loss(params):
        return jnp.sum(sj.translucency(b, params, cam, light, thickness=0.1))

    g = jax.grad(loss)(sj.STAParams(distortion=1.0, power=4.0, scale=1.0, ambient=0.1, thickness_mm=3.0))
    assert all(np.all(np.isfinite(np.asarray(leaf))) for leaf in jax.tree.leaves(g))
    # with the light off the axis the norm is the same expression: its gradient is the forward pass's slope
    # (central differences, float64)
    tilted = sj.DirectionalLight(jnp.array([0.4, -0.2, 0.9]))
    f = lambda x: jnp.sum(sj.translucency(b, sj.STAParams(distortion=x, power=4.0, scale=1.0, ambient=0.1,
                                                          thickness_mm=3.0), cam, tilted, thickness=0.1))
    d, step = 0.7, 1e-6
    slope = (float(f(d + step)) - float(f(d - step))) / (2 * step)
    assert abs(slope) > 1e-3 and float(jax.grad(f)(jnp.asarray(d))) == pytest.approx(slope, rel=1e-6)


def test_sta_view_directions_hold_at_a_tiny_float32_depth():
    # the view vector was -p / |p| of the camera position: at a depth of 1e-20 its squares flushed to 0 in float32
    # and the back light vanished (0 where 0.797). The direction towards the camera does not depend on the depth
    with jax.enable_x64(False):
        light = sj.DirectionalLight([0.2, -0.1, 0.97])
        params = sj.STAParams(distortion=0.2, power=2.0, scale=1.0, ambient=0.0, thickness_mm=1.0)
        cam = sj.Camera(50.0, 1.0)
        out = [np.asarray(sj.translucency(sj.Buffers(jnp.full((3, 4, 3), 0.5, jnp.float32),
                                                     jnp.full((3, 4), z, jnp.float32),
                                                     normal=jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0]),
                                                                             (3, 4, 3)).astype(jnp.float32)),
                                          params, cam, light, thickness=0.0)) for z in (1.0, 1e-20)]
    assert out[0].max() > 0.6
    np.testing.assert_allclose(out[1], out[0], rtol=1e-6)


# --- float32, as users run (the tests turn x64 on); each found by a review against the same inputs in float64 ----


def test_engine_gradients_are_finite_in_float32_where_a_pixels_only_samples_cross_a_depth_step():
    # a disc 200 mm in front of a wall at 50 px/mm: hdrp's weight total underflowed float32 when squared (the
    # quotient's derivative), dL/dd NaN where float64 gives [2.94, -2.79, -6.13]; eevee-next has the same quotient
    h = w = 32
    yy, xx = np.mgrid[:h, :w]
    with jax.enable_x64(False):
        e = jnp.asarray(((0.2 + 0.8 * (xx < 20))[..., None] * np.ones(3)).astype(np.float32))
        z = jnp.asarray(np.where((xx - 10) ** 2 + (yy - 16) ** 2 < 8**2, 1.0, 1.2).astype(np.float32))
        b, cam = sj.Buffers(e, z), sj.Camera(jnp.float32(5e4), jnp.float32(1000.0))
        d0 = jnp.asarray([3.0, 1.4, 0.8], jnp.float32)
        for tech in (sj.hdrp, sj.eevee_next):
            g = np.asarray(jax.grad(lambda d, t=tech: jnp.sum(t(b, sj.BurleyMaterial((0.8, 0.55, 0.45), d), cam)))(d0))
            assert np.all(np.isfinite(g)), (tech.__name__, g)


def test_jimenez_follow_surface_changes_nothing_on_a_plane_in_float32():
    # skin 3 m away in a scene in mm (depth 3000), focal 300 px: the fetched depth of a flat plane came back an ulp
    # off ((1 - f) a + f b), and 300 / tan x width x that ulp pulled taps to the centre: 63 of 1024 pixels off by up
    # to 0.015 in float32, none in float64
    with jax.enable_x64(False):
        e = jnp.asarray(np.random.default_rng(1).uniform(0, 1, (32, 32, 3)).astype(np.float32))
        b, cam = sj.Buffers(e, jnp.full((32, 32), 3000.0, jnp.float32)), sj.Camera(300.0, 1.0)
        skin = sj.BurleyMaterial(albedo=(0.8, 0.55, 0.45), d_mm=(3.0, 1.4, 0.8))
        follow = np.asarray(sj.jimenez(b, skin, cam))
        plain = np.asarray(sj.jimenez(b, skin, cam, follow_surface=False))
        # the fetch itself: between two equal depths it returns that depth exactly, wherever it lands
        from sss_jax._techniques._jimenez import _linear_clamp_1d

        values = jnp.full((4, 64, 1), 3000.0, jnp.float32)
        pos = jnp.asarray(np.random.default_rng(2).uniform(0, 63, (4, 64)).astype(np.float32))
        fetched = np.asarray(jax.jit(_linear_clamp_1d, static_argnums=2)(values, pos, 1))
    np.testing.assert_allclose(follow, plain, rtol=1e-6, atol=1e-7)  # the two programs round alike to float32
    assert np.all(fetched == np.float32(3000.0))


def test_half_buffers_hold_added_light_at_halfs_largest_value():
    # translucency adds light: a half irradiance of 60000 plus a back light came out inf (the float32 result cast to
    # half); it holds at 65504, as the CLI's half writer clamps it
    e = jnp.full((4, 4, 3), 60000.0, jnp.float16)
    b, cam = sj.Buffers(e, jnp.ones((4, 4), jnp.float32)), sj.Camera(100.0, 10.0)
    light = sj.DirectionalLight(direction=(0.0, 0.0, 1.0), colour=(8000.0, 8000.0, 8000.0))
    for model, params in (("sta", sj.STAParams(distortion=0.2, power=4.0, thickness_mm=3.0)),
                          ("thin", sj.BurleyMaterial((1.0, 1.0, 1.0), (3.0, 1.4, 0.8)))):
        out = np.asarray(sj.translucency(b, params, cam, light, thickness=0.0, model=model))
        assert out.dtype == np.float16 and np.all(out == np.float16(65504)), (model, out[0, 0])


def test_a_far_tail_of_the_thin_transmittance_keeps_its_precision_in_float32():
    # 1 - CDF cancelled float32's digits: 5.96e-8 for 4.33e-8 at t = 50 d, 0 at 60 d. Truth: the closed form
    # (exp(-x) + 3 exp(-x / 3)) / 4 in float64
    x = np.array([1.0, 20.0, 50.0, 60.0, 150.0])
    with jax.enable_x64(False):
        got = np.asarray(sj.thin_transmittance(jnp.asarray(x, jnp.float32), 1.0))
    np.testing.assert_allclose(got, (np.exp(-x) + 3 * np.exp(-x / 3)) / 4, rtol=1e-5)


def test_a_two_gaussian_kernel_cut_near_its_centre_keeps_its_mass_in_float32():
    # the cut table's mass over [0, x] was the normal CDF minus 1/2: at x = 1e-6 sigma float32 kept ~1 digit.
    # Truth: erf(x / (sigma sqrt 2)) / 2 in float64 (scipy)
    from scipy.special import erf

    from sss_jax._kernels import two_gaussian_half_masses

    unit = np.array([1e-7, 1e-6, 1e-4, 0.01, 0.5, 1.0])
    with jax.enable_x64(False), jax.numpy_rank_promotion("allow"):  # (K, 1) x (C,), as the pass calls it
        got = np.asarray(two_gaussian_half_masses([0.6], [1.0], [3.0], unit, range_mm=[10.0]))[:, 0]
    x = unit * 10.0
    want = 0.6 * erf(x / np.sqrt(2)) / 2 + 0.4 * erf(x / (3 * np.sqrt(2))) / 2
    np.testing.assert_allclose(got, want, rtol=2e-6)
