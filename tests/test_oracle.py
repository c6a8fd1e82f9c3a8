"""Independent NumPy loops of Burley's screen-space pass and of the reference, against every formulation and option,
and tiles.

The loop is written from the formulas (Christensen & Burley 2015's CDF ``1 - (exp(-r/d) + 3 exp(-r/3d))/4``, its
closed-form inverse, the golden-angle spiral, Wellons' lowbias32 hash for the per-pixel rotation), pixel by pixel
in float64; it calls nothing of sss_jax's internals.
"""

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import sss_jax as sj

CAM = sj.Camera(focal_px=100.0, mm_per_unit=10.0)  # at depth 50: 0.2 px per mm
GOLDEN = np.pi * (3 - np.sqrt(5))
M32 = 0xFFFFFFFF


def _lowbias32(x: int) -> int:
    x &= M32
    x ^= x >> 16
    x = (x * 0x7FEB352D) & M32
    x ^= x >> 15
    x = (x * 0x846CA68B) & M32
    return x ^ (x >> 16)


def _rotation(row: int, col: int, frame: int, seed: int, rotated: bool) -> float:
    """The documented hash: key = h(seed * 0x9E3779B9 + frame * 0x85EBCA6B + 0x27D4EB2F); per pixel
    h(h(row * 0x68E31DA4 ^ key) + col * 0xB5297A4D); the top 24 bits as a fraction of a turn; fixed: frame 0 none."""
    key = _lowbias32(seed * 0x9E3779B9 + frame * 0x85EBCA6B + 0x27D4EB2F)
    if rotated:
        key = _lowbias32(_lowbias32(((row * 0x68E31DA4) & M32) ^ key) + col * 0xB5297A4D)
    elif frame == 0:
        key = 0
    return (key >> 8) / (1 << 24) * 2 * np.pi


def _ccdf(x):
    return (np.exp(-x) + 3 * np.exp(-x / 3)) / 4


def _inverse_cdf_truncated(u):
    """rho with CDF(rho) = u (units of d), by bisection on the CDF: independent of the pass's closed form."""
    lo, hi = 0.0, 1e4
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if 1 - _ccdf(mid) < u else (lo, mid)
    return 0.5 * (lo + hi)


def numpy_burley(e, z, valid, d, ppm, samples, mm_per_unit, *, linear, rotated, frames, seed, leaves,
                 truncate, origin=(0, 0), frame_shape=None, footprint=0.5):
    """The pass pixel by pixel. ``truncate``: sample the profile truncated at the frame's diagonal (and, with
    ``leaves``, count the energy beyond it as leaving); else the whole profile."""
    h, w = z.shape
    fh, fw = frame_shape or (h, w)
    r0, c0 = origin
    profile = lambda x: (np.exp(-x) + np.exp(-x / 3)) / x  # R(x d) up to 8 pi d^2 (cancels in the normalisation)
    r99 = _inverse_cdf_truncated(0.99)
    out = np.array(e, np.float64)
    for y in range(h):
        for x in range(w):
            dmax = d[y, x].max()
            if not (valid[y, x] and dmax * ppm[y, x] * r99 >= footprint):
                continue
            inside = 1 - _ccdf(np.hypot(fh, fw) / ppm[y, x] / dmax) if truncate else 1.0
            acc = np.zeros(3)
            for k in range(frames):
                phi = _rotation(y + r0, x + c0, k, seed, rotated)
                num, den = np.zeros(3), np.zeros(3)
                for i in range(samples):
                    rho = _inverse_cdf_truncated((i + 0.5) / samples * inside)
                    off = rho * dmax * ppm[y, x]
                    ang = i * GOLDEN + phi
                    py, px = y + r0 + off * np.sin(ang), x + c0 + off * np.cos(ang)  # frame coordinates
                    if linear:
                        y0, x0 = np.floor(py), np.floor(px)
                        fy, fx = py - y0, px - x0
                        corners = [(y0, x0, (1 - fy) * (1 - fx)), (y0, x0 + 1, (1 - fy) * fx),
                                   (y0 + 1, x0, fy * (1 - fx)), (y0 + 1, x0 + 1, fy * fx)]
                    else:
                        corners = [(np.round(py), np.round(px), 1.0)]
                    inv_pdf = rho / (np.exp(-rho) + np.exp(-rho / 3))
                    outside = 0.0
                    for yi, xi, cw in corners:
                        if not (0 <= yi < fh and 0 <= xi < fw):
                            outside += cw
                            continue
                        ly, lx = int(yi) - r0, int(xi) - c0
                        if not (0 <= ly < h and 0 <= lx < w and valid[ly, lx]):
                            continue
                        r3 = np.hypot(rho * dmax, (z[ly, lx] - z[y, x]) * mm_per_unit)
                        wgt = cw * inv_pdf * np.where(d[y, x] > 0, profile(r3 / np.where(d[y, x] > 0, d[y, x], 1)),
                                                      0.0)
                        num += wgt * e[ly, lx]
                        den += wgt
                    if leaves:  # dark surface at the pixel's own depth for the part outside the frame
                        dd = np.where(d[y, x] > 0, d[y, x], 1)
                        den += outside * inv_pdf * np.where(d[y, x] > 0, profile(rho * dmax / dd), 0.0)
                if leaves and truncate:  # the energy beyond the diagonal, in the weights' units
                    r_clip = np.hypot(fh, fw) / ppm[y, x]
                    den += samples / inside * _ccdf(r_clip / np.where(d[y, x] > 0, d[y, x], 1)) * (d[y, x] / dmax) ** 2
                acc += np.where(den > 0, num / np.where(den > 0, den, 1.0), e[y, x])
            out[y, x] = acc / frames
    return out


