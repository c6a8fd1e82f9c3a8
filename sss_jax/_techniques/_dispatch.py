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
"""

from __future__ import annotations

import jax

FORMULATIONS = {"burley": ("compacted", "gather", "pallas"), "separable": ("banded", "gather", "pallas")}
ALIASES = {"xla-cpu": {"burley": "compacted", "separable": "banded"},
           "xla-gpu": {"burley": "gather", "separable": "gather"}}
IMPLS = ("auto", "compacted", "banded", "gather", "pallas", *ALIASES)

# options a formulation does not implement, by technique and formulation: none today (every layout runs the spec);
# a future one that lacks an option lists it here and cannot be chosen for it
UNSUPPORTED: dict[tuple[str, str], dict[str, tuple]] = {}


def resolve_impl(impl: str, technique: str = "burley", options: dict | None = None) -> str:
    """``impl`` checked against ``technique``'s formulations (and the old names); ``"auto"`` becomes the CPU
    formulation on a CPU backend, else ``"gather"``. ``options``: the call's option values, checked against what the
    chosen formulation implements (``UNSUPPORTED``); ``"auto"`` skips a formulation that lacks one."""
    names = FORMULATIONS[technique]
    valid = ("auto", *names, *ALIASES)
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
