"""What the engines' own passes (``_hdrp``, ``_eevee_next``, ``_jimenez``) share: a buffer's place in the whole frame
(tiles), the frame's pixel coordinates, and the checks of their options.

A tile passes its top-left pixel in the frame (``origin``) and the frame's ``(H, W)`` (``frame_shape``): the
per-pixel hashes, the texel coordinates an engine's noise reads and the field of view follow the frame. Samples
that land outside the buffer are treated as off-frame; a tile's halo (``reach_px``) keeps them from the pixels it
keeps. A pass that gathers per pixel (``hdrp``, ``eevee-next``) takes ``keep=(row0, col0, rows, cols)`` too, the
pixels the caller keeps (``_dispatch.kept_window``): it computes only those, fetching from the whole buffer, and
returns the others as their local shading.

Which pixels a pass computes (``computed_pixels``): every pixel of the buffer (under ``jit``, where nothing can be
counted), the kept window, or, where a call's buffers are concrete and SSS pixels are under half of those
(``compacted_pixels``), only the SSS pixels, compacted on the host into a list of the next quarter-octave size (as
``burley``'s compacted formulation: one compilation per size bucket) and scattered back. The arithmetic per pixel is
the same in every layout.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._scene import Buffers, Camera
from ._common import (
    _check_albedo_mode,
    _is_concrete,
    _sss_mask,
    check_one_image,
    padded_indices,
)
from ._dispatch import check_keep, check_tile, crop, kept_window, uncrop


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


@jax.jit
def _sss_pixels(buffers: Buffers) -> Array:
    return _sss_mask(buffers)


def compacted_pixels(buffers: Buffers, keep) -> np.ndarray | None:
    """Host side: the flat indices (int32, row-major) of the buffer's SSS pixels, within ``keep``'s window where
    given, padded with ``H * W``: for the whole buffer to the next quarter-octave size (``_burley.
    compaction_capacity``), for a kept window to an eighth, a quarter or half of the window (``_burley.
    kept_capacity``). None where they would fill half the buffer or the window or more (every pixel computed, or the
    window's, costs less than the compaction). Reads the SSS mask to the host: concrete buffers only."""
    from ._burley import compaction_capacity, kept_capacity

    h, w = buffers.depth.shape
    mask = np.asarray(jax.device_get(_sss_pixels(buffers)))
    keep = check_keep("keep", keep, (h, w))
    if keep is not None:
        r0, c0, kh, kw = keep
        inside = np.zeros_like(mask)
        inside[r0:r0 + kh, c0:c0 + kw] = True
        mask = mask & inside
    count = int(np.count_nonzero(mask))
    if keep is None:
        capacity = compaction_capacity(count, h * w)
    else:  # a tile's: an eighth, a quarter or half of its window, else the window computed whole (one program)
        capacity = kept_capacity(count, keep[2] * keep[3], h * w, fractions=(8, 4, 2))
    return None if capacity is None else padded_indices(mask, capacity)


def pixels_to_compute(name: str, buffers: Buffers, material, camera, keep
                      ) -> tuple[Array | None, tuple[int, int] | None, np.ndarray | None]:
    """What a pass's call computes, as ``(start, size, idx)``: the compacted SSS pixels (``compacted_pixels``, a host
    array; ``start``, ``size`` None) where the call's inputs are concrete and those pixels fill under half the
    buffer, else the kept window (``_dispatch.kept_window``: None, None for the whole buffer) and ``idx`` None."""
    window = kept_window(name, keep, buffers.depth.shape)
    idx = compacted_pixels(buffers, keep) if _is_concrete(buffers, material, camera) else None
    return (None, None, idx) if idx is not None else (*window, None)


def computed_pixels(shape: tuple[int, int], start: Array | None, size: tuple[int, int] | None, idx: Array | None):
    """``(take, put, row, col)`` for the pixels a pass computes: ``take(a)`` the computed pixels' values of an
    ``(H, W, ...)`` array, ``put(whole, part)`` ``whole`` with them replaced by ``part``, and their rows and columns
    in the buffer (int32). The pixels: the compacted list ``idx`` (``compacted_pixels``: padding entries compute the
    last pixel and are dropped), else the kept window (``start``, ``size``: ``_dispatch.kept_window``), else all."""
    h, w = shape
    if idx is not None:
        safe = jnp.minimum(idx, h * w - 1)

        def take(a):
            return a.reshape((h * w,) + a.shape[2:])[safe]

        def put(whole, part):
            flat = whole.reshape((h * w,) + whole.shape[2:])
            return flat.at[idx].set(part.astype(whole.dtype), mode="drop").reshape(whole.shape)

        return take, put, safe // w, safe % w
    r0, c0 = (0, 0) if start is None else (start[0], start[1])
    kh, kw = (h, w) if size is None else size
    return (lambda a: crop(a, start, size), lambda whole, part: uncrop(whole, part, start),
            jnp.arange(kh, dtype=jnp.int32)[:, None] + r0, jnp.arange(kw, dtype=jnp.int32)[None, :] + c0)