def _case(h=10, w=12, seed=3, wide=False):
    rng = np.random.default_rng(seed)
    e = rng.uniform(0.0, 2.0, (h, w, 3))
    depth = 50.0 + 6.0 * (np.arange(w)[None, :] >= 6) + rng.uniform(0.0, 1.0, (h, w))  # a depth step
    ids = np.ones((h, w), np.int32)
    ids[rng.uniform(size=(h, w)) < 0.15] = 0
    ids[(np.arange(h)[:, None] + np.arange(w)[None, :]) % 3 == 0] *= 2
    d = [[60.0, 30.0, 15.0], [20.0, 40.0, 10.0]] if wide else [[6.0, 3.0, 1.5], [2.0, 4.0, 1.0]]
    mat = sj.BurleyMaterial(albedo=[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], d_mm=d)
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.asarray(depth), material_id=jnp.asarray(ids))
    valid = ids > 0
    dpix = np.where(valid[..., None], np.asarray(d)[np.maximum(ids - 1, 0)], 0.0)
    ppm = np.where(valid, CAM.focal_px / (depth * 10.0), 0.0)
    return b, mat, e, depth, valid, dpix, ppm


OPTIONS = [dict(pattern="rotated", border="leaves", frames=1, interpolation="bilinear", seed=0),
           dict(pattern="fixed", border="renormalise", frames=1, interpolation="nearest", seed=0),
           dict(pattern="rotated", border="renormalise", frames=2, interpolation="bilinear", seed=11),
           dict(pattern="fixed", border="leaves", frames=2, interpolation="nearest", seed=5)]


@pytest.mark.parametrize("impl", ["compacted", "gather", "pallas"])
@pytest.mark.parametrize("opts", OPTIONS, ids=lambda o: "-".join(str(v) for v in o.values()))
@pytest.mark.parametrize("wide", [False, True], ids=["narrow", "wide"])
def test_burley_matches_the_numpy_loop(impl, opts, wide):
    b, mat, e, depth, valid, dpix, ppm = _case(wide=wide)
    got = np.asarray(sj.burley(b, mat, CAM, samples=6, impl=impl, **opts))
    # the pass samples truncated where the widest active profile has more than 1e-4 of its energy beyond the
    # frame's diagonal (its documented rule)
    truncate = bool(_ccdf(np.hypot(*depth.shape) / (dpix.max(-1) * ppm)[valid].max()) > 1e-4)
    expected = numpy_burley(e, depth, valid, dpix, ppm, 6, 10.0, linear=opts["interpolation"] == "bilinear",
                            rotated=opts["pattern"] == "rotated", frames=opts["frames"], seed=opts["seed"],
                            leaves=opts["border"] == "leaves", truncate=truncate)
    np.testing.assert_allclose(got, expected, rtol=1e-7, atol=1e-9)
    assert np.abs(expected - e)[valid].max() > 0.05  # it scattered


@pytest.mark.parametrize("impl", ["compacted", "gather"])
@pytest.mark.parametrize("opts", OPTIONS[:2], ids=["rotated-leaves", "fixed-renormalise"])
def test_a_tile_with_its_halo_gives_the_untiled_frames_pixels(impl, opts):
    b, mat, *_ = _case(h=32, w=44, seed=9)
    frame = np.asarray(sj.burley(b, mat, CAM, samples=6, impl=impl, **opts))
    halo_px = lambda fetch: sj._techniques._burley.burley_halo_px(b, mat, CAM, samples=6, interpolation=fetch)
    halo = halo_px(opts["interpolation"])
    r0, r1, c0, c1 = 13, 19, 18, 26  # the tile, its halo inside the frame
    assert halo < 13
    # one reach: the batch's tiles take the technique's (before, it added one pixel for the bilinear footprint and
    # this two, whatever the fetch); a bilinear fetch reaches one pixel further than a nearest one
    assert sj.technique("burley", samples=6, **opts).reach_px(b, mat, CAM) == halo
    assert halo_px("bilinear") == halo_px("nearest") + 1
    a0, a1, b0, b1 = r0 - halo, r1 + halo, c0 - halo, c1 + halo
    crop = jax_tree_crop(b, a0, a1, b0, b1)
    tile = np.asarray(sj.burley(crop, mat, CAM, samples=6, impl=impl, origin=(a0, b0), frame_shape=(32, 44), **opts))
    diff = np.abs(tile[r0 - a0:r1 - a0, c0 - b0:c1 - b0] - frame[r0:r1, c0:c1]).max()
    assert diff <= 1e-4
    # without the origin the tile's rotations are its own: other pixels (the fixed spiral with the renormalised
    # border depends on nothing of the frame: the same pixels)
    alone = np.asarray(sj.burley(crop, mat, CAM, samples=6, impl=impl, **opts))
    if opts["pattern"] == "rotated":
            assert np.abs(alone[r0 - a0:r1 - a0, c0 - b0:c1 - b0] - frame[r0:r1, c0:c1]).max() > 1e-3


def test_a_tile_told_the_pixels_it_keeps_computes_only_those(monkeypatch, as_users_run_it):
    # a batch's tile computed its halo as well as the pixels it keeps (a 3840x2160 close-up through burley: 15 tiles
    # of mostly halo, 28 s against 7.5 s for the frame whole): told them (``keep``), the compacted formulation
    # computes only those, the same values, and leaves the halo its local shading
    import sss_jax._techniques._burley as B

    b, mat, e, *_ = _case(h=32, w=44, seed=9)
    opts = OPTIONS[0]
    frame = np.asarray(sj.burley(b, mat, CAM, samples=6, **opts))
    halo = B.burley_halo_px(b, mat, CAM, samples=6)
    r0, r1, c0, c1 = 13, 19, 18, 26
    a0, a1, b0, b1 = r0 - halo, r1 + halo, c0 - halo, c1 + halo
    crop = jax_tree_crop(b, a0, a1, b0, b1)
    capacities = []
    real = B._burley_impl
    monkeypatch.setattr(B, "_burley_impl", lambda *a, **k: capacities.append(a[6]) or real(*a, **k))
    keep = (r0 - a0, c0 - b0, r1 - r0, c1 - c0)
    tile = np.asarray(sj.burley(crop, mat, CAM, samples=6, impl="compacted", origin=(a0, b0), frame_shape=(32, 44),
                                keep=keep, **opts))
    kept = np.zeros(tile.shape[:2], bool)
    kept[r0 - a0:r1 - a0, c0 - b0:c1 - b0] = True
    np.testing.assert_allclose(tile[kept].reshape(r1 - r0, c1 - c0, 3), frame[r0:r1, c0:c1], rtol=0, atol=1e-4)
    np.testing.assert_array_equal(tile[~kept], e[a0:a1, b0:b1][~kept])  # local shading: albedo 1, the irradiance
    # the slots held the window's 48 pixels (the smallest bucket, 256), not the crop's active pixels
    assert capacities == [256] and B.burley_active_count(crop, mat, CAM) > 256
    for bad in ((0, 0, 0, 5), (0, 0, 1), (True, 0, 1, 1), (0, 0, 1000, 1), (0.5, 0, 1, 1), "all"):
        with pytest.raises(ValueError, match="keep"):
            sj.burley(crop, mat, CAM, samples=6, keep=bad)


