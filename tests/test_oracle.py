"""Independent NumPy loops of Burley's screen-space pass and of the reference, against every formulation and option,
and tiles.

The loop is written from the formulas (Christensen & Burley 2015's CDF ``1 - (exp(-r/d) + 3 exp(-r/3d))/4``, its
closed-form inverse, the golden-angle spiral, Wellons' lowbias32 hash for the per-pixel rotation), pixel by pixel
in float64; it calls nothing of sss_jax's internals.
"""

import numpy as np
import pytest
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
    halo = sj._techniques._burley.burley_halo_px(b, mat, CAM, samples=6)
    r0, r1, c0, c1 = 13, 19, 18, 26  # the tile, its halo inside the frame
    assert halo < 13
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


def jax_tree_crop(b, a0, a1, b0, b1):
    return sj.Buffers(irradiance=b.irradiance[a0:a1, b0:b1], depth=b.depth[a0:a1, b0:b1],
                      material_id=b.material_id[a0:a1, b0:b1])


def test_tile_arguments_are_checked(as_users_run_it):
    b, mat, *_ = _case()
    with pytest.raises(ValueError, match="does not lie inside frame_shape"):
        sj.burley(b, mat, CAM, origin=(5, 0), frame_shape=(12, 12))
    with pytest.raises(ValueError, match="origin must be a pair of integers"):
        sj.burley(b, mat, CAM, origin=(0.5, 0))


# ------------------------------------------------------------------------------------------------------------------
# The reference: an independent NumPy loop of the dense pixel-integrated convolution (the paper's ground truth)
# ------------------------------------------------------------------------------------------------------------------
# Written from the formulas: Christensen & Burley 2015's normalised R(r) = (exp(-r/d) + exp(-r/3d)) / (8 pi d r) and
# its CDF 1 - (exp(-r/d) + 3 exp(-r/3d))/4; a Gaussian sum R(r) = sum w_k exp(-r^2/2v_k) / (2 pi v_k) / sum w_k. The
# centre pixel's mass is the profile's integral over the pixel's square, in polar coordinates around the centre
# (scipy's adaptive quadrature of CDF(a / cos t)); a neighbour's is the midpoint rule the reference documents
# (near_subsamples^2 points within two pixels, 2x2 within six, one beyond) at the 3D distance; with the leaving
# border the energy beyond the frame is 1 - (1/2pi) int CDF(distance to the frame's edge along phi) dphi (scipy, the
# corner angles as break points), not the package's triangle rule. Nothing of sss_jax is called.

from scipy import integrate  # noqa: E402


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
    b, mat, *_ = _reference_case("two", h=20, w=24, seed=8, d_scale=0.1)
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
    # told another place, the leaving border moves (the renormalised one depends on nothing of the frame)
    moved = np.asarray(tech(crop, mat, CAM, origin=(a0 + 1, b0), frame_shape=(20, 24)))
    shift = np.abs(moved[r0 - a0:r1 - a0, c0 - b0:c1 - b0] - frame[r0:r1, c0:c1]).max()
    assert shift > 1e-6 if border == "leaves" else shift <= 1e-10


def test_a_reference_tile_needs_the_frames_window(as_users_run_it):
    b, mat, *_ = _reference_case("one", h=12, w=12)
    crop = jax_tree_crop(b, 0, 6, 0, 6)
    with pytest.raises(ValueError, match="needs the frame's window, radius_px"):
        sj.reference(crop, mat, CAM, origin=(0, 0), frame_shape=(12, 12))
    with pytest.raises(ValueError, match="does not lie inside frame_shape"):
        sj.reference(crop, mat, CAM, radius_px=2, origin=(8, 0), frame_shape=(12, 12))
