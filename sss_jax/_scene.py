"""The buffers a screen-space pass reads, the pinhole camera, and the procedural demo scene.

Conventions (DESIGN.md): images ``(H, W, 3)`` linear scene-referred RGB; depth ``(H, W)`` planar view depth in
scene units, ``inf`` (or any non-finite or non-positive value) where there is no surface; camera space is
x right, y down, z forward; ``Camera.mm_per_unit`` says how many millimetres one scene unit is.
"""

from __future__ import annotations

import math
import threading
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._checks import is_bool
from ._custom_types import ParamLike
from ._materials import DirectionalLight

__all__ = ["Camera", "Buffers", "validate_buffers", "surface_mask", "camera_positions", "normals_from_depth",
           "demo_scene", "DemoScene"]


class Camera(eqx.Module):
    """Pinhole camera: focal length in pixels, scene unit in millimetres, principal point in pixels.

    ``principal_point`` defaults to the image centre when None (static: it decides no shapes, but is host data).
    """

    focal_px: Float[Array, ""]
    mm_per_unit: Float[Array, ""]
    principal_point: tuple[float, float] | None = eqx.field(static=True, default=None)

    def __init__(self, focal_px: ParamLike, mm_per_unit: ParamLike = 1.0, principal_point=None):
        for name, value in (("focal_px", focal_px), ("mm_per_unit", mm_per_unit)):
            if is_bool(value):  # True reads as 1
                raise TypeError(f"camera {name} must be a number, not a bool, got {value!r}")
        self.focal_px = jnp.asarray(focal_px, dtype=jnp.result_type(jnp.asarray(focal_px).dtype, jnp.float32))
        self.mm_per_unit = jnp.asarray(mm_per_unit, dtype=self.focal_px.dtype)
        self.principal_point = None if principal_point is None else (float(principal_point[0]), float(principal_point[1]))
        for name, v in (("focal_px", self.focal_px), ("mm_per_unit", self.mm_per_unit)):
            if not isinstance(v, jnp.ndarray) or v.shape != ():
                raise ValueError(f"camera {name} must be a scalar, got shape {getattr(v, 'shape', None)}")
            try:
                value = float(v)
            except Exception:  # traced: checked by the caller outside jit
                continue
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"camera {name} must be a finite positive number, got {value}")


class Buffers(eqx.Module):
    """What a screen-space pass reads for one frame (a batch adds a leading axis and is vmapped).

    - ``irradiance (H, W, 3)``: linear RGB irradiance (diffuse light before albedo).
    - ``depth (H, W)``: planar view depth in scene units; ``inf`` (or anything from ``BACKGROUND_DEPTH``, 1e9, on:
      Blender's 1e10) where there is no surface.
    - ``albedo (H, W, 3)`` optional: surface colour in [0, 1]; when absent the material's albedo is used.
    - ``normal (H, W, 3)`` optional: unit normals in camera space (STA); derived from depth when absent.
    - ``thickness (H, W)`` optional: object thickness along the light in scene units (STA, transmission).
    - ``material_id (H, W)`` optional int: 0 = no SSS (passes through untouched), k >= 1 selects material k.
    """

    irradiance: Float[Array, "*batch H W 3"]
    depth: Float[Array, "*batch H W"]
    albedo: Float[Array, "*batch H W 3"] | None = None
    normal: Float[Array, "*batch H W 3"] | None = None
    thickness: Float[Array, "*batch H W"] | None = None
    material_id: Int[Array, "*batch H W"] | None = None

    def __check_init__(self):
        # a batch adds leading axes: check the trailing (H, W[, 3]) dimensions
        e, z = self.irradiance, self.depth
        if e.ndim < 3 or e.shape[-1] != 3:
            raise ValueError(f"irradiance must have shape (H, W, 3), got {e.shape}")
        if z.shape != e.shape[:-1]:
            raise ValueError(f"depth shape {z.shape} does not match irradiance shape {e.shape} (expected {e.shape[:-1]})")
        for name, shape in (("albedo", e.shape), ("normal", e.shape), ("thickness", z.shape), ("material_id", z.shape)):
            buf = getattr(self, name)
            if buf is not None and buf.shape != shape:
                raise ValueError(f"{name} shape {buf.shape} does not match irradiance {e.shape} (expected {shape})")
        for name in ("irradiance", "depth", "albedo", "normal", "thickness"):
            buf = getattr(self, name)
            if buf is not None and not jnp.issubdtype(buf.dtype, jnp.floating):
                raise ValueError(f"{name} must be a floating-point array, got dtype {buf.dtype}")
        if self.material_id is not None and not jnp.issubdtype(self.material_id.dtype, jnp.integer):
            raise ValueError(f"material_id must be an integer array, got dtype {self.material_id.dtype}")

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape[-2:])


