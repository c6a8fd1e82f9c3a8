"""Property-based tests (hypothesis) of the invariants every pass must keep."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings, strategies as st

import sss_jax as sj

SETTINGS = settings(max_examples=15, deadline=None)
H, W = 10, 12
CAM = sj.Camera(focal_px=80.0, mm_per_unit=10.0)
positive = st.floats(min_value=1e-3, max_value=50.0, allow_nan=False)
triples = st.tuples(positive, positive, positive)


def _buffers(e, depth):
    return sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.asarray(depth))


@jax.jit
def _passes(e, depth, d):
    b = _buffers(e, depth)
    mat = sj.BurleyMaterial(jnp.ones(3), d)
    # 2x2 sub-pixel rule near the centre (as in tests/test_techniques.py): the invariants below hold for any rule,
    # and the 6x6 default triples this function's compile time
    return (sj.burley(b, mat, CAM, samples=8), sj.separable(b, mat, CAM, taps=7),
            sj.reference(b, mat, CAM, radius_px=4, near_subsamples=2))


# the kernel builders jitted (taps static, one compilation per tap count): eagerly, every example would dispatch
# (and on first use compile) each of their operations one by one, ~270 compilations for the six tap counts
_preintegrated_kernel = jax.jit(sj.separable_kernel_from_profile, static_argnames="taps")
_two_gaussian_kernel = jax.jit(sj.two_gaussian_kernel, static_argnames="taps")


@SETTINGS
@given(triples, st.sampled_from([5, 9, 25]))
def test_preintegrated_weights_sum_to_one(d, taps):
    k = _preintegrated_kernel(sj.BurleyProfile(jnp.asarray(d)), taps=taps)
    np.testing.assert_allclose(np.asarray(k.weights).sum(0), 1.0, rtol=1e-9)
    assert np.all(np.asarray(k.weights) >= 0)


@SETTINGS
@given(st.tuples(*[st.floats(0, 1)] * 3), triples, triples, st.sampled_from([3, 7, 33]))
def test_two_gaussian_weights_sum_to_one(w, s_near, s_far, taps):
    k = _two_gaussian_kernel(jnp.asarray(w), jnp.asarray(s_near), jnp.asarray(s_far), taps=taps)
    np.testing.assert_allclose(np.asarray(k.weights).sum(0), 1.0, rtol=1e-9)


@SETTINGS
@given(st.integers(0, 2**31 - 1), triples, st.floats(-50, 50), st.floats(0.5, 3.0))
def test_linear_and_no_energy_created(seed, d, a, slope):
    rng = np.random.default_rng(seed)
    e1, e2 = rng.uniform(0, 2, (H, W, 3)), rng.uniform(0, 2, (H, W, 3))
    depth = 40.0 + slope * np.linspace(0, 1, W)[None, :] * np.ones((H, 1))
    d = jnp.asarray(d)
    c = abs(a)
    out1, out2, out12 = _passes(e1, depth, d), _passes(e2, depth, d), _passes(2 * e1 + c * e2, depth, d)
    for o1, o2, o12 in zip(out1, out2, out12):
        np.testing.assert_allclose(np.asarray(o12), 2 * np.asarray(o1) + c * np.asarray(o2), rtol=1e-9, atol=1e-9)
        # each output is a weighted mean of the inputs and of the dark beyond the frame (light that scatters out of
        # it leaves; albedo 1): no pixel exceeds the brightest input, none goes negative
        assert np.asarray(o1).max() <= e1.max() * (1 + 1e-12)
        assert np.asarray(o1).min() >= 0


def test_linear_where_one_channel_is_twenty_thousand_times_narrower_than_the_widest():
    # hypothesis's example (seed 0): d_B = 0.001 mm beside d_G = 20.5 mm. Every sample lies >= ~1 mm out, where B's
    # weights were ~1e-307: their products with the irradiance fell below float64's smallest normal, which XLA's CPU
    # backend flushes to 0, so 8 pixels of B came out 0 and burley(2 e) != 2 burley(e) (by up to 1.38). The weights
    # are now scaled by the nearest sample's exponent (``weight_offset``)
    rng = np.random.default_rng(0)
    e = rng.uniform(0, 2, (H, W, 3))
    depth = 40.0 + np.linspace(0, 1, W)[None, :] * np.ones((H, 1))
    d = jnp.asarray((1.0, 20.5, 0.001))
    for o1, o2 in zip(_passes(e, depth, d), _passes(2 * e, depth, d)):
        np.testing.assert_allclose(np.asarray(o2), 2 * np.asarray(o1), rtol=1e-9, atol=1e-9)
        assert np.asarray(o1).min() > 0  # every input is positive: so is every weighted mean of them


# mm: at most 0.06 px at depth 20 (0.4 px per mm), so all but ~e^-16.7 (the exp(-r/3d) tail) of every profile
# lies within 3 px
narrow = st.floats(min_value=1e-3, max_value=0.15, allow_nan=False)


@SETTINGS
@given(st.floats(0.01, 100.0), st.tuples(narrow, narrow, narrow), st.floats(0.0, 5.0), st.floats(20.0, 80.0))
def test_flat_stays_flat_on_a_smooth_surface(level, d, slope, base):
    # away from the frame's border (where light leaves through it) flat light stays flat on a tilted plane
    e = np.full((H, W, 3), level)
    ys, xs = np.mgrid[0:H, 0:W]
    depth = base + slope * (xs / W + 0.5 * ys / H)  # a tilted plane: no depth edges
    for out in _passes(e, depth, jnp.asarray(d)):
        np.testing.assert_allclose(np.asarray(out)[3:-3, 3:-3], level, rtol=1e-7)
        assert np.asarray(out).max() <= level * (1 + 1e-9)


@SETTINGS
@given(st.integers(0, 2**31 - 1))
def test_zero_width_is_identity(seed):
    e = np.random.default_rng(seed).uniform(0, 5, (H, W, 3))
    for out in _passes(e, np.full((H, W), 30.0), jnp.zeros(3)):
        np.testing.assert_allclose(np.asarray(out), e, rtol=1e-12)


# energy: a flat plane, light only in the middle, every kernel shorter than the dark margin (so no border effects)
HE, WE, MARGIN = 16, 16, 5
CAM_E = sj.Camera(focal_px=80.0, mm_per_unit=10.0)  # at depth 40: 0.2 px per mm, so 5 px are 25 mm


@jax.jit
def _energy_passes(e, d, w, s_near, s_far):
    b = _buffers(e, jnp.full((HE, WE), 40.0))
    burley_mat = sj.BurleyMaterial(jnp.ones(3), d)
    tg = sj.TwoGaussianMaterial(jnp.ones(3), w, s_near, s_far)
    return (sj.burley(b, burley_mat, CAM_E, samples=16, pattern="fixed"), sj.separable(b, burley_mat, CAM_E, taps=9),
            sj.separable(b, tg, CAM_E, taps=9), sj.burley(b, burley_mat, CAM_E, samples=16))


def _vec(x: float) -> jnp.ndarray:
    """(3,) float64, strongly typed: ``jnp.full(3, x)`` alone is weakly typed, and a weak argument of
    ``_energy_passes`` where another test passes a strong one would compile it a second time."""
    return jnp.full(3, x, jnp.float64)


small = st.floats(min_value=1e-3, max_value=0.5, allow_nan=False)  # d in mm: 99.9% of the energy within ~2 px
sigmas = st.floats(min_value=0.0, max_value=2.0, allow_nan=False)  # 3 sigma = 6 mm = 1.2 px


@SETTINGS
@given(st.integers(0, 2**31 - 1), st.tuples(small, small, small), st.floats(0, 1), sigmas, sigmas)
def test_no_energy_created_on_a_flat_plane(seed, d, w, s_near, s_far):
    e = np.zeros((HE, WE, 3))
    inner = (slice(MARGIN, HE - MARGIN), slice(MARGIN, WE - MARGIN))
    e[inner] = np.random.default_rng(seed).uniform(0, 10, (HE - 2 * MARGIN, WE - 2 * MARGIN, 3))
    outs = _energy_passes(e, jnp.asarray(d), _vec(w), _vec(s_near), _vec(s_far))
    # Burley with the spiral turned per pixel gathers with other weights at every pixel: it keeps the energy in
    # expectation only (the sampling noise; 16 samples on this small frame: well under 3%)
    rotated = np.asarray(outs[3])
    np.testing.assert_allclose(rotated.sum(axis=(0, 1)), e.sum(axis=(0, 1)), rtol=0.03)
    assert rotated.min() >= 0
    for out in outs[:3]:
        out = np.asarray(out)
        # a normalised gather with the same weights at every pixel of a plane moves light, it never adds any
        # (albedo 1): sum over the image out = sum in, up to rounding
        assert np.all(out.sum(axis=(0, 1)) <= e.sum(axis=(0, 1)) * (1 + 1e-9) + 1e-12)
        np.testing.assert_allclose(out.sum(axis=(0, 1)), e.sum(axis=(0, 1)), rtol=1e-6)
        assert out.min() >= 0


@SETTINGS
@given(st.integers(0, 2**31 - 1), st.floats(0, 1))
def test_zero_width_two_gaussian_is_identity(seed, w):
    e = np.random.default_rng(seed).uniform(0, 5, (HE, WE, 3))
    zero = _vec(0.0)
    out = _energy_passes(e, _vec(0.1), _vec(w), zero, zero)[2]
    np.testing.assert_allclose(np.asarray(out), e, rtol=1e-12)
