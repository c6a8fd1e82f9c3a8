"""Fidelity of the passes against independent references (issue #18 parts 3-5): Burley's sampling pattern on a
shadow edge, energy at the frame border and for kernels wider than the frame, and the large-d limit."""

import itertools
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

import sss_jax as sj

# ------------------------------------------------------------------------------------------------------------------
# Part 3: a hard shadow edge on a flat plane, d = 4, 2, 1 mm at 1 px/mm, the profile averaged over 40 rows
# ------------------------------------------------------------------------------------------------------------------

EDGE_MARGIN, EDGE_ROWS, EDGE_W = 48, 40, 256
EDGE_H = EDGE_ROWS + 2 * EDGE_MARGIN
EDGE_CAM = sj.Camera(focal_px=1.0, mm_per_unit=1.0)  # depth 1: 1 px per mm
EDGE_MAT = sj.BurleyMaterial(albedo=[1.0, 1.0, 1.0], d_mm=[4.0, 2.0, 1.0])


def edge_buffers(flat=False, dtype=jnp.float32):
    e = np.zeros((EDGE_H, EDGE_W, 3))
    e[:, EDGE_W // 2:] = 1.0
    if flat:
        e[:] = 1.0
    return sj.Buffers(irradiance=jnp.asarray(e, dtype), depth=jnp.ones((EDGE_H, EDGE_W), dtype))


def edge_asymmetry(out, flat_out, reach=64):
    """max_t |p(x0 + t) - (F(x0 - t) - p(x0 - t))| over the 40 middle rows' mean profile p across the edge at x0
    (between columns W/2 - 1 and W/2), per channel. On an infinite plane a symmetric kernel gives p(x0 + t) =
    1 - p(x0 - t) (point reflection about the edge); in a frame, F (the same pass on flat light: the in-frame share,
    1 away from the border) replaces the 1, so light leaving at the border is not counted as asymmetry. By linearity
    F - p is the pass's output for the complementary edge."""
    rows = slice(EDGE_MARGIN, EDGE_MARGIN + EDGE_ROWS)
    p = np.asarray(out, np.float64)[rows].mean(0)
    f = np.asarray(flat_out, np.float64)[rows].mean(0)
    x0 = EDGE_W // 2
    right = p[x0:x0 + reach]
    left = (f - p)[x0 - reach:x0][::-1]
    return np.abs(right - left).max(0)


def test_fixed_spiral_blurs_a_shadow_edge_asymmetrically_and_the_rotated_one_does_not():
    # the measurement: 0.056 at 32 samples for the shared (fixed) spiral; goal <= 0.02 with the default
    b, flat = edge_buffers(), edge_buffers(flat=True)
    fixed = edge_asymmetry(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=32, pattern="fixed"),
                           sj.burley(flat, EDGE_MAT, EDGE_CAM, samples=32, pattern="fixed"))
    assert fixed.max() > 0.04, fixed  # the old behaviour fails the goal
    for seed in (0, 1):
        default = edge_asymmetry(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=32, seed=seed),
                                 sj.burley(flat, EDGE_MAT, EDGE_CAM, samples=32, seed=seed))
        assert default.max() <= 0.02, (seed, default)
    # separable is symmetric by construction (taps in +-pairs, exact up to float32 rounding)
    sep = edge_asymmetry(sj.separable(b, EDGE_MAT, EDGE_CAM, taps=25), sj.separable(flat, EDGE_MAT, EDGE_CAM, taps=25))
    assert sep.max() < 1e-5, sep