def on_host(x) -> bool:
    """Whether reading ``x`` costs no transfer: a NumPy array (or a Python value), or a JAX array on the host's CPU
    devices (read zero-copy); not an accelerator's array, whose read-back would wait for the device."""
    devices = getattr(x, "devices", None)
    return devices is None or all(d.platform == "cpu" for d in devices())


def _first_pixel(bad: np.ndarray) -> str:
    """Where the first ``True`` of ``bad`` (``(..., H, W)``: leading axes are a batch's frames) lies."""
    *lead, row, col = (int(i) for i in np.unravel_index(int(np.argmax(bad.reshape(-1))), bad.shape))
    return f"row {row}, column {col}" + (f" of frame {tuple(lead)}" if lead else "")


def validate_buffers(buffers: Buffers, *, materials: int | None = None, name: str | None = None,
                     physical: bool = True) -> None:
    """Host-side value checks (outside jit) with messages that name the buffer, the offending values and the first
    pixel holding one (``name``: the caller, e.g. a technique, put before the message).

    What would make a technique's result wrong without a word, always:

    - ``irradiance``, ``albedo`` and ``normal``: finite (a NaN or inf irradiance pixel with SSS spreads to every pixel
      that reads it); ``thickness``: not NaN (every model reads a negative thickness as 0, as the file reader does,
      and inf as infinitely thick);
    - ``material_id``: >= 0 and, with ``materials`` > 1 rows, at most ``materials`` (a larger id would take the last
      row's parameters). Depth needs no check: NaN, inf, 0, negative and background depths mean no surface.

    With ``physical`` (the default; the batch and the command line on files), what a renderer writes, too:
    ``irradiance`` >= 0 and ``albedo`` within [0, 1]. The technique functions check with ``physical=False``: the
    passes are linear in the irradiance (a signed input, a difference of two lightings, is filtered as such) and clip
    the albedo to [0, 1] as documented.

    Each buffer is read through its minimum and maximum (NaN carries through both), ~0.1 ms at 640x360; the counts
    and the pixel are computed only for a buffer that fails. The technique functions run this on concrete buffers held
    on the host (``_techniques._common.check_one_image``); under ``jit``/``vmap``, or for buffers on an accelerator,
    call it yourself.

    ``validate_planes`` checks planes themselves (a batch's, on the host, before they go to the device).
    Buffers of JAX arrays (immutable) that pass are remembered, weakly and by identity with ``materials`` and
    ``physical``, and not read again: the batch checks a frame and then calls its technique, a fit calls one
    technique many times on one frame."""
    if passed(buffers, materials, physical=physical):
        return
    validate_planes(buffers.irradiance, albedo=buffers.albedo, normal=buffers.normal, thickness=buffers.thickness,
                    material_id=buffers.material_id, materials=materials, name=name, physical=physical)
    _remember(buffers, materials, physical)


Plane = Array | np.ndarray