def test_a_tiles_slots_are_a_fraction_of_its_kept_window(monkeypatch):
    # each tile's active count went into the next quarter-octave bucket, so a frame's tiles compiled a program each
    # (a 3840x2160 close-up's 15 tiles: 8 programs, 10.0-10.8 s; with these sizes 3 programs, 6.6-7.4 s, the frame
    # whole 7.5 s): a tile's slots are an eighth, a quarter, half or all of its kept window (at least 256)
    import jax.numpy as jnp

    import sss_jax._techniques._burley as B

    assert [B.kept_capacity(c, 3840, 20000) for c in (0, 480, 481, 960, 961, 1920, 1921, 3840)] == \
        [480, 480, 960, 960, 1920, 1920, 3840, 3840]
    assert B.kept_capacity(1921, 3840, 6144) is None  # the slots would hold half the buffer: dense
    h, w = 96, 128
    capacities = []
    real = B._burley_impl
    monkeypatch.setattr(B, "_burley_impl", lambda *a, **k: capacities.append(a[6]) or real(*a, **k))
    mat = sj.BurleyMaterial([0.8, 0.6, 0.5], [1.0, 0.5, 0.3])
    for count in (300, 700, 1500):
        ids = np.zeros((h, w), np.int32)
        rows, cols = np.divmod(np.arange(count), 80)
        ids[8 + rows, 8 + cols] = 1  # the SSS pixels in the kept window (48x80 = 3840 px)
        b = sj.Buffers(irradiance=jnp.ones((h, w, 3)), depth=jnp.full((h, w), 50.0), material_id=jnp.asarray(ids))
        sj.burley(b, mat, CAM, samples=4, keep=(8, 8, 48, 80), min_footprint_px=0.0)
    assert capacities == [480, 960, 1920], capacities


def test_compacted_tiles_of_one_shape_share_one_program():
    # the compacted pass took a tile's origin as a static argument: a 3840x2160 frame's 15 tiles compiled 15 programs
    # (~11 s of a 19-s frame); traced, the tiles of one shape and bucket compile once
    import jax.monitoring

    b, mat, *_ = _case(h=32, w=44, seed=9)
    run = lambda r, c: jax.block_until_ready(sj.burley(jax_tree_crop(b, r, r + 16, c, c + 20), mat, CAM, samples=6,
                                                       impl="compacted", compact=True, origin=(r, c),
                                                       frame_shape=(32, 44)))
    run(0, 0)
    compiles = []
    listener = lambda name, seconds, **kw: compiles.append(name) if "compile" in name else None
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        for r, c in ((16, 0), (0, 24), (16, 24), (7, 11)):
            run(r, c)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiles == []


def jax_tree_crop(b, a0, a1, b0, b1):
    return sj.Buffers(irradiance=b.irradiance[a0:a1, b0:b1], depth=b.depth[a0:a1, b0:b1],
                      material_id=b.material_id[a0:a1, b0:b1])


@pytest.mark.parametrize("impl", ["compacted", "gather", "pallas"])
def test_a_channel_far_narrower_than_the_widest_keeps_its_weights_in_float32(impl):
    # d_B = 0.0022 mm beside d_max = 6 mm: the nearest of 6 samples lies ~1 mm out (0.17 d_max), where B's profile
    # weighs exp(-1 / (3 0.0022)) = e^-150 of its value at 0, below float32's smallest normal (1.2e-38, e^-87).
    # Before the weights were shifted by the nearest sample's exponent (``weight_offset``) every B weight rounded to
    # 0 and B kept the pixel's own irradiance (or, nearer the limit, its products with the irradiance flushed to 0
    # while its weights did not: a black channel). The float64 loop holds e^-150 without trouble: B is the irradiance
    # where sample 0 lands (the farther samples weigh e^-350 and less of it). Flat depth: the fall-off across a
    # depth step would take B's weights below float32's range too, which no shift of the in-plane exponent helps.
    b, mat, e, depth, valid, dpix, ppm = _case()
    depth = np.full(depth.shape, 50.0)
    d = [[6.0, 3.0, 0.0022], [5.0, 4.0, 0.002]]
    mat = sj.BurleyMaterial(albedo=[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], d_mm=d)
    b = sj.Buffers(irradiance=jnp.asarray(e, jnp.float32), depth=jnp.asarray(depth, jnp.float32),
                   material_id=b.material_id)
    dpix = np.where(valid[..., None], np.asarray(d)[np.maximum(np.asarray(b.material_id) - 1, 0)], 0.0)
    ppm = np.where(valid, CAM.focal_px / (depth * 10.0), 0.0)
    opts = OPTIONS[0]
    got = np.asarray(sj.burley(b, mat, CAM, samples=6, impl=impl, **opts))
    assert got.dtype == np.float32
    truncate = bool(_ccdf(np.hypot(*depth.shape) / (dpix.max(-1) * ppm)[valid].max()) > 1e-4)
    expected = numpy_burley(e, depth, valid, dpix, ppm, 6, 10.0, linear=True, rotated=True, frames=1, seed=0,
                            leaves=True, truncate=truncate)
    np.testing.assert_allclose(got, expected, rtol=2e-5, atol=2e-5)
    assert np.abs(expected - e)[valid][:, 2].max() > 0.05  # B is not the pixel's own irradiance