def test_reference_is_symmetric_across_a_shadow_edge():
    # a narrower material (the dense window's cost grows with its area); the same measure
    mat = sj.BurleyMaterial(albedo=[1.0, 1.0, 1.0], d_mm=[1.0, 0.5, 0.25])
    sub = lambda bb: sj.Buffers(irradiance=bb.irradiance[EDGE_MARGIN - 16:EDGE_MARGIN + EDGE_ROWS + 16, 64:192],
                                depth=bb.depth[EDGE_MARGIN - 16:EDGE_MARGIN + EDGE_ROWS + 16, 64:192])
    b, flat = sub(edge_buffers()), sub(edge_buffers(flat=True))
    out, f = sj.reference(b, mat, EDGE_CAM, radius_px=16), sj.reference(flat, mat, EDGE_CAM, radius_px=16)
    p = np.asarray(out)[16:-16].mean(0)
    fl = np.asarray(f)[16:-16].mean(0)
    right, left = p[64:96], (fl - p)[32:64][::-1]
    assert np.abs(right - left).max() < 1e-5
    assert p[64, 0] < 0.9 and p[63, 0] > 0.1  # and it does blur the edge (the test can fail)


def test_temporal_accumulation_reduces_the_noise():
    # K frames of independent rotations: the per-pixel error against a long accumulation falls about as 1/sqrt(K)
    b = edge_buffers()
    run = lambda k, seed: np.asarray(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=8, frames=k, seed=seed), np.float64)
    converged = run(16, 7)
    e1 = np.sqrt(np.mean((run(1, 0) - converged) ** 2))
    e4 = np.sqrt(np.mean((run(4, 0) - converged) ** 2))
    assert e4 < 0.65 * e1, (e1, e4)  # 1/sqrt(4) = 0.5 for independent noise; the converged run has its own noise
    # the fixed pattern with one frame is the old spiral: no per-pixel rotation, so rows of a vertical edge agree
    fixed = np.asarray(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=8, pattern="fixed"))
    np.testing.assert_allclose(fixed[EDGE_MARGIN], fixed[EDGE_MARGIN + 1], rtol=1e-6)


def test_rotation_is_seeded_and_gradients_in_the_material_are_finite():
    import jax

    b = edge_buffers(dtype=jnp.float64)
    a = np.asarray(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=8, seed=3))
    np.testing.assert_array_equal(a, np.asarray(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=8, seed=3)))
    assert np.abs(a - np.asarray(sj.burley(b, EDGE_MAT, EDGE_CAM, samples=8, seed=4))).max() > 1e-3
    small = sj.Buffers(irradiance=b.irradiance[:8, 124:132], depth=b.depth[:8, 124:132])
    f = lambda d: jnp.sum(sj.burley(small, sj.BurleyMaterial(EDGE_MAT.albedo, d), EDGE_CAM, samples=8) ** 2)
    g = jax.grad(f)(jnp.asarray([[4.0, 2.0, 1.0]]))
    assert np.all(np.isfinite(np.asarray(g))) and np.abs(np.asarray(g)).max() > 0
    # finite differences (float64): the angle does not depend on d, so the derivative is that of the radii
    h = 1e-4
    fd = (f(jnp.asarray([[4.0 + h, 2.0, 1.0]])) - f(jnp.asarray([[4.0 - h, 2.0, 1.0]]))) / (2 * h)
    np.testing.assert_allclose(float(g[0, 0]), float(fd), rtol=1e-4)


def test_bad_pattern_frames_and_seed_are_rejected():
    b = edge_buffers()
    with pytest.raises(ValueError, match="pattern"):
        sj.burley(b, EDGE_MAT, EDGE_CAM, pattern="spiral")
    with pytest.raises(ValueError, match="frames"):
        sj.burley(b, EDGE_MAT, EDGE_CAM, frames=0)
    with pytest.raises(ValueError, match="seed"):
        sj.burley(b, EDGE_MAT, EDGE_CAM, seed=-1)