def validate_planes(irradiance: Plane, *, albedo: Plane | None = None, normal: Plane | None = None,
                    thickness: Plane | None = None, material_id: Plane | None = None, materials: int | None = None,
                    name: str | None = None, physical: bool = True) -> None:
    """``validate_buffers``' checks of the planes themselves, JAX or NumPy arrays, nothing remembered: a batch checks
    a frame's NumPy planes (``Frame.host_planes``) on the host before they go to the device, where JAX's CPU
    backend makes an array readable only once the computations queued before it are done (and an accelerator's
    would be copied back), then keeps the device buffers as checked (``remember_validated``)."""
    prefix = f"{name}: " if name else ""

    def fail(what: str, bad: np.ndarray, rule: str, *, channels: bool = True):
        count = int(np.count_nonzero(bad))
        bad = bad.any(axis=-1) if channels else bad  # the pixel: (..., H, W)
        raise ValueError(f"{prefix}{what.format(n=count, s='' if count == 1 else 's')}, the first at "
                         f"{_first_pixel(bad)}; {rule}")

    def values(x):
        v = np.asarray(x)
        return v, (v.min(), v.max()) if v.size else (0, 0)

    finite = lambda lo, hi: bool(np.isfinite(lo) and np.isfinite(hi))
    e, (lo, hi) = values(irradiance)
    if not finite(lo, hi):
        fail("irradiance has {n} non-finite value{s} (NaN or inf)", ~np.isfinite(e), "irradiance must be finite")
    if physical and lo < 0:
        fail(f"irradiance has {{n}} negative value{{s}} (min {float(lo):.3g})", e < 0, "irradiance must be >= 0")
    if albedo is not None:
        a, (lo, hi) = values(albedo)
        if physical and not (lo >= 0 and hi <= 1):  # NaN fails both
            fail("albedo buffer has {n} value{s} outside [0, 1] or NaN", ~((a >= 0) & (a <= 1)),
                 "the albedo buffer must be finite and within [0, 1]")
        if not finite(lo, hi):
            fail("albedo buffer has {n} non-finite value{s} (NaN or inf)", ~np.isfinite(a),
                 "the albedo buffer must be finite")
    if thickness is not None:
        t, (lo, _) = values(thickness)
        if np.isnan(lo):
            fail("thickness buffer has {n} NaN value{s}", np.isnan(t),
                 "thickness must not be NaN (a negative value reads as 0, inf as infinitely thick)", channels=False)
    if normal is not None:
        nrm, (lo, hi) = values(normal)
        if not finite(lo, hi):
            fail("normal buffer has {n} non-finite value{s}", ~np.isfinite(nrm), "normals must be finite")
    if material_id is not None:
        ids, (lo, hi) = values(material_id)
        if lo < 0:
            fail(f"material_id has {{n}} negative id{{s}} (min {int(lo)})", ids < 0, "ids must be >= 0", channels=False)
        if materials is not None and materials > 1 and hi > materials:
            fail(f"material_id uses id {int(hi)} but only {materials} materials were given (ids 1..{materials}): "
                 "{n} pixel{s} above", ids > materials, "an id k selects material row k (0: no SSS)", channels=False)


# ``validate_buffers``' passed buffers: id -> (weak reference, materials, physical); a few, the newest kept
_PASSED: dict[int, tuple[weakref.ref, int | None, bool]] = {}
_PASSED_LOCK = threading.Lock()
_PASSED_KEPT = 16


def passed(buffers: Buffers, materials: int | None, *, physical: bool = True) -> bool:
    """Whether ``validate_buffers(buffers, materials=materials, physical=physical)`` passed before (remembered): a
    frame that passed the physical rules passes the others."""
    entry = _PASSED.get(id(buffers))
    return (entry is not None and entry[0]() is buffers and entry[1] == materials
            and (entry[2] or not physical))


def remember_validated(buffers: Buffers, *, materials: int | None, physical: bool = True) -> None:
    """Keep ``buffers`` (JAX arrays) as passed by ``validate_buffers``, where their caller checked the same values on
    the host before putting them on the device (``validate_planes`` of ``Frame.host_planes``, then
    ``Frame.to_buffers``): reading them back would wait for every computation queued on the device before them
    (JAX's CPU backend), or copy them back (an accelerator)."""
    _remember(buffers, materials, physical)


