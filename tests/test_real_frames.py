"""Right on real renders (issue #27): the default techniques against path-traced truth, the back-lit slab, and a fit
that does not fit the frame's edge.

Frames: tests/data/mitsuba (scripts/render_mitsuba.py, Mitsuba 3 volpath through skin1, skin2 and marble of Jensen
et al. 2001, Table 2; README there), the Blender 3.4 / Cycles render in ../shared/reference/blender and three Cycles
frames of our own in tests/data/cycles (scripts/render_blender.py; README there). Every error is
recomputed here with raw OpenImageIO reads and NumPy: rel_l2 = ||out - truth||_2 / ||truth||_2 over RGB on the SSS
pixels (id > 0).
"""

import json
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax._match import edge_loss, held_mask, match_frame, match_render
from test_match import _raw  # every channel of an EXR with raw OpenImageIO: the independent reader

DATA = pathlib.Path(__file__).resolve().parent / "data" / "mitsuba"


@pytest.fixture
def float32():
    """The fits in float32, as a user's run has them (the test config turns x64 on globally): half the cost."""
    with jax.enable_x64(False):
        yield


def _mitsuba(name: str):
    """Buffers, camera, material, truth (H, W, 3), SSS mask and the sidecar of a committed Mitsuba scene."""
    raw, truth = _raw(DATA / f"{name}_buffers.exr"), _raw(DATA / f"{name}_truth.exr")
    meta = json.loads((DATA / f"{name}_buffers.json").read_text())
    rgb = lambda d, p="": np.stack([d[p + c] for c in "RGB"], -1)
    b = sj.Buffers(irradiance=jnp.asarray(rgb(raw), jnp.float32), depth=jnp.asarray(raw["Z"], jnp.float32),
                   albedo=jnp.asarray(rgb(raw, "albedo."), jnp.float32),
                   normal=jnp.asarray(np.stack([raw[f"N.{c}"] for c in "XYZ"], -1), jnp.float32),
                   thickness=jnp.asarray(raw["thickness"], jnp.float32) if "thickness" in raw else None,
                   material_id=jnp.asarray(np.rint(raw["id"]), jnp.int32))
    cam = sj.Camera(meta["camera"]["focal_px"], meta["scene_unit_mm"])
    mat = sj.BurleyMaterial(np.asarray(meta["material"]["albedo"], np.float32),
                            np.asarray(meta["material"]["d_mm"], np.float32))
    return b, cam, mat, rgb(truth), raw["id"] > 0.5, meta


CYCLES = pathlib.Path(__file__).resolve().parent / "data" / "cycles"


def _blender(shared_dir):
    return _cycles(shared_dir / "reference" / "blender", "backlit")


def _cycles(base: pathlib.Path, name: str):
    """A Cycles frame as Blender wrote it: the white render ``irradiance_<name>.exr`` (multi-layer, ``ViewLayer.*``
    passes; our own are half-float colour with float32 Depth and IndexOB) and Cycles' SSS ``burley_<name>.exr``."""
    scene = json.loads((base / f"burley_{name}.json").read_text())
    white, cycles = _raw(base / f"irradiance_{name}.exr"), _raw(base / f"burley_{name}.exr")
    col = lambda raw, p, c: raw[f"ViewLayer.{p}.{c}"]
    irr = np.stack([col(white, "DiffDir", c) + col(white, "DiffInd", c) for c in "RGB"], -1)
    depth = col(white, "Depth", "Z")
    depth = np.where(depth > 1e9, np.inf, depth)
    ids = np.rint(col(white, "IndexOB", "X")).astype(np.int32)
    b = sj.Buffers(irradiance=jnp.asarray(irr, jnp.float32), depth=jnp.asarray(depth, jnp.float32),
                   material_id=jnp.asarray(ids))
    a = np.asarray(scene["material"]["subsurface_color"], np.float64)
    # Cycles >= 3.0: d = radius / (4 pi) (bssrdf_setup_radius in intern/cycles/kernel/closure/bssrdf.h)
    d = np.asarray(scene["material"]["radius_m"], np.float64) * scene["scene_unit_mm"] / (4 * math.pi)
    mat = sj.BurleyMaterial(a.astype(np.float32), d.astype(np.float32))
    cam = sj.Camera(scene["camera"]["focal_px"], scene["scene_unit_mm"])
    truth = np.stack([col(cycles, "Combined", c) for c in "RGB"], -1)
    return b, cam, mat, truth, ids > 0