def test_cli_apply_burley_on_a_shadow_edge_is_symmetric(tmp_path):
    oiio = pytest.importorskip("OpenImageIO")
    from sss_jax import _io
    from sss_jax.cli import main

    def write(path, e):
        h, w = e.shape[:2]
        data = np.concatenate([e, np.ones((h, w, 1))], -1).astype(np.float32)  # R, G, B, Z
        spec = oiio.ImageSpec(w, h, 4, oiio.FLOAT)
        spec.channelnames = ("R", "G", "B", "Z")
        out = oiio.ImageOutput.create(str(path))
        assert out.open(str(path), spec) and out.write_image(data)
        out.close()

    args = ["--technique", "burley", "--albedo", "1,1,1", "--d-mm", "4,2,1", "--focal-px", "1", "--mm-per-unit", "1",
            "--samples", "32"]
    outs = {}
    for name, flat in (("edge", False), ("flat", True)):
        write(tmp_path / f"{name}.exr", np.asarray(edge_buffers(flat=flat).irradiance))
        assert main(["apply", str(tmp_path / f"{name}.exr"), "-o", str(tmp_path / f"{name}_out.exr")] + args) == 0
        outs[name] = _io.read_frame(tmp_path / f"{name}_out.exr",
                                    channel_map={"irradiance": ["R", "G", "B"], "depth": "R"}).irradiance
    assert edge_asymmetry(outs["edge"], outs["flat"]).max() <= 0.02


# ------------------------------------------------------------------------------------------------------------------
# Part 4: light scattering out of the frame leaves
# ------------------------------------------------------------------------------------------------------------------

SPOT_H, SPOT_W = 24, 32
SPOT_CAM = sj.Camera(focal_px=12.0, mm_per_unit=1.0)  # depth 1: 12 px per mm; the profiles reach past the frame
SPOT_D = (3.0, 1.4, 0.8)
SPOT_MAT = sj.BurleyMaterial(albedo=[1.0, 1.0, 1.0], d_mm=list(SPOT_D))


def spot(row, col):
    e = np.zeros((SPOT_H, SPOT_W, 3))
    e[row, col] = 1.0
    return sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.ones((SPOT_H, SPOT_W)))


def burley_in_frame_fraction(row, col, d_mm, px_mm):
    """The fraction of Burley's profile around pixel (row, col) inside the frame, from its CDF
    ``1 - exp(-r/d)/4 - 3 exp(-r/3d)/4`` (Christensen & Burley 2015): the mass of a star-shaped region seen from its
    centre is the mean over angles of the CDF at the distance to the boundary (scipy's adaptive quadrature, not the
    code under test)."""
    cdf = lambda r: 1 - math.exp(-r / d_mm) / 4 - 3 * math.exp(-r / (3 * d_mm)) / 4

    def boundary(th):
        c, s = math.cos(th), math.sin(th)
        ts = [t for t, ok in (((SPOT_W - 0.5 - col) / c, c > 1e-15), ((-0.5 - col) / c, c < -1e-15),
                              ((SPOT_H - 0.5 - row) / s, s > 1e-15), ((-0.5 - row) / s, s < -1e-15)) if ok]
        return min(ts) * px_mm

    corners = sorted(math.atan2(y - row, x - col) % (2 * math.pi)
                     for y in (-0.5, SPOT_H - 0.5) for x in (-0.5, SPOT_W - 0.5))
    return integrate.quad(lambda th: cdf(boundary(th)), 0, 2 * math.pi, points=corners, limit=200)[0] / (2 * math.pi)


@pytest.mark.parametrize("where", [(12, 16), (12, 0), (0, 0)], ids=["inside", "border", "corner"])
def test_a_lit_spot_keeps_the_share_of_its_profile_that_lies_in_the_frame(where):
    # the issue: a spot inside a frame narrower than the kernel gained 11-13% (light pushed back onto the frame),
    # a spot at the border lost a fraction unrelated to the profile; now the light past the border leaves
    b = spot(*where)
    expected = np.array([burley_in_frame_fraction(*where, d, 1 / 12) for d in SPOT_D])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default window spans the frame: no warning
        ref = np.asarray(sj.reference(b, SPOT_MAT, SPOT_CAM, border="leaves")).sum((0, 1))
    np.testing.assert_allclose(ref, expected, rtol=2e-3)
    assert np.all(expected < 0.6)  # the case is one where most of the light leaves (the test can fail)


