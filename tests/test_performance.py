"""Cost that follows the scene: compaction, the footprint skip, the scale levels, one trace per shape, the advisor."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import sss_jax as sj
from sss_jax._techniques import _separable as separable_module
from sss_jax._advise import (
    Advice,
    Candidate,
    advise,
    choose,
    known_materials,
    resolve_material,
)
from sss_jax._techniques import burley_active_count, compaction_capacity, kernel_groups, weight_channel_count
from sss_jax._techniques._burley import _burley_impl
from sss_jax._techniques._separable import _separable_impl, _separable_pass
from sss_jax.cli import main

CAM = sj.Camera(focal_px=100.0, mm_per_unit=10.0)  # at depth 50: 0.2 px per mm
MAT = sj.BurleyMaterial(albedo=[0.9, 0.8, 0.7], d_mm=[6.0, 3.0, 1.5])


def _scene(coverage_rows: int, h=24, w=32, dtype=jnp.float64):
    rng = np.random.default_rng(0)
    e = rng.uniform(0.0, 2.0, (h, w, 3))
    depth = 50.0 + rng.uniform(0.0, 2.0, (h, w))
    ids = np.zeros((h, w), np.int32)
    ids[:coverage_rows] = 1
    return sj.Buffers(irradiance=jnp.asarray(e, dtype), depth=jnp.asarray(depth, dtype), material_id=jnp.asarray(ids))


def test_compaction_capacity_buckets_by_powers_of_two():
    assert compaction_capacity(1, 1 << 20) == 256  # a floor, so tiny counts share one compilation
    assert compaction_capacity(300, 1 << 20) == 512
    assert compaction_capacity(512, 1 << 20) == 512
    assert compaction_capacity(513, 1 << 20) == 1024
    assert compaction_capacity(600, 2000) is None  # the bucket would hold over half the frame: dense


def test_compacted_equals_dense():
    b = _scene(coverage_rows=3)
    assert burley_active_count(b, MAT, CAM) == 3 * 32
    dense = np.asarray(sj.burley(b, MAT, CAM, samples=8, compact=False))
    compacted = np.asarray(sj.burley(b, MAT, CAM, samples=8, compact=True))
    default = np.asarray(sj.burley(b, MAT, CAM, samples=8))  # 96 of 768 pixels: compacted by default
    np.testing.assert_allclose(compacted, dense, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(default, compacted)
    # the SSS rows did scatter (the comparison is not of two identities), the rest passed through
    assert np.abs(dense[:3] - 0.9 * np.asarray(b.irradiance)[:3, :, :1]).max() > 1e-3
    np.testing.assert_array_equal(dense[3:], np.asarray(b.irradiance)[3:])


def test_compaction_under_jit_falls_back_to_dense():
    b = _scene(coverage_rows=3)
    jitted = np.asarray(jax.jit(lambda bb: sj.burley(bb, MAT, CAM, samples=8))(b))
    np.testing.assert_allclose(jitted, np.asarray(sj.burley(b, MAT, CAM, samples=8)), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("technique", ["burley", "separable"])
def test_footprint_below_half_a_pixel_keeps_local_shading(technique):
    b = _scene(coverage_rows=24)
    # d = 0.05 mm: 99% of the energy within ~0.65 mm = 0.13 px at 0.2 px/mm, under half a pixel
    tiny = sj.BurleyMaterial(albedo=[0.9, 0.8, 0.7], d_mm=[0.05, 0.04, 0.03])
    run = {"burley": lambda **kw: sj.burley(b, tiny, CAM, samples=8, **kw),
           "separable": lambda **kw: sj.separable(b, tiny, CAM, taps=9, **kw)}[technique]
    local = np.asarray([0.9, 0.8, 0.7]) * np.asarray(b.irradiance)
    np.testing.assert_allclose(np.asarray(run()), local, rtol=1e-12)
    # without the skip the pass runs and differs from local shading (the test can fail)
    assert np.abs(np.asarray(run(min_footprint_px=0.0)) - local).max() > 1e-6
    assert burley_active_count(b, tiny, CAM) == 0 and burley_active_count(b, tiny, CAM, min_footprint_px=0.0) == 768
    with pytest.raises(ValueError, match="min_footprint_px must be >= 0"):
        run(min_footprint_px=-1.0)


def _equations(fn, *args, primitive: str):
    """Every equation of ``primitive`` in the traced computation, nested jaxprs (jit, loops, conds) included."""

    def walk(jaxpr):
        for eqn in jaxpr.eqns:
            if eqn.primitive.name == primitive:
                yield eqn
            for v in eqn.params.values():
                for sub in v if isinstance(v, (tuple, list)) else (v,):
                    if isinstance(sub, jax.extend.core.ClosedJaxpr):
                        yield from walk(sub.jaxpr)
                    elif isinstance(sub, jax.extend.core.Jaxpr):
                        yield from walk(sub)

    return list(walk(jax.make_jaxpr(fn)(*args).jaxpr))


def _exp_shapes(fn, *args) -> list[tuple[int, ...]]:
    """Output shapes of every ``exp`` in the traced computation."""
    return [tuple(eqn.outvars[0].aval.shape) for eqn in _equations(fn, *args, primitive="exp")]


def test_grey_channels_share_one_kernel_evaluation():
    b = _scene(coverage_rows=24)
    grey = sj.BurleyMaterial(albedo=[0.9, 0.8, 0.7], d_mm=[3.0, 3.0, 3.0])
    assert weight_channel_count(grey.d_mm) == 1 and weight_channel_count(MAT.d_mm) == 3
    assert weight_channel_count(jnp.asarray([[3.0] * 3, [2.0, 2.0, 2.1]])) == 3  # every material must be grey
    # the per-sample kernel (one exponential per pixel, corner and channel plane) is evaluated on one channel for the
    # grey material, on three otherwise: two fewer per corner, four corners (bilinear); and the weight of the part of
    # a fetch outside the frame (light that leaves) needs the kernel on each of the three planes, none for grey
    # (there it is the sampled profile's own R/pdf, 1)
    n = 24 * 32
    grey_exps = _exp_shapes(lambda bb: sj.burley(bb, grey, CAM, samples=8, compact=False), b)
    rgb_exps = _exp_shapes(lambda bb: sj.burley(bb, MAT, CAM, samples=8, compact=False), b)
    assert grey_exps.count((n,)) >= 4 and rgb_exps.count((n,)) - grey_exps.count((n,)) == 2 * 4 + 3
    # and the image is the one the three-channel evaluation gives
    shared = np.asarray(sj.burley(b, grey, CAM, samples=8, compact=False))
    per_channel = np.asarray(_burley_impl(b, grey, CAM, 8, "post", "bilinear", None, 0.5, 3, True))
    np.testing.assert_allclose(shared, per_channel, rtol=1e-12, atol=1e-14)
    assert np.abs(shared - 0.9 * np.asarray(b.irradiance)[..., :1]).max() > 1e-3  # it did scatter


def test_untruncated_frames_share_the_sample_radii():
    # a wide frame against a small d: the profile's tail beyond the image diagonal rounds away, so the per-pixel
    # truncated sampling and the shared radii give the same image; where the diagonal cuts the profile (large d) the
    # truncated sampling is kept, and it matters there
    b = _scene(coverage_rows=24, h=24, w=32)
    small = sj.BurleyMaterial(albedo=[0.9, 0.8, 0.7], d_mm=[0.6, 0.3, 0.15])  # 0.12 px: diagonal 40 px = 333 d
    large = sj.BurleyMaterial(albedo=[0.9, 0.8, 0.7], d_mm=[60.0, 30.0, 15.0])  # 12 px: diagonal 3.3 d
    impl = lambda m, truncate: np.asarray(_burley_impl(b, m, CAM, 8, "post", "bilinear", None, 0.0, 3, truncate))
    out_small = np.asarray(sj.burley(b, small, CAM, samples=8, min_footprint_px=0.0, compact=False))
    np.testing.assert_allclose(out_small, impl(small, True), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(out_small, impl(small, False))  # the shared radii are what ran
    out_large = np.asarray(sj.burley(b, large, CAM, samples=8, min_footprint_px=0.0, compact=False))
    np.testing.assert_array_equal(out_large, impl(large, True))
    assert np.abs(impl(large, False) - out_large).max() > 1e-3


@pytest.mark.parametrize("axis", [2, 1])
def test_separable_bands_compute_only_their_own_levels_and_agree_with_one_band(axis):
    # a frame of 19 rows (bands of 8 rows at rows 0, 8 and 11: the last overlaps), two materials with their own tap
    # weights, SSS pixels only in the middle rows, and two reach levels that each only some bands use; both passes
    # (the vertical one reads its taps across band boundaries)
    rng = np.random.default_rng(3)
    h, w, n = 19, 23, 5
    e = jnp.asarray(rng.uniform(0.0, 2.0, (3, h, w)))
    z = jnp.asarray(50.0 + rng.uniform(0.0, 3.0, (h, w)))
    valid = np.zeros((h, w), bool)
    valid[6:15] = True
    t = np.clip((np.arange(h)[:, None] - 6) / 8.0, 0, 1) * np.ones((1, w))  # level 0 at the top, level 1 below
    level_weights = jnp.asarray(np.stack([1 - t, t]) * valid[None])
    onehot = np.zeros((2, h, w))
    onehot[0, :, : w // 2], onehot[1, :, w // 2 :] = 1, 1
    w_table = jnp.asarray(rng.uniform(0.1, 1.0, (2, 3, n)))
    args = (e, z, jnp.asarray(valid), level_weights, jnp.asarray([2.0, 5.0]), jnp.asarray(~valid), jnp.asarray(onehot),
            w_table, jnp.full((h, w), 0.2), jnp.asarray(np.linspace(-1, 1, n)), jnp.asarray(10.0), True, "bilinear")
    banded = np.asarray(_separable_pass(*args, rows_per_band=8, axis=axis))
    whole = np.asarray(_separable_pass(*args, rows_per_band=h, axis=axis))
    np.testing.assert_allclose(banded, whole, rtol=1e-13, atol=1e-13)
    np.testing.assert_array_equal(banded[:, ~valid], np.asarray(e)[:, ~valid])  # rows without SSS keep their value
    assert np.abs(banded - np.asarray(e))[:, valid].max() > 1e-2  # and the others were filtered


def _numpy_depth_aware_pass(e, z, valid, w_table, rows, reach_px, reach_mm, unit_offsets, mm_per_unit, linear):
    """Jimenez's depth-aware horizontal 1D pass written directly, pixel by pixel in float64 (the shape of the
    SeparableSSS shader's loop): each tap is a linear (or nearest) fetch whose pixels count as far as they are valid
    and at the centre's depth ("follow the surface", full at equal depth, none at the kernel's reach), the rest of
    the tap counting as the centre colour, except the part off the frame, which is dark (light scattered out of the
    frame leaves). An independent check of the fused shifted-slice pass."""
    h, w = z.shape
    out = np.array(e, np.float64)
    for y in range(h):
        for x in range(w):
            if not valid[y, x]:
                continue
            acc = np.zeros(3)
            for i, u in enumerate(unit_offsets):
                pos = x + np.clip(u * reach_px, -(w + 1.0), w + 1.0)
                x0, f = np.floor(pos), pos - np.floor(pos)
                corners = [(int(x0), 1 - f), (int(x0) + 1, f)] if linear else [(int(np.round(pos)), 1.0)]
                sample = e[:, y, x].copy()
                for xi, frac in corners:
                    if not 0 <= xi < w:
                        sample -= frac * e[:, y, x]
                    elif valid[y, xi]:
                        follow = 1 - min(abs(z[y, xi] - z[y, x]) * mm_per_unit / reach_mm[y, x], 1.0)
                        sample += frac * follow * (e[:, y, xi] - e[:, y, x])
                acc += w_table[rows[y, x], :, i] * sample
            out[:, y, x] = acc
    return out


@pytest.mark.parametrize("axis", [2, 1])
@pytest.mark.parametrize("linear", [True, False])
@pytest.mark.parametrize("taps_per_fusion", [33, 3])
def test_separable_pass_matches_a_pixel_by_pixel_loop(axis, linear, taps_per_fusion, monkeypatch):
    # one reach level, two materials, a depth step (follow the surface), invalid pixels, taps reaching off the frame;
    # the 7 taps fused at once, or in chunks of 3 (the last padded with two taps of weight 0)
    monkeypatch.setattr(separable_module, "_TAPS_PER_FUSION", taps_per_fusion)
    assert separable_module.tap_chunks(7) == ((1, 7) if taps_per_fusion == 33 else (3, 3))
    rng = np.random.default_rng(5)
    h, w, n = 11, 13, 7
    e = rng.uniform(0.0, 2.0, (3, h, w))
    z = 50.0 + 4.0 * (np.arange(w)[None, :] >= 6) + rng.uniform(0.0, 0.5, (h, w))
    valid = rng.uniform(size=(h, w)) > 0.2
    rows = (np.arange(h)[:, None] + np.arange(w)[None, :]) % 2
    w_table = rng.uniform(0.05, 1.0, (2, 3, n))
    reach_mm = np.where(rows == 0, 20.0, 35.0)
    unit = np.linspace(-1.0, 1.0, n) ** 3
    reach_px, mm_per_unit = 3.7, 10.0
    t = (lambda a: np.swapaxes(a, -1, -2)) if axis == 1 else (lambda a: a)
    expected = t(_numpy_depth_aware_pass(t(e), t(z), t(valid), w_table, t(rows), reach_px, t(reach_mm), unit,
                                         mm_per_unit, linear))
    onehot = np.stack([rows == 0, rows == 1]).astype(np.float64)
    got = _separable_pass(jnp.asarray(e), jnp.asarray(z), jnp.asarray(valid), jnp.asarray(valid[None] * 1.0),
                          jnp.asarray([reach_px]), jnp.asarray(~valid), jnp.asarray(onehot), jnp.asarray(w_table),
                          jnp.asarray(1.0 / reach_mm), jnp.asarray(unit), jnp.asarray(mm_per_unit), True,
                          "bilinear" if linear else "nearest", rows_per_band=4, axis=axis)
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-12, atol=1e-12)
    assert np.abs(expected - e)[:, valid].max() > 0.1  # it filtered


def test_materials_sharing_a_kernel_share_its_weight_term():
    # three materials, the first and the third with one kernel (same d, other albedo): two kernels, not three
    mats = sj.BurleyMaterial(albedo=[[0.9, 0.8, 0.7], [0.5, 0.5, 0.5], [0.3, 0.6, 0.9]],
                             d_mm=[[6.0, 3.0, 1.5], [2.0, 1.0, 0.5], [6.0, 3.0, 1.5]])
    assert kernel_groups(mats) == (0, 1, 0)
    assert kernel_groups(sj.BurleyMaterial(albedo=[[1] * 3] * 2, d_mm=[[1.0] * 3, [2.0] * 3])) is None  # distinct
    assert kernel_groups(MAT) is None  # one material
    tg = sj.TwoGaussianMaterial(albedo=[[1] * 3, [0.5] * 3], w=[[0.5] * 3] * 2, sigma_near_mm=[[1.0] * 3] * 2,
                                sigma_far_mm=[[4.0] * 3, [4.0, 4.0, 5.0]])
    assert kernel_groups(tg) is None
    b = _scene(coverage_rows=24)
    ids = np.ones((24, 32), np.int32)
    ids[:, 10:20], ids[:, 20:] = 2, 3
    b = sj.Buffers(irradiance=b.irradiance, depth=b.depth, material_id=jnp.asarray(ids))
    args = (b, mats, CAM, 9, "post", True, "bilinear", 4, 0.5)
    shared = np.asarray(sj.separable(b, mats, CAM, taps=9))
    np.testing.assert_allclose(shared, np.asarray(_separable_impl(*args, None)), rtol=1e-12, atol=1e-14)
    albedo = np.asarray(mats.albedo)[ids - 1]
    assert np.abs(shared - albedo * np.asarray(b.irradiance)).max() > 1e-3  # it scattered (not local shading)
    # one per-pixel selection (an equality test against the material row) per kernel: two, not three
    eqs = {g: len(_equations(lambda bb, g=g: _separable_impl(bb, *args[1:], g), b, primitive="eq"))
           for g in (None, (0, 1, 0))}
    assert eqs[(0, 1, 0)] == eqs[None] - 1


def test_separable_levels_exact_for_one_reach_and_close_otherwise():
    rng = np.random.default_rng(1)
    e = jnp.asarray(rng.uniform(0, 2, (16, 20, 3)))
    # a strongly typed depth, like the tilted plane's below: the two share each level count's compilation
    flat = sj.Buffers(irradiance=e, depth=jnp.full((16, 20), 50.0, jnp.float64))
    one, four = (np.asarray(sj.separable(flat, MAT, CAM, taps=9, scale_levels=n)) for n in (1, 3))
    np.testing.assert_allclose(four, one, rtol=1e-12)  # every pixel has the same reach: the levels coincide
    # a tilted plane (reach varying by 30% across the frame): more levels follow the per-pixel reach more closely
    tilted = sj.Buffers(irradiance=e, depth=jnp.asarray(45.0 + 15.0 * np.linspace(0, 1, 20)[None, :] * np.ones((16, 1))))
    fine = np.asarray(sj.separable(tilted, MAT, CAM, taps=9, scale_levels=12))
    err = {n: np.abs(np.asarray(sj.separable(tilted, MAT, CAM, taps=9, scale_levels=n)) - fine).max() for n in (2, 3)}
    assert err[3] < err[2]
    with pytest.raises(ValueError, match="scale_levels must be a positive integer"):
        sj.separable(flat, MAT, CAM, scale_levels=0)


def test_one_trace_per_shape_in_a_batch():
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def run(batch):
        return jax.vmap(lambda bb: sj.burley(bb, MAT, CAM, samples=4))(batch)

    for seed in range(3):  # different coverage per batch: the shape alone decides the compilation
        rng = np.random.default_rng(seed)
        ids = (rng.uniform(size=(2, 12, 16)) < 0.1 * (seed + 1)).astype(np.int32)
        batch = sj.Buffers(irradiance=jnp.asarray(rng.uniform(0, 1, (2, 12, 16, 3))),
                           depth=jnp.full((2, 12, 16), 50.0), material_id=jnp.asarray(ids))
        assert np.all(np.isfinite(np.asarray(run(batch))))


# ------------------------------------------------------------------------------------------------------------------
# the advisor, on a stubbed measurement table
# ------------------------------------------------------------------------------------------------------------------

TABLE = [Candidate("local", None, 0.5, 3.0), Candidate("separable", 5, 4.0, 1.2), Candidate("separable", 9, 6.0, 0.8),
         Candidate("burley", 8, 5.0, 2.0), Candidate("burley", 32, 20.0, 0.4)]


def test_choose_the_fastest_within_budget():
    pick, why = choose(TABLE, 1.0)
    assert (pick.technique, pick.count) == ("separable", 9)
    assert "separable 9" in why and "misses the budget" in why
    assert choose(TABLE, 5.0)[0].technique == "local"
    assert choose(TABLE, 0.5)[0].count == 32
    pick, why = choose(TABLE, 0.1)
    assert pick is None and "no candidate" in why and "burley 32" in why


def test_advise_uses_the_measurement_and_explains():
    seen = {}

    def measure(mat, **kw):
        seen.update(kw, mat=mat)
        return TABLE

    advice = advise("skin", max_delta_e=1.0, scene_scale=2.0, measure=measure)
    assert isinstance(advice, Advice) and advice.choice == TABLE[2] and advice.material == "skin"
    np.testing.assert_allclose(np.asarray(seen["mat"].d_mm).ravel(), [3.0, 1.4, 0.8], rtol=1e-6)
    assert seen["scene_scale"] == 2.0
    table = advice.table()
    assert "<- choice" in table and table.count("\n") == len(TABLE) + 1
    assert json.loads(json.dumps(advice.to_json()))["choice"]["count"] == 9


def test_unknown_material_lists_the_known_ones():
    assert {"skin", "marble", "wax"} <= set(known_materials())
    with pytest.raises(ValueError, match="unknown material 'unobtainium'.*skin"):
        resolve_material("unobtainium")


def test_advise_cli(tmp_path, monkeypatch, capsys):
    import sss_jax._advise as adv

    monkeypatch.setattr(adv, "measure_candidates", lambda mat, **kw: TABLE)
    out = tmp_path / "a.json"
    assert main(["advise", "--material", "marble", "--max-delta-e", "1.0", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "separable 9" in printed and "<- choice" in printed
    assert json.loads(out.read_text())["choice"]["technique"] == "separable"
    assert main(["advise", "--material", "marble", "--max-delta-e", "0.1"]) == 1  # nothing meets the budget
    assert main(["advise", "--material", "unobtainium", "--max-delta-e", "1"]) == 2
    assert main(["advise", "--material", "skin", "--max-delta-e", "-1"]) == 2
    assert "must be >= 0" in capsys.readouterr().err


def test_advise_measures_for_real():
    advice = advise("wax", max_delta_e=2.0, size=(24, 32), repeats=1,
                    candidates=(("local", None), ("separable", 5), ("burley", 8)))
    assert {c.technique for c in advice.candidates} == {"local", "separable", "burley"}
    assert all(c.ms > 0 and c.delta_e >= 0 for c in advice.candidates)