def _remember(buffers: Buffers, materials: int | None, physical: bool) -> None:
    """Keep ``buffers`` as passed where its arrays cannot change (JAX arrays; a NumPy array could be written)."""
    if not all(isinstance(leaf, jax.Array) for leaf in jax.tree.leaves(buffers)):
        return
    with _PASSED_LOCK:
        known = _PASSED.pop(id(buffers), None)
        if known is not None and known[0]() is buffers and known[1] == materials:
            physical = physical or known[2]  # the stricter pass stands
        _PASSED[id(buffers)] = (weakref.ref(buffers), materials, physical)
        while len(_PASSED) > _PASSED_KEPT:
            _PASSED.pop(next(iter(_PASSED)))


# Depths from here on are background, not a surface: Blender writes 1e10 where there is none, other renderers
# FLT_MAX or 1e20; as surfaces, their squared distances overflow float32 and the gradients turn NaN. (1e9 scene
# units is 1000 km in metres.) The file reader maps them to inf.
BACKGROUND_DEPTH = 1e9


def surface_mask(depth: Array | np.ndarray) -> Array | np.ndarray:
    """Pixels with a surface: positive depth below ``BACKGROUND_DEPTH`` (inf, NaN, 0 and a background's huge
    finite depth are none). Operators only: a NumPy depth gives a NumPy mask (host side, no dispatch). A float16
    depth cannot hold ``BACKGROUND_DEPTH`` (its largest value is 65504): every finite positive value is a surface."""
    dtype = getattr(depth, "dtype", None)
    if dtype is not None and np.dtype(dtype) == np.float16:  # 1e9 cast to float16 overflowed, with numpy's warning
        return (depth > 0) & (depth < math.inf)
    return (depth > 0) & (depth < BACKGROUND_DEPTH)


def _principal_point(camera: Camera, shape: tuple[int, int]) -> tuple[float, float]:
    h, w = shape
    return camera.principal_point if camera.principal_point is not None else (w / 2, h / 2)


def _depth_plane(depth, camera: Camera, who: str) -> Array:
    """``depth`` as an (H, W) floating-point array (an integer plane as the default float), or an error naming
    ``who`` and what is wrong; ``camera`` must be a ``Camera``."""
    if not isinstance(camera, Camera):
        raise TypeError(f"{who}: camera must be a Camera, got {type(camera).__name__}")
    try:
        depth = jnp.asarray(depth)
    except (TypeError, ValueError):
        raise TypeError(f"{who}: depth must be an (H, W) array of depths, got {type(depth).__name__}") from None
    if depth.ndim != 2:
        raise ValueError(f"{who}: depth must be an (H, W) array of depths, got shape {depth.shape}")
    if not jnp.issubdtype(depth.dtype, jnp.floating):
        depth = depth.astype(jnp.result_type(float))
    return depth


def camera_positions(depth: Array, camera: Camera) -> Array:
    """Camera-space position ``(H, W, 3)`` of each pixel centre at its planar depth (scene units)."""
    return _positions(_depth_plane(depth, camera, "camera_positions"), camera)


def _positions(depth: Array, camera: Camera) -> Array:
    """``camera_positions`` of a depth plane ``_depth_plane`` has checked."""
    h, w = depth.shape
    cx, cy = _principal_point(camera, (h, w))
    dtype = depth.dtype
    xs = (jnp.arange(w, dtype=dtype) + 0.5 - cx) / camera.focal_px.astype(dtype)
    ys = (jnp.arange(h, dtype=dtype) + 0.5 - cy) / camera.focal_px.astype(dtype)
    z = jnp.where(surface_mask(depth), depth, jnp.ones_like(depth))
    return jnp.stack([xs[None, :] * z, ys[:, None] * z, z], axis=-1)