def test_burley_keeps_the_in_frame_share_of_flat_light():
    # On a plane the kernel is symmetric, so the light a spot at p keeps in the frame equals what p gathers from
    # flat unit light. Burley's spot energy is a rare-hit estimate (+-10% at 64 samples x 16 frames); flat light
    # lets every sample count, so the same quantity is tested to a few percent
    b = sj.Buffers(irradiance=jnp.ones((SPOT_H, SPOT_W, 3)), depth=jnp.ones((SPOT_H, SPOT_W)))
    out = np.asarray(sj.burley(b, SPOT_MAT, SPOT_CAM, samples=32, frames=16, border="leaves"))
    groups = {"inside": [(12, 16), (11, 15)],
              "border": [(r, 0) for r in range(6, 18, 2)] + [(0, c) for c in range(8, 24, 3)],
              "corner": [(0, 0), (0, SPOT_W - 1), (SPOT_H - 1, 0), (SPOT_H - 1, SPOT_W - 1)]}
    for name, pixels in groups.items():
        expected = np.array([[burley_in_frame_fraction(*p, d, 1 / 12) for d in SPOT_D] for p in pixels])
        got = np.array([out[p] for p in pixels])
        # the mean ratio over the group (per pixel the border's noise is ~3% at 32 samples x 16 frames; bilinear
        # fetches see the frame's edge as a 1-px ramp, ~1% at the border)
        np.testing.assert_allclose((got / expected).mean(0), 1.0, atol=0.03, err_msg=name)
        assert np.all(expected < 0.9)  # light does leave here (the old rule kept 1: the test can fail)


def test_separable_keeps_the_share_of_its_product_kernel_in_the_frame():
    # separable renders a(x) a(y) (the 1D marginal of the profile twice), so its in-frame share is the product of
    # the 1D shares, from the marginal's CDF (integrated independently here: the marginal density of a radial
    # profile is a(x) = int R(sqrt(x^2 + y^2)) dy, scipy quadrature)
    def marginal_mass(lo_mm, hi_mm, d):
        big = 60 * d
        R = lambda r: (math.exp(-r / d) + math.exp(-r / (3 * d))) / (8 * math.pi * d * r)
        # mass of R over the strip lo < x < hi, in polar form: int over angles of CDF-like radial integrals is
        # awkward for a strip; integrate the 2D density directly (inner over y, outer over x), the 1/r peak split off
        inner = lambda x: 2 * integrate.quad(lambda y: R(math.hypot(x, y)), 0, big, limit=200, points=[abs(x)])[0]
        pts = [0.0] if lo_mm < 0 < hi_mm else None
        return integrate.quad(inner, lo_mm, hi_mm, points=pts, limit=200)[0]

    px = 1 / 12
    for where in [(12, 16), (12, 0)]:
        row, col = where
        b = spot(*where)
        out = np.asarray(sj.separable(b, SPOT_MAT, SPOT_CAM, taps=65, border="leaves")).sum((0, 1))
        expected = np.array([marginal_mass(-(col + 0.5) * px, (SPOT_W - 0.5 - col) * px, d)
                             * marginal_mass(-(row + 0.5) * px, (SPOT_H - 0.5 - row) * px, d) for d in SPOT_D])
        # the taps know the kernel only to their cells' resolution near the frame's edge: a few percent
        np.testing.assert_allclose(out, expected, rtol=0.06)


# A kernel cut at the frame is re-integrated from each channel's own profile over the shrunk tap cells. The old rule
# read a channel's mass "linear within the original cells", which spread a narrow channel's centre mass over every
# shrunk cell inside the old centre cell: a d = 0 channel beside a wide one stopped being the identity (0.22 of the
# input off on the frame below). The exact masses below are written from the profiles: the two-Gaussian's erf, and
# the 1D marginal of Burley's R(r) = (exp(-r/d) + exp(-r/3d)) / (8 pi d r), int R(sqrt(x^2 + y^2)) dy =
# (K0(|x|/d) + K0(|x|/3d)) / (4 pi d) (scipy's k0, quadrature).

