"""The engines' own passes (``hdrp``, ``eevee-next``, ``jimenez``) against independent NumPy ports of the shaders.

Each port below is written from the engine's source, pixel by pixel, with the engine's own formulations where the
technique uses another one: HDRP's closed-form ``SampleBurleyDiffusionProfile`` (the technique: sss_jax's
``burley_inverse_ccdf``), Blender's Newton iteration ``burley_sample`` (the technique: the closed form), Jimenez's
``calculateKernel`` in NumPy (``engines.jimenez_kernel``; the technique: a traced port) and explicit per-tap
bilinear fetches. Sources: Unity-Technologies/Graphics ``SubsurfaceScattering.compute`` (``EvaluateSss``,
``EvaluateSample``) and ``DiffusionProfile.hlsl``; blender/blender ``eevee_subsurface.cc``
(``precompute_samples_location``, ``burley_sample``, ``burley_eval``, ``burley_pdf``) and
``eevee_subsurface_convolve_comp.glsl``; iryoku/separable-sss ``SeparableSSS.h`` (``SSSSBlurPS``).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax._techniques._burley import spiral_rotation
from sss_jax._techniques._eevee_next import EeveeNextPass
from sss_jax._techniques._hdrp import HdrpPass
from sss_jax._techniques._jimenez import JimenezParams, JimenezPass
from sss_jax.engines import jimenez_kernel

SKIN = sj.BurleyMaterial([0.8, 0.5, 0.4], [3.0, 1.4, 0.8])
GOLDEN_RATIO = (1 + 5**0.5) / 2


# --- the ports ----------------------------------------------------------------------------------------------------


def hdrp_sample_profile(u, rcp_s):
    # DiffusionProfile.hlsl, SampleBurleyDiffusionProfile: closed-form inverse of Burley's CDF, and 1/pdf
    u = 1 - u
    g = 1 + 4 * u * (2 * u + math.sqrt(1 + 4 * u * u))
    n = g ** (-1 / 3)
    p = g * n * n
    c = 1 + p + n
    x = 3 * math.log(c / (4 * u))
    rcp_exp = c**3 / (4 * u * (c * c + 16 * u * u))
    return x * rcp_s, 8 * math.pi * rcp_s * rcp_exp


def hdrp_port(e, z, valid, albedo, d, focal, mm_per_unit, budget, phase):
    """EvaluateSss for every SSS pixel (HDRP: mmPerUnit = 1000 metersPerUnit / distScale; here the camera's)."""
    h, w, _ = e.shape
    out = e * albedo
    d_max = d.max()
    # UpdateKernel: filterRadius = the radius at CDF 0.997 of the widest channel
    filter_radius = hdrp_sample_profile(0.997, d_max)[0]
    for y in range(h):
        for x in range(w):
            if not valid[y, x]:
                out[y, x] = e[y, x]
                continue
            ppm = focal / (z[y, x] * mm_per_unit)
            count = int(math.pi * (filter_radius * ppm) ** 2 / 4)
            n = min(count, budget)
            if n < 1:
                continue
            tot_e, tot_w = np.zeros(3), np.zeros(3)
            for i in range(n):
                r, rcp_pdf = hdrp_sample_profile(i / n + 0.5 / n, d_max)
                psi = phase[y, x] + 2 * math.pi * ((i / GOLDEN_RATIO) % 1.0)
                sy = y + int(np.round(ppm * r * math.sin(psi)))
                sx = x + int(np.round(ppm * r * math.cos(psi)))
                if not (0 <= sy < h and 0 <= sx < w) or not valid[sy, sx]:
                    continue  # off-screen or no SSS: TestLightingForSSS fails, the sample is skipped
                rel_z = (z[sy, sx] - z[y, x]) * mm_per_unit
                r3 = math.sqrt(r * r + rel_z * rel_z)
                s = 1 / d
                weight = s / (8 * math.pi) * (np.exp(-s * r3 / 3) + np.exp(-s * r3)) * rcp_pdf
                tot_e += weight * e[sy, sx]
                tot_w += weight
            out[y, x] = albedo * tot_e / np.maximum(tot_w, 1e-300)
    return out


def blender_burley_sample(d, x_rand):
    # eevee_subsurface.cc, burley_sample: Newton from Blender's initial guess (run to float64 convergence here)
    x_rand *= 0.9963790093708328
    r = math.exp(x_rand * x_rand * 2.4) - 1.0 if x_rand <= 0.9 else 15.0
    for _ in range(60):
        e3 = math.exp(-r / 3)
        f = 1 - 0.25 * e3**3 - 0.75 * e3 - x_rand
        fp = 0.25 * e3**3 + 0.25 * e3
        if abs(f) < 1e-14 or fp == 0:
            break
        r = max(r - f / fp, 0.0)
    return r * d


def radical_inverse(i, base):
    f, out = 1.0, 0.0
    while i > 0:
        f /= base
        out += f * (i % base)
        i //= base
    return out


def eevee_pattern(k, seed=0):
    d0 = 0.25 / math.pi / (1.9 - 1 + 3.5 * 0.2**2)  # burley_setup(1, 1)
    rand_u, rand_v = radical_inverse(k + 1 + seed, 2), radical_inverse(k + 1 + seed, 3)
    golden_angle = math.pi * (3 - math.sqrt(5))
    pattern = []
    for i in range(16):
        theta = golden_angle * i + 2 * math.pi * rand_u
        x = (1 + rand_v / 16) * (i / 16)
        r = blender_burley_sample(d0, x)
        pdf = (math.exp(-r / d0) + math.exp(-r / (3 * d0))) / (8 * math.pi * d0) / 0.9963790093708328
        pattern.append((math.cos(theta) * r, math.sin(theta) * r, 1 / pdf))
    return pattern


def eevee_port(e, z, ids, albedo_mat, d, focal, mm_per_unit, frames, cx=None, cy=None):
    h, w, _ = e.shape
    cx = w / 2 if cx is None else cx
    cy = h / 2 if cy is None else cy
    a = albedo_mat / max(1e-6, albedo_mat.max())
    s = 1.9 - a + 3.5 * (a - 0.8) ** 2
    radius = d * 4 * math.pi * s  # engines.EeveeNext: radius * scale * mm_per_unit
    max_radius = radius.max()
    dd = 0.25 / math.pi * np.maximum(1e-4, radius / max_radius) * max_radius / s  # burley_setup
    golden_angle = math.pi * (3 - math.sqrt(5))
    acc = np.zeros_like(e)
    for k in range(frames):
        pattern = eevee_pattern(k)
        for y in range(h):
            for x in range(w):
                if ids[y, x] == 0:
                    acc[y, x] += e[y, x]
                    continue
                scale = focal * max_radius / (z[y, x] * mm_per_unit)
                if scale <= 1:
                    acc[y, x] += e[y, x]
                    continue
                y_gl = h - 1 - y
                ign = (52.9829189 * ((0.06711056 * x + 0.00583715 * y_gl) % 1.0)) % 1.0
                theta = ign * golden_angle
                c, sn = math.cos(theta), math.sin(theta)
                vp = np.array([(x + 0.5 - cx) / focal * z[y, x], (y + 0.5 - cy) / focal * z[y, x], z[y, x]])
                tot_e, tot_w = np.zeros(3), np.zeros(3)
                for sx_, sy_, pdf_inv in pattern:
                    ox = scale * (c * sx_ - sn * sy_)
                    oy = -scale * (sn * sx_ + c * sy_)  # the pattern's y points up the screen
                    tx, ty = math.floor(x + ox + 0.5), math.floor(y + oy + 0.5)
                    if not (0 <= tx < w and 0 <= ty < h) or ids[ty, tx] != ids[y, x]:
                        continue  # border colour id 0, or another object
                    zs = z[ty, tx]
                    sp = np.array([(x + ox + 0.5 - cx) / focal * zs, (y + oy + 0.5 - cy) / focal * zs, zs])
                    r = np.linalg.norm(sp - vp) * mm_per_unit
                    weight = (np.exp(-r / dd) + np.exp(-r / (3 * dd))) / (4 * dd) * pdf_inv
                    tot_e += weight * e[ty, tx]
                    tot_w += weight
                acc[y, x] += np.where(tot_w > 0, tot_e / np.where(tot_w > 0, tot_w, 1), 0)
    out = acc / frames
    return np.where((ids > 0)[..., None], out * albedo_mat, e)


def jimenez_port(e, z, valid, albedo, strength, falloff, sss_width, alpha, focal, taps, follow=True):
    h, w, _ = e.shape
    offsets, weights = jimenez_kernel(strength, falloff, n_samples=taps)
    inv_tan = 2 * focal / h  # 1 / tan(fovy / 2)
    zz = np.where(np.isfinite(z) & (z > 0), z, 1e20)

    def fetch(img, y, x):  # LinearSampler: linear filter, Clamp address mode (pixel centres at integers)
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        out = 0.0
        for yy, xx, wt in ((y0, x0, (1 - fy) * (1 - fx)), (y0, x0 + 1, (1 - fy) * fx), (y0 + 1, x0, fy * (1 - fx)),
                           (y0 + 1, x0 + 1, fy * fx)):
            if wt:
                out = out + wt * img[min(max(yy, 0), h - 1), min(max(xx, 0), w - 1)]
        return out

    def blur(colour, direction, target):  # the pass writes ``target`` where the stencil passes (SSS pixels)
        out = target.copy()
        for y in range(h):
            for x in range(w):
                if not valid[y, x]:
                    continue
                centre = colour[y, x]
                step = sss_width * inv_tan / zz[y, x] * alpha / 3.0  # finalStep
                acc = weights[0] * centre
                for i in range(1, taps):
                    tx = x + offsets[i] * step * w * direction[0]
                    ty = y + offsets[i] * step * h * direction[1]
                    c = fetch(colour, ty, tx)
                    if follow:
                        s = min(max(300 * inv_tan * sss_width * abs(zz[y, x] - fetch(zz, ty, tx)), 0.0), 1.0)
                        c = c + s * (centre - c)
                    acc = acc + weights[i] * c
                out[y, x] = acc
        return out

    # SeparableSSS::go: the horizontal pass reads the colour target and writes tmpRT, cleared to black first; the
    # vertical pass reads tmpRT and writes the colour target
    result = blur(blur(e, (1, 0), np.zeros_like(e)), (0, 1), e)
    return np.where(valid[..., None], result * albedo, e)


# --- small frames with depth steps, borders and a non-SSS region ---------------------------------------------------


def stepped_frame(h=10, w=14, seed=0):
    rng = np.random.default_rng(seed)
    e = rng.uniform(0.1, 1.0, (h, w, 3))
    z = np.full((h, w), 100.0)
    z[:, w // 2:] = 100.8  # a depth step of 0.8 mm across the frame
    z[0, 0] = np.inf  # no surface
    ids = np.ones((h, w), np.int64)
    ids[h - 2:, :3] = 0  # a corner without SSS
    ids[0, 0] = 0
    return e, z, ids


def buffers_of(e, z, ids, dtype=jnp.float64):
    return sj.Buffers(irradiance=jnp.asarray(e, dtype), depth=jnp.asarray(z, dtype),
                      material_id=jnp.asarray(ids, jnp.int32))


@pytest.mark.parametrize("options", [{"quality": "low"}, {"budget": 7}, {"quality": "medium", "seed": 3}])
def test_hdrp_matches_the_shader_port(options):
    e, z, ids = stepped_frame()
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)  # 0.4 px/mm: samples reach a few pixels, past the borders
    tech = HdrpPass(**options)
    out = np.asarray(tech(buffers_of(e, z, ids), SKIN, cam))
    h, w = z.shape
    phase = np.asarray(spiral_rotation(jnp.arange(h)[:, None] * jnp.ones((1, w), jnp.int32),
                                       jnp.ones((h, 1), jnp.int32) * jnp.arange(w)[None, :], 0,
                                       options.get("seed", 0), dtype=jnp.float64))
    ref = hdrp_port(e, z, ids > 0, np.asarray(SKIN.albedo[0]), np.asarray(SKIN.d_mm[0]), 40.0, 1.0, tech.samples,
                    phase)
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("frames", [1, 3])
def test_eevee_next_matches_the_shader_port(frames):
    e, z, ids = stepped_frame(9, 12, seed=1)
    ids[:, -2:] = 2  # another object: its samples are rejected
    cam = sj.Camera(focal_px=30.0, mm_per_unit=1.0)
    out = np.asarray(EeveeNextPass(frames=frames)(buffers_of(e, z, ids), SKIN, cam))
    ref = eevee_port(e, z, ids, np.asarray(SKIN.albedo[0]), np.asarray(SKIN.d_mm[0]), 30.0, 1.0, frames)
    np.testing.assert_allclose(out, ref, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("taps, follow", [(17, True), (11, False), (25, True)])
def test_jimenez_matches_the_shader_port(taps, follow):
    e, z, ids = stepped_frame(8, 13, seed=2)
    params = JimenezParams(strength=[0.5, 0.4, 0.3], falloff=[1.0, 0.37, 0.3], sss_width=0.012, albedo=[0.8, 0.5, 0.4],
                           alpha=0.9)
    cam = sj.Camera(focal_px=20.0, mm_per_unit=1000.0)
    out = np.asarray(JimenezPass(taps=taps, follow_surface=follow)(buffers_of(e, z * 0.01, ids), params, cam))
    ref = jimenez_port(e, z * 0.01, ids > 0, np.array([0.8, 0.5, 0.4]), [0.5, 0.4, 0.3], [1.0, 0.37, 0.3], 0.012,
                       0.9, 20.0, taps, follow)
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12)
    assert np.abs(out - e * [0.8, 0.5, 0.4]).max() > 1e-3  # the frame is blurred: the test can fail


def test_jimenez_horizontal_pass_reaches_w_over_h_farther():
    # an impulse in a 21 x 105 frame: the horizontal spread (px) is W/H = 5 times the vertical one (the vertical
    # pass reaches 4 px, 2 px per kernel unit, so the frame's edge does not clamp it)
    h, w = 21, 105
    e = np.zeros((h, w, 3))
    e[h // 2, w // 2] = 1.0
    z = np.ones((h, w))
    params = JimenezParams(strength=[1.0] * 3, falloff=[1.0] * 3, sss_width=0.075)  # 2/3 width f / z = 2 px
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1000.0)
    out = np.asarray(JimenezPass(follow_surface=False)(buffers_of(e, z, np.ones((h, w), np.int64)), params, cam))
    cols, rows = out[h // 2, :, 0], out[:, w // 2, 0]
    sd = lambda m: math.sqrt(np.sum(m * (np.arange(len(m)) - len(m) // 2) ** 2) / np.sum(m))
    assert sd(cols) / sd(rows) == pytest.approx(w / h, rel=0.08)


# --- noise-averaged profiles on a 96 x 128 frame at 1 px/mm ---------------------------------------------------------

H, W = 96, 128
CAM_1PX = sj.Camera(focal_px=100.0, mm_per_unit=1.0)  # depth 100: 1 px/mm


def edge_and_disc():
    edge = np.zeros((H, W, 3))
    edge[:, W // 2:] = 1.0
    yy, xx = np.mgrid[:H, :W]
    rad = np.hypot(yy - H / 2 + 0.5, xx - W / 2 + 0.5)
    disc = np.where((rad < 20)[..., None], 1.0, 0.0) * np.ones(3)
    return edge, disc, rad


def azimuthal_mean(img, rad):
    bins = np.floor(rad).astype(int)
    return np.stack([np.bincount(bins.ravel(), img[..., c].ravel()) / np.bincount(bins.ravel())
                     for c in range(3)], -1)[:45]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hdrp", "eevee-next"])
def test_noise_averaged_profiles_match_the_port(name):
    edge, disc, rad = edge_and_disc()
    z = np.full((H, W), 100.0)
    ids = np.ones((H, W), np.int64)
    albedo, d = np.asarray(SKIN.albedo[0]), np.asarray(SKIN.d_mm[0])
    for img, profile in ((edge, lambda o: o.mean(axis=0)), (disc, lambda o: azimuthal_mean(o, rad))):
        b = buffers_of(img, z, ids, jnp.float32)
        if name == "hdrp":
            out = np.asarray(HdrpPass(quality="low")(b, SKIN, CAM_1PX), np.float64)
            phase = np.asarray(spiral_rotation(jnp.arange(H)[:, None] * jnp.ones((1, W), jnp.int32),
                                               jnp.ones((H, 1), jnp.int32) * jnp.arange(W)[None, :], 0, 0,
                                               dtype=jnp.float64))
            ref = hdrp_port(img, z, ids > 0, albedo, d, 100.0, 1.0, 20, phase)
        else:
            out = np.asarray(EeveeNextPass(frames=2)(b, SKIN, CAM_1PX), np.float64)
            ref = eevee_port(img, z, ids, albedo, d, 100.0, 1.0, 2)
        contrast = albedo  # the edge and the disc go from 0 to 1 irradiance: albedo in the output
        assert np.all(np.abs(profile(out) - profile(ref)) <= 0.01 * contrast)
        assert np.abs(profile(out) - profile(img * albedo)).max() > 0.05  # it scatters: the test can fail


@pytest.mark.slow
def test_jimenez_image_matches_the_port():
    edge, disc, _ = edge_and_disc()
    z = np.full((H, W), 0.1)
    ids = np.ones((H, W), np.int64)
    cam = sj.Camera(focal_px=100.0, mm_per_unit=1000.0)  # depth 0.1 m: 1 px/mm
    tech = JimenezPass()
    params = tech.params(SKIN, cam)
    for img in (edge, disc):
        out = np.asarray(tech(buffers_of(img, z, ids, jnp.float32), params, cam), np.float64)
        ref = jimenez_port(img, z, ids > 0, np.asarray(SKIN.albedo[0]), np.asarray(params.strength),
                           np.asarray(params.falloff), float(params.sss_width), float(params.alpha), 100.0, 17)
        assert np.linalg.norm(out - ref) / np.linalg.norm(ref) < 0.02


# --- options, tiles, gradients --------------------------------------------------------------------------------------


@pytest.mark.parametrize("make, message", [
    (lambda: HdrpPass(quality="ultra"), "quality='ultra' is not one of"),
    (lambda: HdrpPass(budget=0), r"budget must be an integer in \[1, 1000\]"),
    (lambda: HdrpPass(frames=0), r"frames must be a positive integer"),
    (lambda: EeveeNextPass(blender_version="4.1"), "EEVEE Next starts with 4.2"),
    (lambda: JimenezPass(taps=13), "taps=13 is not one of"),
    (lambda: JimenezParams(strength=[1.5, 0, 0], falloff=1.0, sss_width=0.01), "strength must be within"),
])
def test_bad_options_name_themselves(make, message, as_users_run_it):
    with pytest.raises(ValueError, match=message):
        make()


def test_registry_builds_the_passes():
    assert sj.technique("hdrp", quality="high").samples == 80
    assert sj.technique("hdrp", budget=7).samples == 7
    for name in ("hdrp", "eevee-next", "jimenez"):
        cls = sj.TECHNIQUES[name]
        assert cls.conserves_energy and all(f.metadata.get("help") for f in cls.option_fields())


def test_a_tile_with_its_halo_is_the_frame():
    e, z, ids = stepped_frame(16, 20, seed=4)
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)
    full = buffers_of(e, z, ids)
    for tech in (HdrpPass(quality="low"), EeveeNextPass(frames=2)):
        whole = np.asarray(tech(full, SKIN, cam))
        halo = tech.reach_px(full, SKIN, cam)
        r0, c0 = 5, 8  # the tile's kept pixels: rows 5..9, cols 8..11; the buffer adds the halo (clipped to the frame)
        rs, cs = max(0, r0 - halo), max(0, c0 - halo)
        sub = buffers_of(e[rs:r0 + 5 + halo, cs:c0 + 4 + halo], z[rs:r0 + 5 + halo, cs:c0 + 4 + halo],
                         ids[rs:r0 + 5 + halo, cs:c0 + 4 + halo])
        tile = np.asarray(tech(sub, SKIN, cam, origin=(rs, cs), frame_shape=(16, 20)))
        np.testing.assert_allclose(tile[r0 - rs:r0 - rs + 5, c0 - cs:c0 - cs + 4], whole[r0:r0 + 5, c0:c0 + 4],
                                   rtol=1e-12)


def test_tiles_of_one_shape_share_one_program():
    # the engines' passes took a tile's origin as a static argument: each tile of a large frame compiled its own
    # program (a 200x120 frame in 28 tiles through eevee-next: 54 s against 1.3 s whole), as the reference's
    # tiles (traced origin) do not
    import jax.monitoring

    e, z, ids = stepped_frame(16, 20, seed=4)
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)
    params = JimenezParams(strength=[0.5, 0.4, 0.3], falloff=[1.0, 0.37, 0.3], sss_width=0.05, albedo=[0.8, 0.5, 0.4])
    tile = lambda r, c: buffers_of(e[r:r + 8, c:c + 10], z[r:r + 8, c:c + 10], ids[r:r + 8, c:c + 10])
    compiles = []
    listener = lambda name, seconds, **kw: compiles.append(name) if "compile" in name else None
    for tech, material in ((HdrpPass(quality="low"), SKIN), (EeveeNextPass(frames=1), SKIN),
                           (JimenezPass(taps=11), params)):
        # the passes that compute only a tile's kept pixels take them as a traced corner too (one program per size)
        keep = (lambda r, c: {"keep": (r % 3, c % 3, 5, 7)}) if tech.name != "jimenez" else (lambda r, c: {})
        jax.block_until_ready(tech(tile(0, 0), material, cam, origin=(0, 0), frame_shape=(16, 20), **keep(0, 0)))
        compiles.clear()
        jax.monitoring.register_event_duration_secs_listener(listener)
        try:
            for r, c in ((8, 0), (0, 10), (8, 10), (3, 7)):
                jax.block_until_ready(tech(tile(r, c), material, cam, origin=(r, c), frame_shape=(16, 20),
                                           **keep(r, c)))
        finally:
            jax.monitoring.unregister_event_duration_listener(listener)
        assert compiles == [], (tech.name, compiles)


def test_jimenez_working_memory_does_not_grow_with_the_taps():
    # the taps were unrolled and XLA held every tap's fetch at once: 672 / 1,056 / 1,568 bytes of scratch a pixel at
    # 11 / 17 / 25 taps (9.4 GB peak for a 3840x2160 frame at 17); the taps in a loop: 96 at each count (XLA's own
    # buffer assignment of the compiled program, not a timing)
    scene = sj.demo_scene(40, 48)
    per_px = {}
    for taps in (11, 25):
        tech = JimenezPass(taps=taps)
        params = tech.params(SKIN, scene.camera)
        compiled = jax.jit(lambda b, tech=tech, params=params: tech(b, params, scene.camera)).lower(
            scene.buffers).compile()
        per_px[taps] = compiled.memory_analysis().temp_size_in_bytes / (40 * 48)
    assert per_px[25] <= 1.1 * per_px[11] and per_px[25] < 400, per_px


def test_gradients_are_finite():
    e, z, ids = stepped_frame(6, 7, seed=5)
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)
    b = buffers_of(e, z, ids)
    for tech in (HdrpPass(quality="low"), EeveeNextPass(frames=1)):
        g = jax.grad(lambda d: jnp.sum(tech(b, sj.BurleyMaterial(SKIN.albedo, d), cam)))(SKIN.d_mm)
        assert np.all(np.isfinite(np.asarray(g))) and np.any(np.asarray(g) != 0)
    cam_j = sj.Camera(focal_px=20.0, mm_per_unit=1000.0)
    bj = buffers_of(e, z * 0.01, ids)

    def loss(width):
        p = JimenezParams(strength=[0.5, 0.4, 0.3], falloff=[1.0, 0.37, 0.3], sss_width=width)
        return jnp.sum(JimenezPass()(bj, p, cam_j))

    g = jax.grad(loss)(jnp.asarray(0.012))
    assert np.isfinite(float(g)) and float(g) != 0


def test_jimenez_refuses_a_traced_burley_material(as_users_run_it):
    cam = sj.Camera(focal_px=20.0, mm_per_unit=1000.0)
    e, z, ids = stepped_frame(6, 7)
    with pytest.raises(TypeError, match="trace JimenezParams instead"):
        jax.jit(lambda d: JimenezPass()(buffers_of(e, z * 0.01, ids), sj.BurleyMaterial(SKIN.albedo, d), cam))(
            SKIN.d_mm)
    # a concrete material closed over under jit is read on the host like an eager call's (it raised
    # TracerArrayConversionError: ``material.albedo[0]``, a JAX operation, was staged by the trace)
    b = buffers_of(e, z * 0.01, ids)
    eager = np.asarray(JimenezPass()(b, SKIN, cam))
    traced = np.asarray(jax.jit(lambda bb: JimenezPass()(bb, SKIN, cam))(b))
    # the same parameters; XLA folds the closed-over kernel build into constants (its exponentials rounded apart)
    np.testing.assert_allclose(traced, eager, rtol=1e-3, atol=1e-6)
    assert np.abs(eager - np.asarray(b.irradiance) * np.asarray(SKIN.albedo)).max() > 1e-3  # it scattered


def test_jimenez_vertical_pass_reads_black_where_the_stencil_held_no_sss():
    # SeparableSSS::go clears the horizontal pass's target (tmpRT) and writes it only where the stencil passes: the
    # vertical pass reads 0 below an SSS region, whatever light the pixels there hold (the port kept their light:
    # the last skin row went from 0.47 to 3.75 in red as the pixels below went from 0 to 10)
    h = w = 16
    ids = np.zeros((h, w), np.int32)
    ids[: h // 2] = 1  # whole rows of SSS over whole rows without: only the vertical pass reaches across
    cam = sj.Camera(focal_px=600.0, mm_per_unit=1.0)
    params = JimenezParams(strength=[0.5, 0.4, 0.3], falloff=[1.0, 0.37, 0.3], sss_width=2.0,
                           albedo=[0.8, 0.5, 0.4], alpha=1.0)
    outs = []
    for below in (0.0, 10.0):
        e = np.full((h, w, 3), 1.0)
        e[h // 2:] = below
        outs.append(np.asarray(JimenezPass(taps=17)(buffers_of(e, np.full((h, w), 500.0), ids), params, cam)))
    sss = ids > 0
    np.testing.assert_array_equal(outs[0][sss], outs[1][sss])
    # and the pass does reach across: the last SSS row is darker than the first (its taps below read black)
    assert outs[0][h // 2 - 1, w // 2, 0] < outs[0][0, w // 2, 0] - 1e-3


def test_a_float32_tile_of_eevee_next_is_the_frame_bit_for_bit():
    # the per-pixel angle (interleaved gradient noise) was computed from iotas in the pass: XLA folded or contracted
    # it differently for a tile than for the frame, the angle moved by ~1e-4 and a few pixels fetched other texels
    # (a tiled 200x120 frame: 16 pixels off by up to 2.5%)
    scene = sj.demo_scene(120, 200)
    with jax.enable_x64(False):
        b = jax.tree.map(lambda a: a.astype(jnp.float32) if a.dtype == jnp.float64 else a, scene.buffers)
        cam = sj.Camera(float(scene.camera.focal_px), float(scene.camera.mm_per_unit))
        tech = EeveeNextPass(frames=3, seed=5)
        whole = np.asarray(tech(b, SKIN, cam))
        halo = tech.reach_px(b, SKIN, cam)
        for r0, r1, c0, c1 in ((0, 60, 0, 100), (60, 120, 100, 200), (30, 90, 50, 150)):
            rs, re, cs, ce = max(0, r0 - halo), min(120, r1 + halo), max(0, c0 - halo), min(200, c1 + halo)
            sub = jax.tree.map(lambda a, rs=rs, re=re, cs=cs, ce=ce: a[rs:re, cs:ce], b)
            tile = np.asarray(tech(sub, SKIN, cam, origin=(rs, cs), frame_shape=(120, 200)))
            np.testing.assert_array_equal(tile[r0 - rs:r1 - rs, c0 - cs:c1 - cs], whole[r0:r1, c0:c1])


def test_a_tile_told_the_pixels_it_keeps_computes_only_those():
    # HDRP's and EEVEE Next's tiles computed their halos as well as the pixels they keep: a 3840x2160 close-up through
    # HDRP ran in 112 tiles holding ~4.7x the frame's pixels, 135.9 s against 17.3 s whole. keep=(row0, col0, rows,
    # cols) names the kept pixels: only they are computed (the samples read the whole buffer); the frame's values
    # there, bit for bit in float32, and the rest the pixel's local shading
    scene = sj.demo_scene(120, 200)
    with jax.enable_x64(False):
        b = jax.tree.map(lambda a: a.astype(jnp.float32) if a.dtype == jnp.float64 else a, scene.buffers)
        cam = sj.Camera(float(scene.camera.focal_px), float(scene.camera.mm_per_unit))
        for tech in (HdrpPass(quality="low", seed=2), EeveeNextPass(frames=3, seed=5)):
            whole = np.asarray(tech(b, SKIN, cam))
            halo = tech.reach_px(b, SKIN, cam)
            for r0, r1, c0, c1 in ((0, 60, 0, 100), (60, 120, 100, 200), (30, 90, 50, 150)):
                rs, re, cs, ce = max(0, r0 - halo), min(120, r1 + halo), max(0, c0 - halo), min(200, c1 + halo)
                sub = jax.tree.map(lambda a, rs=rs, re=re, cs=cs, ce=ce: a[rs:re, cs:ce], b)
                keep = (r0 - rs, c0 - cs, r1 - r0, c1 - c0)
                tile = np.asarray(tech(sub, SKIN, cam, origin=(rs, cs), frame_shape=(120, 200), keep=keep))
                np.testing.assert_array_equal(tile[r0 - rs:r1 - rs, c0 - cs:c1 - cs], whole[r0:r1, c0:c1])
                # the others: irradiance times the albedo pass on SSS pixels (albedo_mode post), the irradiance
                # elsewhere
                e, z, ids, albedo = (np.asarray(a) for a in (sub.irradiance, sub.depth, sub.material_id, sub.albedo))
                sss = (ids > 0) & np.isfinite(z) & (z > 0)
                local = np.where(sss[..., None], e * np.clip(albedo, 0, 1), e)
                others = np.ones(z.shape, bool)
                others[keep[0]:keep[0] + keep[2], keep[1]:keep[1] + keep[3]] = False
                np.testing.assert_allclose(tile[others], local[others], rtol=1e-6)
            # computes only those: XLA's cost model of the compiled pass, a quarter of the pixels kept
            cost = {}
            for keep in (None, (30, 50, 60, 100)):
                compiled = jax.jit(lambda b, keep=keep, tech=tech: tech(b, SKIN, cam, keep=keep)).lower(b).compile()
                analysis = compiled.cost_analysis()
                cost[keep] = (analysis[0] if isinstance(analysis, list) else analysis)["flops"]
            assert cost[(30, 50, 60, 100)] < 0.5 * cost[None], (tech.name, cost)


@pytest.mark.parametrize("keep, message", [((0, 0, 0, 5), "not a non-empty window inside the 16x20 buffer"),
                                           ((10, 0, 7, 5), "not a non-empty window"),
                                           ((0, 0.5, 4, 4), "keep must be four integers"),
                                           ((0, 0, 4), "keep must be four integers"),
                                           ((True, 0, 4, 4), "keep must be four integers")])
def test_a_bad_keep_names_itself(keep, message, as_users_run_it):
    e, z, ids = stepped_frame(16, 20, seed=4)
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)
    for tech in (HdrpPass(quality="low"), EeveeNextPass(frames=1)):
        with pytest.raises(ValueError, match=f"{tech.name}: .*{message}"):
            tech(buffers_of(e, z, ids), SKIN, cam, keep=keep)


@pytest.mark.parametrize("x64", [True, False])
def test_only_the_sss_pixels_are_computed(monkeypatch, x64):
    # the passes computed every pixel of the frame, where the engines' stencil runs them on SSS pixels only (a
    # quarter of the demo frame): an eager call compacts the SSS pixels on the host and computes those, the same
    # arithmetic per pixel as every pixel computed (bit for bit), and a frame mostly SSS runs every pixel
    import sss_jax._techniques._eevee_next as E
    import sss_jax._techniques._engine_frame as F
    import sss_jax._techniques._hdrp as H

    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        scene = sj.demo_scene(120, 200)
        b = jax.tree.map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, scene.buffers)
        cam = scene.camera
        z = np.asarray(b.depth)
        sss = (np.asarray(b.material_id) > 0) & np.isfinite(z) & (z > 0)
        for module, tech in ((H, HdrpPass(quality="low", seed=3)), (E, EeveeNextPass(frames=2, seed=5))):
            name = "_hdrp_impl" if module is H else "_eevee_next_impl"
            real, seen = getattr(module, name), []
            monkeypatch.setattr(module, name, lambda *a, real=real, seen=seen: seen.append(a[-1]) or real(*a))
            compacted = np.asarray(tech(b, SKIN, cam))
            real_compacted = F.compacted_pixels
            monkeypatch.setattr(F, "compacted_pixels", lambda *a: None)
            every = np.asarray(tech(b, SKIN, cam))
            monkeypatch.setattr(F, "compacted_pixels", real_compacted)
            np.testing.assert_array_equal(compacted, every)
            idx = np.asarray(seen[0])
            # the SSS pixels (a quarter of the frame), in a list padded (with 120 * 200) to at most 1.25x their count
            np.testing.assert_array_equal(idx[idx < 120 * 200], np.flatnonzero(sss))
            assert sss.sum() <= idx.size <= 1.25 * sss.sum() < 0.5 * 120 * 200 and seen[1] is None
            # a frame mostly SSS runs every pixel
            seen.clear()
            tech(buffers_of(*stepped_frame(16, 20), dtype=dtype), SKIN, cam)
            assert seen == [None], tech.name


def test_a_tiles_sss_pixels_are_compacted_into_one_of_a_few_sizes():
    # a whole frame's SSS pixels go into the next quarter-octave size (as burley's), but the tiles of one frame, each
    # with its own count, then compiled a program each (a 1920x1080 frame through HDRP in 6 tiles: 5.6 s, against 4.7
    # s whole); a tile's list is an eighth, a quarter or half of its kept window (_burley.kept_capacity), or the
    # window is computed whole (one program for every such tile)
    from sss_jax._techniques._engine_frame import compacted_pixels

    h, w = 64, 96
    window = (8, 8, 48, 80)  # 3840 px kept
    sizes = {}
    for count in (0, 100, 480, 481, 960, 961, 1920, 1921, 3000):
        ids = np.zeros((h, w), np.int32)
        rows, cols = np.divmod(np.arange(count), 80)
        ids[8 + rows, 8 + cols] = 1
        ids[:4, :] = 1  # outside the window: not counted
        b = buffers_of(np.ones((h, w, 3)), np.full((h, w), 10.0), ids)
        idx = compacted_pixels(b, window)
        sizes[count] = None if idx is None else idx.size
        if idx is not None:  # the window's SSS pixels, row-major, then padding
            np.testing.assert_array_equal(idx[:count], (8 + rows) * w + 8 + cols)
            assert (idx[count:] == h * w).all()
    assert sizes == {0: 480, 100: 480, 480: 480, 481: 960, 960: 960, 961: 1920, 1920: 1920, 1921: None,
                     3000: None}, sizes
    # a whole frame's: the next quarter-octave size (the octave 1024-2048 in steps of 256: 1100 -> 1280)
    ids = np.zeros((h, w), np.int32)
    ids.reshape(-1)[:1100] = 1
    assert compacted_pixels(buffers_of(np.ones((h, w, 3)), np.full((h, w), 10.0), ids), None).size == 1280


def test_hdrp_says_where_it_renders_lit_pixels_black():
    # HDRP writes black where every sample of a pixel is skipped (as the engine does); a frame gone black without a
    # word (d typed 1e4 mm instead of 1.4) read as a bug of the tool
    import warnings

    e, z, ids = stepped_frame(12, 16, seed=3)
    cam = sj.Camera(focal_px=40.0, mm_per_unit=1.0)
    b = buffers_of(e, z, ids)
    for d, expect in ((1e4, True), (1.0, False)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = np.asarray(HdrpPass(quality="low")(b, sj.BurleyMaterial([0.8, 0.6, 0.5], [d, d, d]), cam))
        said = [str(w.message) for w in caught if issubclass(w.category, sj.SamplingWarning)]
        black = int(((ids > 0) & (e > 0).any(-1) & (out == 0).any(-1)).sum())
        assert (black > 0) == expect
        message = (f"hdrp: {black} of {int(((ids > 0) & (e > 0).any(-1)).sum())} lit SSS pixels came out black in "
                   "RGB: every sample of theirs landed off the frame or on pixels without SSS, or the channel's "
                   "weights underflowed in float32 (a d far below the widest channel's): what HDRP's pass renders "
                   "there (burley keeps the pixel's own light)")
        assert said == ([message] if expect else [])