def test_tile_arguments_are_checked(as_users_run_it):
    b, mat, *_ = _case()
    with pytest.raises(ValueError, match="does not lie inside frame_shape"):
        sj.burley(b, mat, CAM, origin=(5, 0), frame_shape=(12, 12))
    with pytest.raises(ValueError, match="origin must be a pair of integers"):
        sj.burley(b, mat, CAM, origin=(0.5, 0))


# ------------------------------------------------------------------------------------------------------------------
# separable (SSSS): an independent NumPy loop of the two 1D passes, against the banded, gather and Pallas layouts
# ------------------------------------------------------------------------------------------------------------------
#
# Written from the formulas (Jimenez et al. 2015, and this package's documented rules), pixel by pixel in float64: taps
# at ``range sign(o) o^2`` (o evenly spaced in [-1, 1], SeparableSSS::calculateKernel), each weighing the kernel's mass
# over its cell (half way to its neighbours, the outer cells to infinity); the two-Gaussian kernel's masses from erf,
# the pre-integrated Burley kernel's from the density of its 1D marginal, (K0(|x|/d) + K0(|x|/3d)) / (4 pi d), by
# adaptive quadrature (the reach by bisection on the CDF); a fetch counts as far as it is valid and, following the
# surface, 1 - |dz| mm_per_unit / range; off the frame it is dark (border "leaves") or the centre ("renormalise"); a
# kernel whose outer cell ends past the frame's extent is shrunk onto the frame, tap i weighing the kernel's mass over
# its shrunk cell, renormalised to the full total with "renormalise". That mass is re-integrated from the kernel's own
# profile (each kernel below gives its mass over [0, x]), tabulated as the spec says: at 0, then at edge 10^(-i/32) for
# i = 256 ... 0 (edge: where the outer cells end), half the weights' total at the edge, linear between the knots, the
# first positive knot's value from 0 on (Burley's masses from the K0 density of its marginal, scipy's quadrature).
# Nothing of sss_jax's kernels or passes is called.

from math import erf

from scipy import integrate
from scipy.special import k0


def _sorted_unit(taps):
    o = np.linspace(-1.0, 1.0, taps) if taps > 1 else np.zeros(1)
    return np.sign(o) * o ** 2


def _cells(taps):
    """Cell boundaries of the ascending taps (unit offsets): infinite outer ones for the kernel's masses, and the
    finite ones the frame cut uses (outer cells as wide beyond the last tap as inside it)."""
    u = _sorted_unit(taps)
    if taps == 1:
        return np.array([-np.inf, np.inf]), np.array([-0.5, 0.5])
    mids = 0.5 * (u[1:] + u[:-1])
    outer = 2 * u[-1] - mids[-1]
    return np.concatenate([[-np.inf], mids, [np.inf]]), np.concatenate([[-outer], mids, [outer]])


def _two_gaussian_taps(w, s_near, s_far, taps):
    """(offsets_mm (n,) ascending, weights (n, 3), half) of w G(s_near) + (1 - w) G(s_far), range 3 max(sigma);
    ``half(u)``: the kernel's mass over [0, u range] at unit positions ``u (K,)``, ``(K, 3)``."""
    reach = 3 * max(max(s_near), max(s_far))
    inf_cells, _ = _cells(taps)

    def phi(x, s):
        if not np.isfinite(x) or s == 0:
            return float(x > 0) if x != 0 else 0.5
        return 0.5 * (1 + erf(x / (s * np.sqrt(2))))

    mass = lambda lo, hi, c: (w[c] * (phi(hi, s_near[c]) - phi(lo, s_near[c]))
                              + (1 - w[c]) * (phi(hi, s_far[c]) - phi(lo, s_far[c])))
    weights = np.array([[mass(lo, hi, c) for c in range(3)]
                        for lo, hi in zip(reach * inf_cells[:-1], reach * inf_cells[1:])])
    total = weights.sum(0)
    half = lambda u: np.array([[mass(0.0, x * reach, c) for c in range(3)] for x in u]) / total
    return reach * _sorted_unit(taps), weights / total, half


def _burley_radius(u, d):
    """r with CDF(r) = u for Burley's 1 - (exp(-r/d) + 3 exp(-r/3d)) / 4, by bisection."""
    lo, hi = np.zeros_like(u), np.full_like(u, 200.0 * d)
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        below = 1 - (np.exp(-mid / d) + 3 * np.exp(-mid / (3 * d))) / 4 < u
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _burley_taps(d, taps):
    """The pre-integrated kernel: range = the radius holding 99% of the widest channel's energy; each tap the exact
    mass of the 1D marginal over its cell (its density is (K0(|x|/d) + K0(|x|/3d)) / (4 pi d), by adaptive
    quadrature); ``half(u)``: the mass over [0, u range]."""
    reach = _burley_radius(np.array([0.99]), max(d))[0]
    inf_cells, _ = _cells(taps)
    density = lambda t, dc: (k0(t / dc) + k0(t / (3 * dc))) / (4 * np.pi * dc)

    def mass(x, dc):  # over [0, |x|], signed
        if dc == 0 or not np.isfinite(x):
            return 0.5 * np.sign(x) if x != 0 else 0.0
        return np.sign(x) * integrate.quad(density, 0, abs(x), args=(dc,), limit=400, epsabs=1e-15, epsrel=1e-13)[0]

    weights = np.array([[mass(hi, d[c]) - mass(lo, d[c]) for c in range(3)]
                        for lo, hi in zip(reach * inf_cells[:-1], reach * inf_cells[1:])])
    total = weights.sum(0)
    half = lambda units: np.array([[mass(x * reach, d[c]) for c in range(3)] for x in units]) / total
    return reach * _sorted_unit(taps), weights / total, half


def _cut_knots(taps):
    """The spec's knots (unit positions): 0, then edge 10^(-i/32), i = 256 ... 0."""
    return np.concatenate([[0.0], _cells(taps)[1][-1] * 10.0 ** (np.arange(-256, 1) / 32)])


def _cut_table(weights, half, taps):
    """(K + 1, 3): 0 at 0, the kernel's masses over [0, x] at the inner knots, half its weights' total at the edge."""
    knots = _cut_knots(taps)
    return np.concatenate([np.zeros((1, 3)), half(knots[1:-1]), weights.sum(0)[None] / 2])