CUT_TAPS = 25


def _two_gaussian_mass(lo, hi, w, s_near, s_far):
    phi = lambda x, s: float(x > 0) if s == 0 else 0.5 * (1 + math.erf(x / (s * math.sqrt(2))))
    return w * (phi(hi, s_near) - phi(lo, s_near)) + (1 - w) * (phi(hi, s_far) - phi(lo, s_far))


def _burley_mass(lo, hi, d):
    from scipy.special import k0
    if d == 0:
        return float(lo < 0 <= hi) if lo != hi else 0.0
    density = lambda x: (k0(abs(x) / d) + k0(abs(x) / (3 * d))) / (4 * math.pi * d)
    pts = [0.0] if lo < 0 < hi else None
    return integrate.quad(density, lo, hi, points=pts, limit=400, epsabs=1e-13)[0]


@pytest.mark.parametrize("kind", ["two_gaussian", "burley"])
def test_a_kernel_cut_at_the_frame_weighs_each_channels_own_mass_over_the_shrunk_cells(kind):
    from sss_jax._techniques import _separable_spec as spec
    if kind == "two_gaussian":
        w, sn, sf = [0.6, 0.5, 1.0], [2.0, 0.05, 0.0], [30.0, 0.4, 0.0]  # wide, narrow, a point (sigma 0)
        mat = sj.TwoGaussianMaterial(albedo=[[1.0] * 3], w=[w], sigma_near_mm=[sn], sigma_far_mm=[sf])
        reach_mm = 3 * 30.0
        mass = lambda lo, hi, c: _two_gaussian_mass(lo, hi, w[c], sn[c], sf[c])
    else:
        d = [20.0, 0.1, 0.0]
        mat = sj.BurleyMaterial(albedo=[[1.0] * 3], d_mm=[d])
        reach_mm = None
        mass = lambda lo, hi, c: _burley_mass(lo, hi, d[c])
    kernels = mat.separable_kernels(CUT_TAPS, jnp.float64)
    reach_mm = float(np.max(np.abs(np.asarray(kernels.offsets_mm)))) if reach_mm is None else reach_mm
    w_table = np.moveaxis(np.asarray(kernels.weights), -1, 1)  # (1, 3, n), the pass's order
    table = np.asarray(spec.cut_table(np.asarray(mat.separable_half_masses(spec.cut_knots(CUT_TAPS)[1:],
                                                                           jnp.float64)), w_table))
    bounds, order = spec.cell_bounds(CUT_TAPS), spec.tap_order(CUT_TAPS)
    for reach_px in [30.0, 100.0, 1e3, 1e5]:  # cut to 0.62 of the kernel, down to 2e-4 of it, on 20 px
        scale, w_levels = spec.frame_truncation(spec.pass_unit_offsets(CUT_TAPS), w_table, np.array([reach_px]),
                                                20.0, table)
        s = float(scale[0])
        assert s < 1
        cells = s * reach_mm * bounds
        exact = np.array([[mass(lo, hi, c) for lo, hi in itertools.pairwise(cells)] for c in range(3)])[:, order]
        np.testing.assert_allclose(w_levels[0, 0], exact, atol=5e-4, err_msg=f"{kind} at {reach_px} px")
        np.testing.assert_array_equal(w_levels[0, 0, 2], np.eye(CUT_TAPS)[0])  # the point channel: the centre tap


