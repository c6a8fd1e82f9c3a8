"""Which formulation of a pass runs (``impl=``): formulations are layouts of one spec, named by algorithm.

Every formulation implements every option of its technique (pattern, frames, seed, border, interpolation, the tile's
origin and frame shape) through the technique's one spec (``_burley_spec``, ``_separable_spec``); they differ in
layout only:

- ``burley``: ``"compacted"`` (the active pixels counted and compacted on the host, truncation and shared channels
  decided there: fastest on a CPU), ``"gather"`` (every pixel of the frame, masked, decided on the device: no host
  round trip), ``"pallas"`` (the gather as a Pallas kernel, blocks without an active pixel skipping the loop).
- ``separable``: ``"banded"`` (constant shifts over blocks of rows and columns at ``scale_levels`` quantised reach
  levels per material, each block computing only the (material, level) pairs its pixels use: fastest on a CPU), ``"gather"`` (a gather per tap at each pixel's own
  offset, Jimenez's shader: no levels), ``"pallas"`` (the gather as a Pallas kernel per pass).

``"auto"`` picks the fastest formulation on the backend: the CPU ones on a CPU, ``"gather"`` elsewhere (the Pallas
kernels are not measured faster yet: no GPU figures). The old names stay accepted: ``"xla-cpu"`` (the CPU
formulation) and ``"xla-gpu"`` (``"gather"``). Pallas runs in interpret mode off a GPU (slow: tests only); its
gradient is the gather's (a custom VJP).

A tile's place is checked here for every technique: ``check_tile`` (``origin``, ``frame_shape``) and ``check_keep``
(``keep``, the pixels a caller keeps); ``kept_window``, ``crop`` and ``uncrop`` are how a per-pixel pass computes
only those.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

FORMULATIONS = {"burley": ("compacted", "gather", "pallas"), "separable": ("banded", "gather", "pallas")}
ALIASES = {"xla-cpu": {"burley": "compacted", "separable": "banded"},
           "xla-gpu": {"burley": "gather", "separable": "gather"}}
IMPLS = ("auto", "compacted", "banded", "gather", "pallas", *ALIASES)


def impl_choices(technique: str) -> tuple[str, ...]:
    """The ``impl`` values ``technique`` takes (``resolve_impl``'s): its technique object refuses any other when made,
    not at its first call (a batch failed every frame of ``--impl banded`` for burley)."""
    return ("auto", *FORMULATIONS[technique], *ALIASES)


# options a formulation does not implement, by technique and formulation: none today (every layout runs the spec);
# a future one that lacks an option lists it here and cannot be chosen for it
UNSUPPORTED: dict[tuple[str, str], dict[str, tuple]] = {}


def resolve_impl(impl: str, technique: str = "burley", options: dict | None = None) -> str:
    """``impl`` checked against ``technique``'s formulations (and the old names); ``"auto"`` becomes the CPU
    formulation on a CPU backend, else ``"gather"``. ``options``: the call's option values, checked against what the
    chosen formulation implements (``UNSUPPORTED``); ``"auto"`` skips a formulation that lacks one."""
    names, valid = FORMULATIONS[technique], impl_choices(technique)
    if impl not in valid:
        raise ValueError(f"impl={impl!r} is not one of {valid}")
    options = options or {}

    def lacks(name):
        return [k for k, bad in UNSUPPORTED.get((technique, name), {}).items() if options.get(k) in bad]

    if impl == "auto":
        order = names if jax.default_backend() == "cpu" else ("gather", *names)
        return next(name for name in order if not lacks(name))
    name = ALIASES[impl][technique] if impl in ALIASES else impl
    missing = lacks(name)
    if missing:
        raise ValueError(f"impl={impl!r} does not implement {', '.join(f'{k}={options[k]!r}' for k in missing)}: "
                         f"pass impl='auto'")
    return name


def check_tile(buffer_shape: tuple[int, int], origin, frame_shape) -> tuple[tuple[int, int], tuple[int, int]]:
    """``origin`` (the buffer's top-left pixel in the whole frame, ``(row0, col0)``) and ``frame_shape`` (the whole
    frame's ``(H, W)``; ``None``: the buffer's own) checked: integers, the buffer inside the frame."""
    def pair(value, name):
        try:
            a, b = (int(v) for v in value)
            ok = all(float(v) == int(v) for v in value)
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"{name} must be a pair of integers, got {value!r}")
        return a, b

    h, w = (int(s) for s in buffer_shape)
    origin = pair(origin, "origin")
    frame_shape = (h, w) if frame_shape is None else pair(frame_shape, "frame_shape")
    if min(origin) < 0 or origin[0] + h > frame_shape[0] or origin[1] + w > frame_shape[1]:
        raise ValueError(f"a buffer of {h}x{w} px at origin={origin} does not lie inside frame_shape={frame_shape}")
    return origin, frame_shape


def check_keep(name: str, keep, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """A pass's ``keep`` (the pixels of the buffer a caller keeps, a tile's without its halo: only they are computed):
    None, or four integers ``(row0, col0, rows, cols)`` of a non-empty window inside the ``shape`` buffer."""
    if keep is None:
        return None
    try:
        values = tuple(int(v) for v in keep)
        ok = len(values) == 4 and not any(isinstance(v, (bool, np.bool_)) for v in keep) and all(
            float(v) == int(v) for v in keep)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name}: keep must be four integers (row0, col0, rows, cols), got {keep!r}")
    r0, c0, rows, cols = values
    if r0 < 0 or c0 < 0 or rows < 1 or cols < 1 or r0 + rows > shape[0] or c0 + cols > shape[1]:
        raise ValueError(f"{name}: keep={values} is not a non-empty window inside the {shape[0]}x{shape[1]} buffer")
    return values


def kept_window(name: str, keep, buffer_shape: tuple[int, int]) -> tuple[Array | None, tuple[int, int] | None]:
    """``keep`` (checked: ``check_keep``) as a pass takes it: ``(None, None)`` where the caller keeps the whole
    buffer (the program as before), else the window's top-left pixel as an int32 array (traced: every tile of a frame
    shares one program) and its ``(rows, cols)`` (static: the computed arrays' shape)."""
    keep = check_keep(name, keep, tuple(buffer_shape))
    if keep is None or keep == (0, 0, *(int(s) for s in buffer_shape)):
        return None, None
    return jnp.asarray(keep[:2], jnp.int32), keep[2:]


def crop(a: Array, start: Array | None, size: tuple[int, int] | None) -> Array:
    """The kept window of an ``(H, W, ...)`` array (``kept_window``'s ``start``, ``size``; the array where None)."""
    if start is None:
        return a
    zero = jnp.zeros((), start.dtype)
    return jax.lax.dynamic_slice(a, (start[0], start[1]) + (zero,) * (a.ndim - 2), tuple(size) + a.shape[2:])


def uncrop(whole: Array, part: Array, start: Array | None) -> Array:
    """``whole`` with the kept window replaced by ``part`` (``part`` itself where ``start`` is None)."""
    if start is None:
        return part
    zero = jnp.zeros((), start.dtype)
    return jax.lax.dynamic_update_slice(whole, part.astype(whole.dtype),
                                        (start[0], start[1]) + (zero,) * (whole.ndim - 2))