def _cut_kernel(offsets_px, weights, table, extent, leaves):
    """The kernel shrunk onto the frame's extent where its outer cell ends past it (see the section's comment);
    ``table``: ``_cut_table``'s, or a function giving it (built only where the kernel is cut)."""
    taps = offsets_px.shape[0]
    reach = np.abs(offsets_px).max()
    _, cells = _cells(taps)
    if reach * cells[-1] <= extent:
        return offsets_px, weights
    s = extent / (reach * cells[-1])
    knots, values = _cut_knots(taps), table() if callable(table) else table

    def cumulative(x):  # the mass over [0, x] (negative below 0) at unit position x, linear between the knots
        a = abs(x)
        if a < knots[1]:
            return np.sign(x) * values[1]
        j = min(np.searchsorted(knots, a, side="right") - 1, knots.size - 2)
        return np.sign(x) * (values[j] + (values[j + 1] - values[j]) * (a - knots[j]) / (knots[j + 1] - knots[j]))

    cut = np.array([cumulative(s * cells[k + 1]) - cumulative(s * cells[k]) for k in range(taps)])
    if not leaves:
        cut = cut * weights.sum(0) / cut.sum(0)
    return offsets_px * s, cut


def numpy_separable(e, z, valid, rows, kernels, ppm, mm_per_unit, albedo, *, linear, follow, leaves,
                    pre_post=False, origin=(0, 0), frame_shape=None, footprint=0.5):
    """Both passes pixel by pixel; ``kernels[m] = (offsets_mm ascending, weights (n, 3), half)`` (``half`` as
    ``_two_gaussian_taps``'); ``albedo (M, 3)``."""
    h, w = z.shape
    tables = {}  # each kernel's cut table, built where it is first cut

    def table(m):
        if m not in tables:
            tables[m] = _cut_table(kernels[m][1], kernels[m][2], kernels[m][1].shape[0])
        return tables[m]

    frame_shape = frame_shape or (h, w)
    a = np.where(valid[..., None], albedo[rows], 1.0)
    x = np.where(valid[..., None], e * (np.sqrt(a) if pre_post else 1.0), 0.0)
    for axis in (1, 0):  # horizontal (along columns), then vertical
        src, out = x.copy(), x.copy()
        length, extent, start = (w, frame_shape[1], origin[1]) if axis == 1 else (h, frame_shape[0], origin[0])
        for py in range(h):
            for px in range(w):
                offsets_mm, weights, _ = kernels[rows[py, px]]
                reach_mm = np.abs(offsets_mm).max()
                if not valid[py, px] or reach_mm * ppm[py, px] < footprint:
                    continue
                offs, wts = _cut_kernel(offsets_mm * ppm[py, px], weights, lambda m=rows[py, px]: table(m), extent,
                                        leaves)
                here = px if axis == 1 else py
                acc = np.zeros(3)
                for off, wt in zip(offs, wts):
                    pos = here + off
                    corners = ([(int(np.floor(pos)), 1 - (pos - np.floor(pos))),
                                (int(np.floor(pos)) + 1, pos - np.floor(pos))] if linear
                               else [(int(np.round(pos)), 1.0)])
                    sample = src[py, px].copy()
                    for q, f in corners:
                        if not 0 <= q + start < extent:  # off the frame
                            if leaves:
                                sample -= f * src[py, px]
                            continue
                        if not 0 <= q < length:  # in the frame, not in this buffer: counts as the centre
                            continue
                        qy, qx = (py, q) if axis == 1 else (q, px)
                        if not valid[qy, qx]:
                            continue
                        keep = 1 - min(abs(z[qy, qx] - z[py, px]) * mm_per_unit / reach_mm, 1.0) if follow else 1.0
                        sample += f * keep * (src[qy, qx] - src[py, px])
                    acc += wt * sample
                out[py, px] = acc
        x = out
    result = x * (np.sqrt(a) if pre_post else a)
    return np.where(valid[..., None], result, e)


SEP_CAM = sj.Camera(focal_px=100.0, mm_per_unit=10.0)


def _separable_case(kind, *, h=12, w=16, seed=4, jitter=True, wide=False):
    """A depth step (two planes, jittered per pixel for the layouts that follow each pixel's reach), holes (id 0)
    and two materials whose kernels share one reach (mm) but not their weights, so the banded levels meet exactly
    two reaches on the unjittered step (one per plane) and are exact there."""
    rng = np.random.default_rng(seed)
    e = rng.uniform(0.0, 2.0, (h, w, 3))
    depth = 47.3 + 5.0 * (np.arange(w)[None, :] >= w // 2) + (rng.uniform(0.0, 1.0, (h, w)) if jitter else 0.0)
    depth = depth * np.ones((h, 1))
    ids = np.ones((h, w), np.int32)
    ids[(np.arange(h)[:, None] + 2 * np.arange(w)[None, :]) % 5 == 0] = 2
    ids[rng.uniform(size=(h, w)) < 0.12] = 0
    albedo = np.array([[0.9, 0.7, 0.5], [0.6, 0.8, 1.0]])
    scale = 10.0 if wide else 0.5
    if kind == "two_gaussian":
        w_, sn, sf = [[0.6, 0.5, 0.4], [0.3, 0.7, 0.5]], [[4.0, 2.0, 1.0], [1.0, 3.0, 2.0]], [[20.0, 10.0, 6.0],
                                                                                             [8.0, 20.0, 12.0]]
        sn, sf = (np.asarray(s) * scale for s in (sn, sf))
        mat = sj.TwoGaussianMaterial(albedo=albedo, w=w_, sigma_near_mm=sn, sigma_far_mm=sf)
        taps = lambda n: [_two_gaussian_taps(w_[m], sn[m], sf[m], n) for m in range(2)]
    else:
        d = np.array([[6.0, 3.0, 1.5], [2.0, 6.0, 1.0]]) * scale
        mat = sj.BurleyMaterial(albedo=albedo, d_mm=d)
        taps = lambda n: [_burley_taps(d[m], n) for m in range(2)]
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.asarray(depth), material_id=jnp.asarray(ids))
    valid = ids > 0
    return b, mat, taps, dict(e=e, z=depth, valid=valid, rows=np.maximum(ids - 1, 0), albedo=albedo,
                              ppm=SEP_CAM.focal_px / (depth * 10.0), mm_per_unit=10.0)