@pytest.mark.parametrize("impl", ["banded", "gather", "pallas"])
@pytest.mark.parametrize("border", ["leaves", "renormalise"])
def test_a_channel_without_spread_stays_the_identity_when_its_material_is_cut_at_the_frame(impl, border):
    # d = 0 (G) beside a channel far wider than the 10x12 frame (R): G renders its input, times its albedo
    rng = np.random.default_rng(0)
    e = rng.uniform(0.2, 1.0, (10, 12, 3))
    cam = sj.Camera(focal_px=100.0, mm_per_unit=10.0)  # depth 50: 0.2 px per mm
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.full((10, 12), 50.0))
    mat = sj.BurleyMaterial(albedo=[[0.8, 0.7, 0.6]], d_mm=[[50.0, 0.0, 0.0]])
    reach_px = float(np.max(np.abs(np.asarray(mat.separable_kernels(CUT_TAPS, jnp.float64).offsets_mm)))) * 0.2
    assert reach_px > 12 * 2  # the kernel is cut at the frame along both passes
    out = np.asarray(sj.separable(b, mat, cam, taps=CUT_TAPS, impl=impl, border=border))
    np.testing.assert_allclose(out[..., 1:], e[..., 1:] * [0.7, 0.6], rtol=1e-12)
    assert np.abs(out[..., 0] - 0.8 * e[..., 0]).max() > 0.1  # R does spread
    if impl == "banded":  # the same pixels with traced buffers (the table read) and traced parameters (built inside)
        run = lambda bb, mm: sj.separable(bb, mm, cam, taps=CUT_TAPS, impl=impl, border=border)
        np.testing.assert_allclose(np.asarray(jax.jit(run)(b, mat)), out, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(jax.jit(lambda bb: run(bb, mat))(b)), out, rtol=1e-12, atol=1e-15)


def test_reference_window_narrower_than_the_profile_says_so():
    b = spot(12, 16)
    assert sj.reference_energy_held(b, SPOT_MAT, SPOT_CAM, 31) == 1.0  # the frame is 32 wide: the window spans it
    held = sj.reference_energy_held(b, SPOT_MAT, SPOT_CAM, 6)
    # independent: Burley's CDF at the window's inscribed radius (6.5 px at 12 px/mm) for the widest d (3 mm)
    r = 6.5 / 12
    np.testing.assert_allclose(held, 1 - math.exp(-r / 3) / 4 - 3 * math.exp(-r / 9) / 4, rtol=1e-6)
    with pytest.warns(sj.ReferenceWindowWarning, match="holds"):
        sj.reference(b, SPOT_MAT, SPOT_CAM, radius_px=6)


# ------------------------------------------------------------------------------------------------------------------
# Part 5: large scattering distances blur more, never snap back
# ------------------------------------------------------------------------------------------------------------------

STEP_H, STEP_W = 64, 80