def _rel_l2(out, truth, mask) -> float:
    o, t = np.asarray(out, np.float64)[mask], np.asarray(truth, np.float64)[mask]
    return float(np.linalg.norm(o - t) / np.linalg.norm(t))


def _local(b, mat) -> np.ndarray:
    albedo = np.asarray(b.albedo) if b.albedo is not None else np.asarray(mat.albedo)[0]
    return albedo * np.asarray(b.irradiance, np.float64)


@pytest.mark.parametrize("scene", ["skin_closeup", "marble_objects", "skin_occlusion", "blender", "cycles_closeup",
                                   "cycles_grazing", "cycles_far"])
def test_default_techniques_beat_local_shading_on_path_traced_frames(scene, shared_dir):
    # issue #27's bar: on the shipped Cycles frame, three Cycles frames and three Mitsuba scenes of our own, each
    # technique with its DEFAULT options is closer to the path-traced truth than local shading (albedo x
    # irradiance); the margins are the README's table
    if scene == "blender":
        b, cam, mat, truth, mask = _blender(shared_dir)
    elif scene.startswith("cycles_"):
        b, cam, mat, truth, mask = _cycles(CYCLES, scene.removeprefix("cycles_"))
    else:
        b, cam, mat, truth, mask = _mitsuba(scene)[:5]
    local = _rel_l2(_local(b, mat), truth, mask)
    for name, out in (("burley", sj.burley(b, mat, cam)), ("separable", sj.separable(b, mat, cam))):
        err = _rel_l2(out, truth, mask)
        assert err < local, (scene, name, err, local)


def test_closeup_default_keeps_the_light_the_old_default_lost():
    # the close-up is cut by the frame on every side: border="leaves" lets light leave (a darker frame), the
    # renormalised default keeps it (burley and separable redistribute light: energy out / in = 1 per channel)
    b, cam, mat, truth, mask, _ = _mitsuba("skin_closeup")
    local = _local(b, mat)
    for technique in (sj.burley, sj.separable):
        kept = np.asarray(technique(b, mat, cam), np.float64)[mask].sum(0) / local[mask].sum(0)
        lost = np.asarray(technique(b, mat, cam, border="leaves"), np.float64)[mask].sum(0) / local[mask].sum(0)
        np.testing.assert_allclose(kept, 1.0, atol=0.02)
        assert np.all(lost < kept) and lost[0] < 0.97, (technique.__name__, lost)


def _slab_interiors(b, mask, margin_px=8):
    """Per slab thickness (mm), the pixels at least ``margin_px`` (3.2 mm, several mean free paths) inside its face:
    the 1D slab model knows nothing of the side faces."""
    thick = np.asarray(b.thickness)
    out = {}
    for t in (1.0, 2.0, 4.0):
        m = mask & (np.abs(thick - t) < 1e-3)
        ys, xs = np.nonzero(m)
        inner = np.zeros_like(m)
        inner[ys.min() + margin_px:ys.max() - margin_px + 1, xs.min() + margin_px:xs.max() - margin_px + 1] = True
        out[t] = inner & m
    return out


