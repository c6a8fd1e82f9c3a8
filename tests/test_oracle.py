"""An independent NumPy loop of Burley's screen-space pass, against every formulation and option, and tiles.

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
