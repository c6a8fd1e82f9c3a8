"""What the engines' own passes (``_hdrp``, ``_eevee_next``, ``_jimenez``) share: a buffer's place in the whole frame
(tiles), the frame's pixel coordinates, and the checks of their options.

A tile passes its top-left pixel in the frame (``origin``) and the frame's ``(H, W)`` (``frame_shape``): the
per-pixel hashes, the texel coordinates an engine's noise reads and the field of view follow the frame. Samples
that land outside the buffer are treated as off-frame; a tile's halo (``reach_px``) keeps them from the pixels it
keeps. A pass that gathers per pixel (``hdrp``, ``eevee-next``) takes ``keep=(row0, col0, rows, cols)`` too, the
pixels the caller keeps (``_dispatch.kept_window``): it computes only those, fetching from the whole buffer, and
returns the others as their local shading.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array

from .._scene import Buffers, Camera
from ._common import _check_albedo_mode, check_one_image
from ._dispatch import check_tile


def frame_geometry(buffers: Buffers, camera: Camera, origin, frame_shape):
    """``(rows, cols, frame_h, frame_w, cx, cy)``: the frame row and column (int32, (H, W)) of every pixel of the
    buffer, the frame's size and its principal point (frame pixels, the image centre unless the camera states one).
    ``origin``, ``frame_shape``: as ``placement`` gives them (None, None for the whole frame)."""
    h, w = buffers.depth.shape
    fh, fw = (h, w) if frame_shape is None else frame_shape
    oy, ox = (0, 0) if origin is None else (origin[0], origin[1])
    rows = jnp.broadcast_to(jnp.arange(h, dtype=jnp.int32)[:, None] + oy, (h, w))
    cols = jnp.broadcast_to(jnp.arange(w, dtype=jnp.int32)[None, :] + ox, (h, w))
    cx, cy = camera.principal_point if camera.principal_point is not None else (fw / 2, fh / 2)
    return rows, cols, fh, fw, float(cx), float(cy)


def nearest_fetch(flat: Array, height: int, width: int, row: Array, col: Array):
    """Point fetch of ``flat (H*W, K)`` at integer pixel ``(row, col)``; ``inside`` is False off the buffer (the
    fetched row is then the clamped one and must be masked)."""
    inside = (row >= 0) & (row < height) & (col >= 0) & (col < width)
    idx = jnp.clip(row, 0, height - 1) * width + jnp.clip(col, 0, width - 1)
    return jnp.take(flat, idx, axis=0), inside


def placement(buffer_shape: tuple[int, int], origin, frame_shape) -> tuple[Array | None, tuple[int, int] | None]:
    """A buffer's place in the frame (checked: ``check_tile``) as an engine's jitted pass takes it: ``(None, None)``
    for the whole frame (its program as before), else the origin as an int32 array (traced: the tiles of one shape
    share one program, as ``reference``'s do) and the frame's ``(H, W)`` (static)."""
    origin, frame_shape = check_tile(tuple(buffer_shape), origin, frame_shape)
    if origin == (0, 0) and frame_shape == tuple(int(s) for s in buffer_shape):
        return None, None
    return jnp.asarray(origin, jnp.int32), frame_shape


def pass_arguments(name: str, albedo_mode: str, buffers: Buffers, origin, frame_shape,
                   materials: int | None = None) -> tuple[Array | None, tuple[int, int] | None]:
    """What an engine pass checks before tracing (the albedo mode, one image, not a batch, its values:
    ``check_one_image``) and its tile arguments (``placement``)."""
    _check_albedo_mode(albedo_mode)
    check_one_image(name, buffers, materials)
    return placement(buffers.depth.shape, origin, frame_shape)