def test_slab_model_against_a_path_traced_back_lit_medium():
    # three slabs of skin1 (index-matched, as rendered) lit only from behind, 17 degrees off the axis: the camera sees
    # only the diffusely transmitted light. model="slab" with the medium's own Monte Carlo table (in the sidecar)
    b, cam, mat, truth, mask, meta = _mitsuba("skin_backlit")
    medium = sj.MediumMaterial.from_tables(mat, [meta["material"]["slab_table"]])
    lt = meta["lights"][0]
    light = sj.DirectionalLight(jnp.asarray(lt["direction_to_light"], jnp.float32), lt["colour"])
    out = np.asarray(sj.translucency(b, medium, cam, light, model="slab"), np.float64)
    # the model before issue #27 by hand: the total transmittance (unscattered beam included), Lambertian exit
    cos_back = float(np.asarray(light.direction)[2])  # -N . L with N = (0, 0, -1)
    total = np.asarray(medium.transmittance(b.thickness), np.float64) * np.asarray(lt["colour"]) * cos_back
    for t, inner in _slab_interiors(b, mask).items():
        assert inner.sum() > 1000
        got, old, want = out[inner].mean(0), total[inner].mean(0), truth[inner].mean(0)
        # measured (README): 1 mm 0.97 / 0.99 / 0.97, 2 mm 0.99 / 0.98 / 0.99, 4 mm 1.02 / 1.02 / 1.10 of the truth
        # (with the thick-slab diffusion exit before: 1.49 / 1.39 / 1.24, 1.30 / 1.16 / 1.03, 1.12 / 0.99 / 0.89; the
        # total with a Lambertian exit: 3.62-2.93, 1.81-1.55, 1.08-0.97); 4 mm blue is the table's T_d (0.0074 against
        # the walk's 0.0067 of scripts/slab_exit.py)
        np.testing.assert_allclose(got, want, rtol=0.12, err_msg=f"{t} mm")
        if t <= 2.0:  # where the unscattered beam is a large share, the error falls by at least 40%
            assert np.all(np.abs(got / want - 1) < 0.6 * np.abs(old / want - 1)), (t, got / want, old / want)


def _exit_by_diffusion_solve(mu_view, tau, alpha, mu_light, n=3000):
    """P(mu_view) of an index-matched slab by finite differences (independent of _slab): the diffusion fluence of the
    scattered light, -phi''/3 + (1 - alpha) phi = alpha e^{-z/mu_light}, phi = (2/3)|phi'| on both faces (scipy
    solve_banded), the source alpha (phi + e^{-z/mu_light}), its emergent radiance int S e^{-(tau-z)/mu} dz / mu
    (trapezoid), over its flux int L 2 mu dmu (Gauss-Legendre in mu)."""
    from scipy.linalg import solve_banded

    z = np.linspace(0.0, tau, n)
    h = z[1] - z[0]
    ab = np.zeros((3, n))
    rhs = alpha * np.exp(-z / mu_light)
    ab[1], ab[0, 1:], ab[2, :-1] = 2 / (3 * h * h) + (1 - alpha), -1 / (3 * h * h), -1 / (3 * h * h)
    ab[1, 0], ab[0, 1], rhs[0] = 1 + 2 / (3 * h), -2 / (3 * h), 0.0  # phi_0 = (2/3)(phi_1 - phi_0) / h
    ab[1, -1], ab[2, -2], rhs[-1] = 1 + 2 / (3 * h), -2 / (3 * h), 0.0
    source = alpha * (solve_banded((1, 1), ab, rhs) + np.exp(-z / mu_light))
    radiance = lambda m: np.trapezoid(source * np.exp(-(tau - z) / m), z) / m
    x, w = np.polynomial.legendre.leggauss(64)
    x, w = 0.5 * (x + 1), 0.5 * w
    return radiance(mu_view) / np.sum(w * np.array([radiance(m) for m in x]) * 2 * x)