# each option set with one material kind, narrow or wide (the kernel cut at the frame), against every layout
SEP_CASES = [("burley", False, dict(border="leaves", interpolation="linear", follow_surface=True, albedo_mode="post",
                                    taps=7)),
             ("two_gaussian", True, dict(border="renormalise", interpolation="nearest", follow_surface=True,
                                         albedo_mode="pre_post", taps=5)),
             ("burley", True, dict(border="renormalise", interpolation="linear", follow_surface=False,
                                   albedo_mode="post", taps=9)),
             ("two_gaussian", False, dict(border="leaves", interpolation="nearest", follow_surface=False,
                                          albedo_mode="post", taps=5))]


@pytest.mark.parametrize("impl", ["banded", "gather", "pallas"])
@pytest.mark.parametrize("kind,wide,opts", SEP_CASES,
                         ids=lambda v: "-".join(str(x) for x in v.values()) if isinstance(v, dict) else str(v))
def test_separable_matches_the_numpy_loop(impl, kind, wide, opts):
    # the banded layout's reach levels are exact where the frame holds two reaches (levels at its least and its
    # largest): the unjittered step; the whole-frame layouts follow each pixel's own reach (jittered depths)
    b, mat, taps, ref = _separable_case(kind, jitter=impl != "banded", wide=wide)
    got = np.asarray(sj.separable(b, mat, SEP_CAM, impl=impl, **opts))
    expected = numpy_separable(ref["e"], ref["z"], ref["valid"], ref["rows"], taps(opts["taps"]), ref["ppm"],
                               ref["mm_per_unit"], ref["albedo"], linear=opts["interpolation"] == "linear",
                               follow=opts["follow_surface"], leaves=opts["border"] == "leaves",
                               pre_post=opts["albedo_mode"] == "pre_post")
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
    local = ref["albedo"][ref["rows"]] * ref["e"]
    assert np.abs(expected - local)[ref["valid"]].max() > 0.05  # it scattered
    reach_px = max(np.abs(k[0]).max() for k in taps(opts["taps"])) * ref["ppm"].max()
    edge_px = reach_px * _cells(opts["taps"])[1][-1]
    assert edge_px > 16 if wide else edge_px < 12  # wide: the widest kernel cut at the frame, else none

# The reference: an independent NumPy loop of the dense pixel-integrated convolution (the paper's ground truth)
# ------------------------------------------------------------------------------------------------------------------
# Written from the formulas: Christensen & Burley 2015's normalised R(r) = (exp(-r/d) + exp(-r/3d)) / (8 pi d r) and
# its CDF 1 - (exp(-r/d) + 3 exp(-r/3d))/4; a Gaussian sum R(r) = sum w_k exp(-r^2/2v_k) / (2 pi v_k) / sum w_k. The
# centre pixel's mass is the profile's integral over the pixel's square, in polar coordinates around the centre
# (scipy's adaptive quadrature of CDF(a / cos t)); a neighbour's is the midpoint rule the reference documents
# (near_subsamples^2 points within two pixels, 2x2 within six, one beyond) at the 3D distance; with the leaving
# border the energy beyond the frame is 1 - (1/2pi) int CDF(distance to the frame's edge along phi) dphi (scipy, the
# corner angles as break points), not the package's triangle rule. Nothing of sss_jax is called.



def _burley_radial(d):
    d = np.asarray(d, np.float64)

    def radial(r):  # r (n,) -> (n, 3)
        ok = d > 0
        dd = np.where(ok, d, 1.0)
        r = np.asarray(r, np.float64)[:, None]
        return np.where(ok, (np.exp(-r / dd) + np.exp(-r / (3 * dd))) / (8 * np.pi * dd * r), 0.0)

    def cdf(r):
        ok = d > 0
        dd = np.where(ok, d, 1.0)
        return np.where(ok, 1 - (np.exp(-r / dd) + 3 * np.exp(-r / (3 * dd))) / 4, 1.0)

    return radial, cdf


def _gaussian_radial(weights, variances):
    w = np.asarray(weights, np.float64) / np.sum(weights, axis=0)  # (K, 3), normalised per channel
    v = np.asarray(variances, np.float64)
    radial = lambda r: np.sum(w * np.exp(-np.asarray(r)[:, None, None] ** 2 / (2 * v)) / (2 * np.pi * v), axis=1)
    cdf = lambda r: np.sum(w * (1 - np.exp(-r * r / (2 * v))), axis=0)
    return radial, cdf


def _energy_inside_frame(cdf, y, x, fh, fw, pixel_mm):
    """Fraction of the profile centred on (y, x) inside the frame [-0.5, fh - 0.5] x [-0.5, fw - 0.5] (px)."""
    def reach(phi):
        c, s = np.cos(phi), np.sin(phi)
        tx = (fw - 0.5 - x) / c if c > 1e-15 else ((-0.5 - x) / c if c < -1e-15 else np.inf)
        ty = (fh - 0.5 - y) / s if s > 1e-15 else ((-0.5 - y) / s if s < -1e-15 else np.inf)
        return min(tx, ty) * pixel_mm

    corners = sorted(np.mod(np.arctan2(cy - y, cx - x), 2 * np.pi)
                     for cy in (-0.5, fh - 0.5) for cx in (-0.5, fw - 0.5))
    edges = [0.0] + corners + [2 * np.pi]
    total = sum(integrate.quad_vec(lambda p: cdf(reach(p)), a, b, epsabs=1e-12, epsrel=1e-10)[0]
                for a, b in zip(edges[:-1], edges[1:]) if b > a)
    return total / (2 * np.pi)