def view_directions(depth: Array, camera: Camera) -> Array:
    """Unit camera-space directions ``(H, W, 3)`` from each pixel centre towards the camera: its ray's, which a
    surface's depth only scales (``-p / |p|`` of ``camera_positions`` underflowed in float32 at a depth of 1e-20,
    the squares of its components flushed to 0, and gave 0/0)."""
    h, w = _depth_plane(depth, camera, "view_directions").shape
    cx, cy = _principal_point(camera, (h, w))
    dtype = depth.dtype
    xs = (jnp.arange(w, dtype=dtype) + 0.5 - cx) / camera.focal_px.astype(dtype)
    ys = (jnp.arange(h, dtype=dtype) + 0.5 - cy) / camera.focal_px.astype(dtype)
    ray = jnp.stack(jnp.broadcast_arrays(xs[None, :], ys[:, None], jnp.ones((h, w), dtype)), axis=-1)
    return -ray / jnp.linalg.norm(ray, axis=-1, keepdims=True)


def normals_from_depth(depth: Array, camera: Camera) -> Array:
    """Unit camera-space normals from differences of the reconstructed positions: central where both neighbours
    along an axis have a surface and their depth changes differ by at most the pixel's lateral size (depth / focal
    length: a smooth surface), else one-sided, on the side whose depth changes least (a silhouette, a crease, the
    frame's edge, a pixel beside no surface); facing the camera where nothing can be derived.

    Against the renders' own normal passes (the angle on the SSS pixels, mean and 99th percentile, one-sided
    everywhere as before -> this; 2026-12-07, ``scripts/normals_vs_render.py``): the Cycles back-lit frame
    (``../shared/reference/blender``) 3.82 / 44.1 -> 3.28 / 44.0 degrees, Mitsuba marble objects 4.26 / 14.6 -> 2.55 /
    7.5, skin occlusion 2.58 / 16.4 -> 1.35 / 8.4 (``tests/data/mitsuba``); skin back-lit 0.057 -> 0.055. Central
    wherever both sides have a surface did worse at the largest angles (p99 49.2 on the Cycles frame: it averages
    across creases and silhouettes)."""
    depth = _depth_plane(depth, camera, "normals_from_depth")
    p = _positions(depth, camera)
    valid = surface_mask(depth)
    lateral = jnp.abs(p[..., 2]) / camera.focal_px.astype(p.dtype)

    def diff(axis):
        fwd = jnp.roll(p, -1, axis=axis) - p
        bwd = p - jnp.roll(p, 1, axis=axis)
        v_f = valid & jnp.roll(valid, -1, axis=axis)
        v_b = valid & jnp.roll(valid, 1, axis=axis)
        n = depth.shape[axis]
        idx = jnp.arange(n)
        shape = [1, 1]
        shape[axis] = n
        idx = idx.reshape(shape)
        v_f = v_f & (idx < n - 1)
        v_b = v_b & (idx > 0)
        # central on a smooth surface (the two sides' depth changes differ by at most the pixel's lateral size, z / f:
        # no silhouette or crease between them); else the side whose depth changes least
        smooth = v_f & v_b & (jnp.abs(fwd[..., 2] - bwd[..., 2]) <= lateral)
        a_f, a_b = jnp.abs(fwd[..., 2]), jnp.abs(bwd[..., 2])
        use_f = v_f & (~v_b | (a_f <= a_b))
        use_b = v_b & ~use_f
        one_sided = jnp.where(use_f[..., None], fwd, jnp.where(use_b[..., None], bwd, 0.0))
        return jnp.where(smooth[..., None], 0.5 * (fwd + bwd), one_sided)

    dx, dy = diff(1), diff(0)
    n = jnp.cross(dy, dx)  # x right, y down, z forward: dy x dx points towards the camera (-z)
    # the norm from a square kept away from 0 where it is not used: a pixel with surface neighbours along one axis
    # only (a 1-pixel strip, a 1-row frame) has n = 0, and the norm's derivative there (0 / 0) made the depth's
    # gradient NaN though the normal (facing the camera) does not move
    sq = jnp.sum(n * n, axis=-1, keepdims=True)
    ok = (sq > 0) & jnp.isfinite(sq)  # an overflowing cross product (absurd focal lengths) faces the camera
    facing = jnp.zeros_like(n).at[..., 2].set(-1.0)
    return jnp.where(ok, n / jnp.sqrt(jnp.where(ok, sq, 1.0)), facing)