def test_slab_exit_distribution():
    from sss_jax._slab import diffuse_exit, slab_exit

    # against the independent diffusion solve: thin and thick, absorbing and not, oblique light
    cases = np.array([(tau, alpha, mu_light, mu) for tau, alpha, mu_light in (
        (0.77, 0.959, 0.958), (2.1, 0.838, 0.958), (5.96, 0.678, 0.958), (1.0, 1.0, 0.6), (8.0, 0.99, 1.0))
        for mu in (0.3, 0.7, 0.98)])
    want = [_exit_by_diffusion_solve(mu, tau, alpha, mu_light) for tau, alpha, mu_light, mu in cases]
    got = slab_exit(cases[:, 3], cases[:, 0], cases[:, 1], cases[:, 2], 1.0)
    np.testing.assert_allclose(got, want, rtol=0.01)
    # and against the NumPy Monte Carlo walk of scripts/slab_exit.py (200,000 photons, exit cosines 0.97-1, skin1's
    # 1 / 2 / 4 mm slabs lit at 0.958): the radiance the walk lets out near the normal, per channel
    mc = {(0.77, 0.959): 0.826, (1.05, 0.838): 0.861, (1.49, 0.678): 0.978, (3.09, 0.959): 1.116,
          (4.20, 0.838): 1.293, (5.96, 0.678): 1.518}
    tau, alpha = np.array(list(mc)).T
    np.testing.assert_allclose(slab_exit(0.985, tau, alpha, 0.958, 1.0), list(mc.values()), rtol=0.05)
    # the thin limit: once-scattered light grows with the path through the slab, P -> 1 / (2 mu) (limb-brightening)
    mu = np.array([0.25, 0.5, 1.0])
    np.testing.assert_allclose(slab_exit(mu, 1e-4, 0.7, 0.9, 1.0), 1 / (2 * mu), rtol=2e-3)
    # a thick conservative slab tends to the diffusion approximation's exit; the flux is that of a Lambertian exit
    assert float(slab_exit(0.9, 12.0, 1.0, 1.0, 1.0)) == pytest.approx(float(diffuse_exit(0.9, 1.0)), rel=0.03)
    x, w = np.polynomial.legendre.leggauss(200)
    x, w = 0.5 * (x + 1), 0.5 * w
    for eta in (1.0, 1.3):
        p = np.asarray(slab_exit(jnp.asarray(x), 1.5, 0.9, 0.8, eta))
        assert np.sum(w * p * 2 * x) == pytest.approx(1.0, abs=5e-3), eta
    # finite gradients at the limits: no thickness, a conservative medium, a grazing view and light, inf thickness
    for args in ((0.5, 0.0, 0.8, 0.9, 1.0), (0.5, 1.0, 1.0, 0.9, 1.3), (0.0, 2.0, 0.5, 0.0, 1.3),
                 (0.9, 1.0, 0.0, 0.9, 1.0), (0.9, np.inf, 0.5, 0.9, 1.0)):
        g = jax.grad(lambda *a: slab_exit(*a), argnums=(0, 1, 2, 3))(*map(jnp.asarray, args))
        assert np.all(np.isfinite(np.asarray(g))), (args, g)
    # the frame's table (what translucency reads) against slab_exit itself, at random points inside its range
    from sss_jax._slab import slab_exit_lookup, slab_exit_table

    rng = np.random.default_rng(5)
    alpha_rows = jnp.asarray([[0.959, 0.838, 0.678], [0.999, 0.99, 0.9]])
    table = slab_exit_table(alpha_rows, jnp.asarray([1.0, 1.3]))
    rows = jnp.asarray(rng.integers(0, 2, 400))
    tau = jnp.asarray(np.exp(rng.uniform(np.log(0.05), np.log(11.0), (400, 3))))
    ml, mv = jnp.asarray(rng.uniform(0.3, 1.0, 400)), jnp.asarray(rng.uniform(0.3, 1.0, 400))
    want = slab_exit(mv[:, None], tau, alpha_rows[rows], ml[:, None], jnp.asarray([1.0, 1.3])[rows][:, None])
    np.testing.assert_allclose(slab_exit_lookup(table, rows, tau, ml, mv), want, rtol=0.015)  # measured 1.04%
    # float32 (a user's run) agrees with float64 on a thick slab
    with jax.enable_x64(False):
        p32 = float(slab_exit(jnp.float32(0.9), jnp.float32(11.0), jnp.float32(0.5), jnp.float32(0.9),
                              jnp.float32(1.0)))
    assert p32 == pytest.approx(float(slab_exit(0.9, 11.0, 0.5, 0.9, 1.0)), rel=1e-4)