def numpy_reference(e, z, valid, profiles, albedo, ppm, mm_per_unit, k, *, near, leaves, pre_post=False,
                    origin=(0, 0), frame_shape=None):
    """``profiles[y][x]``: (radial, cdf) of the pixel's material; ``albedo (H, W, 3)``. The result of every pixel."""
    h, w = z.shape
    fh, fw = frame_shape or (h, w)
    root = np.sqrt(albedo) if pre_post else None
    src = e * root if pre_post else e
    out = np.array(e, np.float64)
    for y in range(h):
        for x in range(w):
            if not valid[y, x]:
                continue
            radial, cdf = profiles[y][x]
            pixel_mm = 1.0 / ppm[y, x]
            a = 0.5 * pixel_mm
            centre = 8 * integrate.quad_vec(lambda t: cdf(a / np.cos(t)), 0, np.pi / 4, epsabs=1e-13,
                                            epsrel=1e-11)[0] / (2 * np.pi)
            num, den = centre * src[y, x], centre.copy()
            if leaves:
                den += 1 - _energy_inside_frame(cdf, y + origin[0], x + origin[1], fh, fw, pixel_mm)
            for dy in range(-k, k + 1):
                for dx in range(-k, k + 1):
                    ring = max(abs(dy), abs(dx))
                    qy, qx = y + dy, x + dx
                    if ring == 0 or not (0 <= qy < h and 0 <= qx < w and valid[qy, qx]):
                        continue
                    sub = near if ring <= 2 else (2 if ring <= 6 else 1)
                    f = (np.arange(sub) + 0.5) / sub - 0.5
                    oy, ox = np.meshgrid(dy + f, dx + f, indexing="ij")
                    dz = (z[qy, qx] - z[y, x]) * mm_per_unit
                    r = np.sqrt((oy * oy + ox * ox) * pixel_mm ** 2 + dz * dz).ravel()
                    mass = radial(r).sum(axis=0) * pixel_mm ** 2 / sub ** 2
                    num, den = num + mass * src[qy, qx], den + mass
            scattered = np.where(den > 0, num / np.where(den > 0, den, 1.0), src[y, x])
            out[y, x] = (root[y, x] if pre_post else albedo[y, x]) * scattered
    return out


def _reference_case(kind, h=7, w=9, seed=4, d_scale=1.0):
    rng = np.random.default_rng(seed)
    e = rng.uniform(0.0, 2.0, (h, w, 3))
    depth = 50.0 + 2.0 * (np.arange(w)[None, :] >= 5) + rng.uniform(0.0, 0.3, (h, w))  # a 20 mm depth step
    ids = np.ones((h, w), np.int32)
    if kind == "gaussian":
        weights, variances = [[0.3, 0.5, 0.6], [0.7, 0.5, 0.4]], [[4.0, 2.0, 1.0], [60.0, 30.0, 8.0]]  # mm^2
        mat = sj.ProfileMaterial(sj.GaussianSumProfile(weights, variances), albedo=[0.9, 0.7, 0.5])
        table = [(_gaussian_radial(weights, variances), [0.9, 0.7, 0.5])]
    else:
        d = [[15.0, 8.0, 4.0], [5.0, 10.0, 3.0]] if kind == "two" else [[12.0, 6.0, 3.0]]
        d = [[v * d_scale for v in row] for row in d]
        albedo = [[0.8, 0.6, 0.5], [0.5, 0.9, 0.7]][:len(d)]
        mat = sj.BurleyMaterial(albedo=albedo, d_mm=d)
        table = [(_burley_radial(row), a) for row, a in zip(d, albedo)]
        if kind == "two":
            ids[(np.arange(h)[:, None] + np.arange(w)[None, :]) % 3 == 0] = 2
            ids[rng.uniform(size=(h, w)) < 0.12] = 0  # pixels without SSS pass through, and pass no light on
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.asarray(depth), material_id=jnp.asarray(ids))
    valid = ids > 0
    rows = np.maximum(ids - 1, 0)
    profiles = [[table[rows[y, x]][0] for x in range(w)] for y in range(h)]
    albedo = np.asarray([t[1] for t in table], np.float64)[rows]
    ppm = CAM.focal_px / (depth * CAM.mm_per_unit)
    return b, mat, e, depth, valid, profiles, albedo, ppm


REFERENCE_OPTIONS = [("two", dict(border="leaves", albedo_mode="post", near_subsamples=3)),
                     ("two", dict(border="renormalise", albedo_mode="pre_post", near_subsamples=2)),
                     ("one", dict(border="leaves", albedo_mode="pre_post", near_subsamples=4)),
                     ("gaussian", dict(border="leaves", albedo_mode="post", near_subsamples=2))]


@pytest.mark.parametrize("kind, opts", REFERENCE_OPTIONS,
                         ids=lambda v: v if isinstance(v, str) else "-".join(str(x) for x in v.values()))
def test_reference_matches_the_numpy_loop(kind, opts):
    b, mat, e, depth, valid, profiles, albedo, ppm = _reference_case(kind)
    k = 8  # the window spans the frame; every tier of the midpoint rule (within 2, within 6, beyond) takes part
    got = np.asarray(sj.reference(b, mat, CAM, radius_px=k, **opts))
    expected = numpy_reference(e, depth, valid, profiles, albedo, ppm, CAM.mm_per_unit, k,
                               near=opts["near_subsamples"], leaves=opts["border"] == "leaves",
                               pre_post=opts["albedo_mode"] == "pre_post")
    np.testing.assert_allclose(got, expected, rtol=2e-6, atol=1e-9)
    assert np.abs(expected - albedo * e)[valid].max() > 0.05  # it scattered
    if kind == "two":
        np.testing.assert_array_equal(got[~valid], e[~valid])  # no SSS: untouched