def step_jump(fn, d_mm):
    e = np.zeros((STEP_H, STEP_W, 3))
    e[:, STEP_W // 2:] = 1.0
    b = sj.Buffers(irradiance=jnp.asarray(e, jnp.float32), depth=jnp.ones((STEP_H, STEP_W), jnp.float32))
    out = np.asarray(fn(b, sj.BurleyMaterial(albedo=[1.0] * 3, d_mm=[d_mm] * 3)), np.float64)
    return float(np.mean(out[:, STEP_W // 2] - out[:, STEP_W // 2 - 1]))


D_SWEEP = [0.25, 1.0, 4.0, 20.0, 80.0, 320.0, 1e3, 1e5, 1e9]  # mm at 1 px/mm


@pytest.mark.parametrize("technique", ["separable", "burley"])
def test_the_jump_across_a_step_edge_falls_monotonically_with_d(technique):
    cam = sj.Camera(focal_px=1.0, mm_per_unit=1.0)
    if technique == "separable":
        fn = lambda b, m: sj.separable(b, m, cam, taps=25, border="leaves")
    else:
        fn = lambda b, m: sj.burley(b, m, cam, samples=32, frames=4, border="leaves")
    jumps = [step_jump(fn, d) for d in D_SWEEP]
    assert jumps[0] > 0.5  # d = 0.25 px: the edge stays sharp
    for a, b in itertools.pairwise(jumps):
        assert b <= a + 1e-4, jumps  # falls (or stays) as d grows
    assert jumps[-1] < 1e-3, jumps  # d = 1e9 mm: spread over metres, nothing of the edge is left


def test_bench_splits_burley_error_into_bias_and_noise():
    from sss_jax._bench import burley_sampling_error, sampling_error_figure

    cam = sj.Camera(focal_px=1.0, mm_per_unit=1.0)
    e = np.zeros((24, 32, 3))
    e[:, 16:] = 1.0
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.ones((24, 32)))
    mat = sj.BurleyMaterial(albedo=[1.0] * 3, d_mm=[2.0, 1.0, 0.5])
    ref = sj.reference(b, mat, cam)
    rows = burley_sampling_error(b, mat, cam, ref, samples=(8,), frames=(1, 4), seeds=3)
    by = {(r["pattern"], r["frames"]): r for r in rows}
    assert len(rows) == 4 and all(r["samples_x_frames"] == 8 * r["frames"] for r in rows)
    # the fixed spiral with one frame does not depend on the seed: all of its error is bias (structure)
    assert by[("fixed", 1)]["noise"] == 0 and by[("fixed", 1)]["bias"] == pytest.approx(by[("fixed", 1)]["error"])
    # the rotated one trades that structure for noise, and four frames average the noise down (~1/2)
    assert by[("rotated", 1)]["noise"] > 0.01
    assert by[("rotated", 4)]["noise"] < 0.7 * by[("rotated", 1)]["noise"]
    assert by[("rotated", 1)]["bias"] < by[("fixed", 1)]["bias"]
    fig = sampling_error_figure(rows)
    assert len(fig.axes) == 3


def test_border_renormalise_keeps_flat_light_flat_at_the_border():
    # the model for a lit surface cut by the frame (its outside sends light in as the inside sends it out), the
    # default since issue #27: flat light stays flat up to the border, where border="leaves" loses the profile's
    # share beyond it
    b = sj.Buffers(irradiance=jnp.ones((SPOT_H, SPOT_W, 3)), depth=jnp.ones((SPOT_H, SPOT_W)))
    runs = {"burley": lambda **kw: sj.burley(b, SPOT_MAT, SPOT_CAM, samples=8, **kw),
            "separable": lambda **kw: sj.separable(b, SPOT_MAT, SPOT_CAM, taps=9, **kw),
            "reference": lambda **kw: sj.reference(b, SPOT_MAT, SPOT_CAM, radius_px=4, near_subsamples=2, **kw)}
    for name, run in runs.items():
        np.testing.assert_allclose(np.asarray(run(border="renormalise")), 1.0, rtol=1e-9, err_msg=name)
        np.testing.assert_array_equal(np.asarray(run()), np.asarray(run(border="renormalise")), err_msg=name)
        assert np.asarray(run(border="leaves"))[0, 0, 0] < 0.9, name
    with pytest.raises(ValueError, match="border"):
        sj.burley(b, SPOT_MAT, SPOT_CAM, border="clamp")


def test_a_kernel_far_wider_than_the_frame_reaches_its_limit_in_float32():
    # float32, the default border: the samples' radii come from the CDF truncated at the frame's diagonal, u times a
    # share of ~diagonal / (2 d); its inversion took -3 log(1 - s), which rounds 1 - s: at d = 1e6-1e7 px the step's
    # jump drifted (0.081, 0.022) and at 1e9 px every radius was 0, so every pixel kept its input (jump 1.0). Past
    # ~1e4 px the profile over the frame is its r -> 0 form, 1/r (Burley's R ~ 1/(4 pi d r)): the result stops moving
    cam = sj.Camera(focal_px=1.0, mm_per_unit=1.0)
    fn = lambda b, m: sj.burley(b, m, cam, samples=32, frames=4)
    with jax.enable_x64(False):
        jumps = [step_jump(fn, d) for d in (1e4, 1e5, 1e6, 1e7, 1e9)]
    assert jumps[0] < 0.2, jumps  # the limit blurs the edge (the input's jump is 1)
    np.testing.assert_allclose(jumps, jumps[0], atol=1e-3)