def test_edge_loss_and_held_mask():
    from scipy import integrate

    # the share of Burley's 2D profile beyond a straight edge, by 2D quadrature of R(r) = (e^-r + e^-r/3) / (8 pi r)
    R = lambda r: (math.exp(-r) + math.exp(-r / 3)) / (8 * math.pi * r)
    mat = sj.BurleyMaterial([0.5] * 3, [1.0, 0.5, 0.25])
    for x0 in (0.0, 1.0, 3.0, 8.0):
        want = integrate.dblquad(lambda y, x: R(math.hypot(x, y)), x0, 80, -80, 80)[0]
        got = edge_loss(np.array([x0]), mat, np.array([0]), np.array([1.0]))[0]  # the widest channel: d = 1
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9), x0
    # the two-Gaussian separable kernel a(x) a(y): the normal tails, w Q(x / s1) + (1 - w) Q(x / s2)
    tg = sj.TwoGaussianMaterial([0.5] * 3, [0.3] * 3, [1.0] * 3, [4.0] * 3)
    q = lambda z: 0.5 * math.erfc(z / math.sqrt(2))
    assert edge_loss(np.array([3.0]), tg, np.array([0]), np.array([1.0]))[0] == pytest.approx(
        0.3 * q(3.0) + 0.7 * q(0.75), rel=1e-9)
    # a frame: the held pixels are those ~8.2 d (d = 2 px) or more from every edge (99% of the energy inside; the
    # shares beyond x by brentq on the marginal above: 0.01 at 8.19 d, 0.05 at 4.11 d)
    shape = (64, 80)
    b = sj.Buffers(irradiance=jnp.ones(shape + (3,)), depth=jnp.full(shape, 100.0))
    f = match_frame(b, sj.Camera(200.0, 1.0), np.ones(shape + (3,)))  # 2 px per mm: d = 1 mm is 2 px
    m = held_mask(f, mat, held_fraction=0.99)
    ys, xs = np.nonzero(m)
    assert 14 <= xs.min() <= 19 and 14 <= ys.min() <= 19 and xs.max() == 79 - xs.min() and ys.max() == 63 - ys.min()
    m95 = held_mask(f, mat)  # the default, 0.95: ~4.1 d = 8.2 px from an edge (a corner counts both edges)
    ys, xs = np.nonzero(m95)
    assert 7 <= xs.min() <= 9 and 7 <= ys.min() <= 9 and m95.sum() > m.sum() > 0


@pytest.mark.usefixtures("float32")
def test_fit_reports_the_pixels_it_scored():
    shape = (24, 32)
    e = np.full(shape + (3,), 0.2, np.float32)
    e[:, 16:] = 1.0
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.full(shape, 100.0, jnp.float32))
    cam = sj.Camera(100.0, 1.0)  # 1 px per mm
    mat = sj.BurleyMaterial([0.6, 0.5, 0.4], [0.8, 0.5, 0.3])
    truth = np.asarray(sj.burley(b, mat, cam, samples=8, pattern="fixed"))
    f = match_frame(b, cam, truth)
    r = match_render(f, mat, samples=8, max_steps=2)
    held = held_mask(f, mat)
    assert r.scored["frames"][0]["scored_pixels"] == int(held.sum()) and 0 < held.sum() < held.size
    assert r.scored["frames"][0]["sss_pixels"] == held.size and np.array_equal(r.score_masks[0], held)
    assert r.to_json()["scored"]["rule"].startswith("SSS pixels holding >= 0.95")
    assert set(r.errors["fitted"]["scored"]) == {"before", "after"}
    r_all = match_render(f, mat, samples=8, max_steps=2, score="all")
    assert r_all.scored["frames"][0]["scored_pixels"] == held.size
    # a kernel wider than the frame leaves nothing to score: said, with the way out
    with pytest.raises(ValueError, match="no pixel of material id.*score='all'"):
        match_render(f, sj.BurleyMaterial([0.6, 0.5, 0.4], [20.0, 10.0, 5.0]), samples=8, max_steps=1)