# ------------------------------------------------------------------------------------------------------------------
# The built-in demo scene
# ------------------------------------------------------------------------------------------------------------------


class DemoScene(eqx.Module):
    buffers: Buffers
    camera: Camera
    light: DirectionalLight
    back_light: DirectionalLight
    material_names: tuple[str, ...] = eqx.field(static=True)


def _ray_sphere(dirs: np.ndarray, origin: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    oc = origin - centre
    b = dirs @ oc
    c = oc @ oc - radius * radius
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def demo_scene(height: int = 192, width: int = 256, *, dtype=np.float32) -> DemoScene:
    """A procedural test scene in centimetres (``mm_per_unit = 10``), analytically ray cast on the host:

    a ground plane (id 0, no SSS), a large sphere (id 1, skin-like), a smaller sphere (id 2, marble-like), and a
    thin ear-like slab (id 3, 3 mm thick, wax-like) standing upright; a directional key light from the upper left
    casts a hard shadow edge across the large sphere and the ground; a second directional light behind the
    objects (``back_light``) lights them only through their thickness (the translucency pass uses it). Irradiance is ``max(0, N.L) * visibility * light + ambient``.
    """
    if height < 1 or width < 1:
        raise ValueError(f"demo scene size must be positive, got {height}x{width}")
    focal = 1.1 * width
    cam = np.zeros(3)
    ys, xs = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    dirs = np.stack([(xs - width / 2) / focal, (ys - height / 2) / focal, np.ones_like(xs)], -1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    d = dirs.reshape(-1, 3)

    spheres = [  # centre (cm), radius (cm), id
        (np.array([-4.0, 1.0, 40.0]), 6.0, 1),
        (np.array([6.5, 3.5, 44.0]), 3.5, 2),
    ]
    ground_y = 7.0  # plane y = 7 (y down), normal (0, -1, 0)
    t_ground = np.where(d[:, 1] > 1e-6, (ground_y - cam[1]) / np.where(d[:, 1] > 1e-6, d[:, 1], 1), np.inf)
    t_ground = np.where(cam[2] + t_ground * d[:, 2] < 80.0, t_ground, np.inf)  # the plane ends 80 cm away

    # ear-like slab: an upright thin elliptical disc at z = 34 cm facing the camera, 0.3 cm thick
    slab_c, slab_axes, slab_thick = np.array([4.0, -3.0, 34.0]), (2.2, 3.2), 0.3
    t_slab = (slab_c[2] - slab_thick / 2) / d[:, 2]
    hit = cam + t_slab[:, None] * d
    inside = ((hit[:, 0] - slab_c[0]) / slab_axes[0]) ** 2 + ((hit[:, 1] - slab_c[1]) / slab_axes[1]) ** 2 <= 1
    t_slab = np.where(inside, t_slab, np.inf)

    ts = [t_ground, t_slab] + [_ray_sphere(d, cam, c, r) for c, r, _ in spheres]
    ids = [0, 3] + [i for _, _, i in spheres]
    t_all = np.stack(ts, -1)
    k = np.argmin(t_all, -1)
    t = t_all[np.arange(len(k)), k]
    hit_any = np.isfinite(t)
    pos = cam + np.where(hit_any, t, 0)[:, None] * d
    normal = np.zeros_like(pos)
    normal[:] = (0, 0, -1)
    normal[k == 0] = (0, -1, 0)
    normal[k == 1] = (0, 0, -1)
    for j, (c, r, _) in enumerate(spheres):
        sel = k == 2 + j
        normal[sel] = (pos[sel] - c) / r
    material = np.where(hit_any, np.asarray(ids)[k], 0)

    light_dir = np.array([-0.55, -0.75, -0.35])
    light_dir /= np.linalg.norm(light_dir)
    # shadow rays towards the light (hard edge: a point light at infinity)
    origin = pos + 1e-3 * normal
    shadow = np.zeros(len(pos), bool)
    for c, r, _ in spheres:
        oc = origin - c
        b = oc @ light_dir
        cc = np.sum(oc * oc, -1) - r * r
        disc = b * b - cc
        tt = -b - np.sqrt(np.maximum(disc, 0))
        shadow |= (disc > 0) & (tt > 1e-4)
    ndotl = np.clip(normal @ light_dir, 0, None)
    light_rgb = np.array([3.0, 2.9, 2.7])
    ambient = np.array([0.08, 0.09, 0.11])
    irr = ndotl[:, None] * (~shadow)[:, None] * light_rgb + ambient
    irr[~hit_any] = 0

    # a back light behind the objects (upper right) for the translucency pass: it lights no visible surface
    # directly, only through the objects' thickness
    back_dir = np.array([0.35, -0.45, 0.82])
    back_dir /= np.linalg.norm(back_dir)
    back_rgb = np.array([1.6, 1.45, 1.3])

    # thickness along the back light, through each object (scene units)
    thickness = np.full(len(pos), np.inf)
    thickness[k == 1] = slab_thick / abs(back_dir[2])
    for j, (c, r, _) in enumerate(spheres):
        sel = k == 2 + j
        # chord through the sphere along the back light's direction from the hit point
        oc = pos[sel] - c
        b = oc @ back_dir
        thickness[sel] = np.maximum(2 * np.sqrt(np.maximum(b * b - (np.sum(oc * oc, -1) - r * r), 0)), 1e-3)
    albedo = np.full((len(pos), 3), 0.5)
    albedo[k == 0] = (0.45, 0.45, 0.42)
    # a checker texture on the ground so screen-space blur of the wrong pixels would show
    gx, gz = np.floor(pos[:, 0] / 2.0), np.floor(pos[:, 2] / 2.0)
    albedo[(k == 0) & ((gx + gz) % 2 == 0)] = (0.25, 0.25, 0.23)
    albedo[k == 2] = (0.80, 0.55, 0.45)  # skin-like
    albedo[k == 3] = (0.83, 0.79, 0.75)  # marble-like
    albedo[k == 1] = (0.85, 0.70, 0.45)  # wax-like slab

    depth = np.where(hit_any, pos[:, 2], np.inf)
    normal[~hit_any] = (0, 0, -1)
    shape = (height, width)
    buffers = Buffers(
        irradiance=jnp.asarray(irr.reshape(shape + (3,)), dtype=dtype),
        depth=jnp.asarray(depth.reshape(shape), dtype=dtype),
        albedo=jnp.asarray(albedo.reshape(shape + (3,)), dtype=dtype),
        normal=jnp.asarray(normal.reshape(shape + (3,)), dtype=dtype),
        thickness=jnp.asarray(thickness.reshape(shape), dtype=dtype),
        material_id=jnp.asarray(material.reshape(shape), dtype=jnp.int32),
    )
    return DemoScene(
        buffers=buffers,
        camera=Camera(focal, mm_per_unit=10.0),
        light=DirectionalLight(jnp.asarray(light_dir, dtype=dtype), jnp.asarray(light_rgb, dtype=dtype)),
        back_light=DirectionalLight(jnp.asarray(back_dir, dtype=dtype), jnp.asarray(back_rgb, dtype=dtype)),
        material_names=("demo_skin", "demo_marble", "demo_wax"),
    )