@pytest.mark.parametrize("border", ["renormalise", "leaves"])
def test_a_reference_tile_with_its_halo_gives_the_untiled_frames_pixels(border):
    # a tile cut with a halo of the technique's reach (the window of the frame), told its place: the frame's pixels
    b, mat, e, _, valid, _, albedo, _ = _reference_case("two", h=20, w=24, seed=8, d_scale=0.1)
    tech = sj.Reference(border=border, near_subsamples=2)
    halo = tech.reach_px(b, mat, CAM)  # the default window on the whole frame
    assert 2 <= halo < 8
    tech = tech.replace(radius_px=halo)  # the frame's window, fixed for its tiles (a tile's own would differ)
    frame = np.asarray(tech(b, mat, CAM))
    np.testing.assert_array_equal(frame, np.asarray(sj.Reference(border=border, near_subsamples=2)(b, mat, CAM)))
    for r0, r1, c0, c1 in [(7, 13, 8, 16), (0, 6, 16, 24)]:  # inside; and at the frame's corner (one shape)
        a0, a1, b0, b1 = max(r0 - halo, 0), min(r1 + halo, 20), max(c0 - halo, 0), min(c1 + halo, 24)
        crop = jax_tree_crop(b, a0, a1, b0, b1)
        tile = np.asarray(tech(crop, mat, CAM, origin=(a0, b0), frame_shape=(20, 24)))
        # the same arithmetic as the frame's (the goal is 1e-4): exact to rounding
        assert np.abs(tile[r0 - a0:r1 - a0, c0 - b0:c1 - b0] - frame[r0:r1, c0:c1]).max() <= 1e-10
        # told the pixels it keeps (keep=, as a batch's tiles are), it computes only those: the same values there,
        # and the local shading (albedo times irradiance on SSS pixels, the irradiance elsewhere) in its halo
        keep = (r0 - a0, c0 - b0, r1 - r0, c1 - c0)
        kept = np.asarray(tech(crop, mat, CAM, origin=(a0, b0), frame_shape=(20, 24), keep=keep))
        inside = np.zeros(kept.shape[:2], bool)
        inside[keep[0]:keep[0] + keep[2], keep[1]:keep[1] + keep[3]] = True
        assert np.abs(kept[inside] - tile[inside]).max() <= 1e-12
        local = np.where(valid[..., None], albedo * e, e)[a0:a1, b0:b1]
        np.testing.assert_allclose(kept[~inside], local[~inside], rtol=1e-12)
    # told another place, the leaving border moves (the renormalised one depends on nothing of the frame)
    moved = np.asarray(tech(crop, mat, CAM, origin=(a0 + 1, b0), frame_shape=(20, 24)))
    shift = np.abs(moved[r0 - a0:r1 - a0, c0 - b0:c1 - b0] - frame[r0:r1, c0:c1]).max()
    assert shift > 1e-6 if border == "leaves" else shift <= 1e-10


def test_a_reference_tile_told_the_pixels_it_keeps_computes_only_those(as_users_run_it):
    # a batch's reference tile computed its halo too (the window's radius on every side): told the pixels it keeps,
    # XLA's cost model of the compiled pass falls with them (a quarter of the pixels kept: under half the flops)
    b, mat, *_ = _reference_case("one", h=24, w=32)
    tech = sj.Reference(radius_px=4)
    cost = {}
    for keep in (None, (6, 8, 12, 16)):
        analysis = jax.jit(lambda b, keep=keep: tech(b, mat, CAM, keep=keep)).lower(b).compile().cost_analysis()
        cost[keep] = (analysis[0] if isinstance(analysis, list) else analysis)["flops"]
    assert cost[(6, 8, 12, 16)] < 0.5 * cost[None], cost
    for bad, message in (((0, 0, 0, 5), "not a non-empty window"), ((0, 0, 1), "four integers"),
                         ((20, 0, 5, 5), "not a non-empty window inside the 24x32 buffer")):
        with pytest.raises(ValueError, match=f"reference: keep.*{message}"):
            sj.reference(b, mat, CAM, radius_px=4, keep=bad)


def test_a_reference_tile_needs_the_frames_window(as_users_run_it):
    b, mat, *_ = _reference_case("one", h=12, w=12)
    crop = jax_tree_crop(b, 0, 6, 0, 6)
    with pytest.raises(ValueError, match="needs the frame's window, radius_px"):
        sj.reference(crop, mat, CAM, origin=(0, 0), frame_shape=(12, 12))
    with pytest.raises(ValueError, match="does not lie inside frame_shape"):
        sj.reference(crop, mat, CAM, radius_px=2, origin=(8, 0), frame_shape=(12, 12))

@pytest.mark.parametrize("impl", ["banded", "gather"])
@pytest.mark.parametrize("border", ["renormalise", "leaves"])
def test_a_separable_tile_with_its_halo_gives_the_untiled_frames_pixels(impl, border):
    # the frame 24x40, a depth step at column 20; the banded layout's levels are the reaches its buffer holds (the
    # least and the largest), so a tile gives the frame's pixels where it holds the frame's reaches: here both planes
    # (unjittered, two reaches), named explicitly ("auto" on a CPU refuses tiles: below); the gather follows each
    # pixel's own reach (jittered depths)
    b, mat, _, _ = _separable_case("burley", h=24, w=40, seed=7, jitter=impl == "gather")
    technique = sj.technique("separable", taps=9, impl=impl, border=border)
    frame = np.asarray(technique(b, mat, SEP_CAM))
    halo = technique.reach_px(b, mat, SEP_CAM)
    assert 5 <= halo <= 10
    # a tile on the frame's top edge, its other sides inside the frame: origin (0, c0 - halo)
    r0, r1, c0, c1 = 0, 5, 16, 24
    a0, a1, b0, b1 = max(r0 - halo, 0), r1 + halo, c0 - halo, c1 + halo
    crop = jax_tree_crop(b, a0, a1, b0, b1)
    tile = np.asarray(technique(crop, mat, SEP_CAM, origin=(a0, b0), frame_shape=(24, 40)))
    inner = (slice(r0 - a0, r1 - a0), slice(c0 - b0, c1 - b0))
    assert np.abs(tile[inner] - frame[r0:r1, c0:c1]).max() <= 1e-4
    if impl == "banded":  # what a batch meets: "auto" gives the same pixels tiled or not, so it refuses the tile
        with pytest.raises(ValueError, match="cannot place a tile"):
            sj.technique("separable", taps=9, border=border)(crop, mat, SEP_CAM, origin=(a0, b0), frame_shape=(24, 40))
    if border == "leaves" and impl == "gather":
        # the frame's border, not the buffer's: alone, the tile's inner sides are a border that light leaves
        alone = np.asarray(technique(crop, mat, SEP_CAM))
        assert np.abs(alone - tile).max() > 1e-3