@pytest.mark.usefixtures("float32")
def test_held_scoring_does_not_bend_d_for_light_lost_at_the_frame():
    # a close-up cut by the frame: the truth is Burley on a frame 16 px wider on every side, cropped, so the light
    # from beyond the crop is in it. Fitted on the crop with border="leaves", every pixel scored, d shrinks to make up
    # for the light its edge pixels lose; scoring the held pixels finds the true d (the same renders there)
    full, pad = (64, 80), 16
    y, x = np.mgrid[0:full[0], 0:full[1]]
    e = np.where((x // 12 + y // 12) % 2 == 0, 1.0, 0.15).astype(np.float32)[..., None] * np.ones(3, np.float32)
    depth = jnp.full(full, 100.0, jnp.float32)
    cam = sj.Camera(100.0, 1.0)  # 1 px per mm
    true = sj.BurleyMaterial([0.6, 0.5, 0.4], [1.2, 0.8, 0.5])
    opts = dict(samples=8, pattern="fixed", interpolation="bilinear", border="leaves")
    truth = np.asarray(sj.burley(sj.Buffers(irradiance=jnp.asarray(e), depth=depth), true, cam, **opts))
    crop = (slice(pad, -pad), slice(pad, -pad))
    f = match_frame(sj.Buffers(irradiance=jnp.asarray(e[crop]), depth=depth[crop]), cam, truth[crop])
    start = sj.BurleyMaterial([0.6, 0.5, 0.4], [1.5, 1.0, 0.625])
    fitted = {score: np.asarray(match_render(f, start, technique=sj.Burley(**opts), score=score, loss="l2",
                                             max_steps=12).parameters["id1"]["d_mm"]) for score in ("held", "all")}
    np.testing.assert_allclose(fitted["held"], [1.2, 0.8, 0.5], rtol=0.03)
    # measured (float32, 12 steps): all 0.965 / 0.78 / 0.78 of the true d, held 1.00 +- 0.03
    ratio = fitted["all"] / np.array([1.2, 0.8, 0.5])
    assert np.all(fitted["all"] < fitted["held"]) and ratio.mean() < 0.9, ratio


def test_advise_flags_candidates_worse_than_local_shading():
    from sss_jax._advise import Candidate, advise, measure_candidates

    def measure(material, **kw):
        return [Candidate("local", None, 0.1, 1.0), Candidate("burley", 8, 2.0, 1.5), Candidate("burley", 32, 5.0, 0.5)]

    advice = advise(sj.BurleyMaterial([0.5] * 3, [1.0] * 3), max_delta_e=2.0, measure=measure)
    assert [c.label for c in advice.worse_than_local] == ["burley 8"]
    assert advice.to_json()["worse_than_local_shading"] == ["burley 8"] and "worse than local shading" in advice.table()
    # against a truth given for the user's frame: the errors are against it (a truth equal to local shading makes
    # every scattering candidate worse than local shading)
    shape = (12, 16)
    e = np.zeros(shape + (3,))
    e[:, 8:] = 1.0
    b = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.full(shape, 10.0))
    cam = sj.Camera(10.0, 1.0)
    mat = sj.BurleyMaterial([0.8] * 3, [1.0] * 3)
    cands = measure_candidates(mat, buffers=b, camera=cam, truth=0.8 * e, candidates=(("local", None), ("burley", 8)),
                               repeats=1, timer=lambda fn, n: [1.0])
    assert cands[0].delta_e == pytest.approx(0.0, abs=1e-9) and cands[1].delta_e > 0.1


def test_blenders_half_float_passes_read_as_blender_wrote_them(tmp_path):
    # tests/data/cycles is Blender 3.4's own output with half-float colour: DiffDir/DiffInd half, Depth and IndexOB
    # float32 in one multi-layer file (per-channel formats), background depth 1e10. The frame reader gives what a
    # raw OpenImageIO read gives, and `sss-jax apply` on the file writes the pass the API computes on those buffers
    import OpenImageIO as oiio
    from test_match import _raw as raw_read

    from sss_jax import _io
    from sss_jax.cli import main

    path = CYCLES / "irradiance_closeup.exr"
    spec = oiio.ImageInput.open(str(path)).spec()
    formats = dict(zip(spec.channelnames, (str(f) for f in spec.channelformats)))
    assert formats["ViewLayer.DiffDir.R"] == "half" and formats["ViewLayer.Depth.Z"] == "float", formats
    b, cam, mat, _, mask = _cycles(CYCLES, "closeup")
    frame = _io.read_frame(path)
    np.testing.assert_array_equal(np.asarray(frame.irradiance), np.asarray(b.irradiance))
    np.testing.assert_array_equal(np.asarray(frame.depth), np.asarray(b.depth))  # 1e10 -> inf in both
    np.testing.assert_array_equal(np.asarray(frame.material_id), np.asarray(b.material_id))
    assert frame.focal_px == pytest.approx(cam.focal_px) and frame.mm_per_unit == pytest.approx(1000.0)
    a, d = np.asarray(mat.albedo)[0], np.asarray(mat.d_mm)[0]
    out = tmp_path / "closeup_sss.exr"
    assert main(["apply", str(path), "-o", str(out), "--technique", "burley", "--samples", "8", "--albedo",
                 ",".join(map(str, a)), "--d-mm", ",".join(map(str, d))]) == 0
    got = raw_read(out)
    rgb = np.stack([got[c] for c in "RGB"], -1)
    with jax.enable_x64(False):  # as the CLI computes
        want = np.asarray(sj.burley(b, sj.BurleyMaterial(np.float32(a), np.float32(d)), cam, samples=8), np.float64)
    # float32 either way, but the API's call and the batch's may round differently (alone they agree to 2e-6; in
    # the whole suite's order 5e-5 of a value apart was seen); a misread frame (another unit, layer or channel) is
    # off by far more
    np.testing.assert_allclose(rgb[mask], want[mask], rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("name, mean_before", [("marble_objects", 4.26), ("skin_occlusion", 2.58)])
def test_normals_from_depth_follow_the_renders_normal_pass(name, mean_before):
    # the rendered normal pass (Mitsuba's shading normals) is the truth; the depth pass is all normals_from_depth
    # sees. One-sided differences everywhere (the rule before) were 4.26 and 2.58 degrees off on average, 14.6 and
    # 16.4 at the 99th percentile; central differences on smooth surfaces 2.55 and 1.35, 7.5 and 8.4
    # (scripts/normals_vs_render.py)
    b, cam, _, _, sss, _ = _mitsuba(name)
    with jax.enable_x64(True):
        derived = np.asarray(sj.normals_from_depth(jnp.asarray(np.asarray(b.depth), jnp.float64),
                                                   sj.Camera(float(cam.focal_px), float(cam.mm_per_unit))))
    truth = np.asarray(b.normal, np.float64)
    angle = np.degrees(np.arccos(np.clip(np.sum(derived * truth, axis=-1), -1.0, 1.0)))[sss]
    assert angle.mean() < 0.6 * mean_before
    assert np.percentile(angle, 99) < 9.0
