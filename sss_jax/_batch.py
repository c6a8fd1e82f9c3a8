"""Batch processing of frame sequences: streamed, sharded over ``jax.devices()``, resumable, failure tolerant.

Before any frame runs, the whole batch is planned and checked: every output path (``out_dir`` keeps each input's
path relative to the inputs' common folder, so ``shots/a/beauty.exr`` and ``shots/b/beauty.exr`` give two outputs),
no two frames writing one output, no output equal to an input, no existing output made from another input (unless
``overwrite``), every output folder writable, the technique's parameters in range. A batch that fails these checks
raises ``SSSInputError`` naming the inputs and writes nothing.

Frames are then read one at a time and grouped by (shape, buffers present, effective sample/tap count); each full
group of ``len(devices)`` frames is stacked along a leading axis sharded over the devices
(``NamedSharding(Mesh(devices, ("frames",)), P("frames"))``) and processed by one jitted, vmapped call, so every
frame shape compiles once and memory holds at most one group per shape. A frame larger than one tile's budget
(``tile_pixels``) or whose work would keep one call busy for more than about a second is processed alone in tiles
that overlap by the kernel's reach (exactly the untiled result; memory bounded per tile, and Ctrl-C lands between
tiles). Sample and tap counts beyond the footprint's pixel count are clamped with a warning.

Outputs are written atomically with a resume record in the EXR header (input path, size, mtime, the technique and
its parameters, the sss_jax version); ``resume=True`` skips a frame whose output is complete and carries the same
record. ``out_dir/sss_jax_manifest.json`` (one per process across hosts) lists every frame's input, output, status
and seconds, rewritten atomically as each frame finishes; SIGINT and SIGTERM stop the run between frames and leave
it true. A frame that cannot be read or is invalid is reported and skipped.

Across hosts, each process calls ``jax.distributed.initialize()`` first and then processes
``frames_for_process(frames, jax.process_index(), jax.process_count())`` (docs/batch.md shows the launch).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import dataclasses
import functools
import glob
import hashlib
import json
import math
from numbers import Real
import os
import pathlib
import signal
import threading
import time
import warnings
from typing import Any, Callable, Iterable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._io import (Frame, SSSInputError, check_writable, exr_is_complete, read_frame, read_header,
                  write_exr, write_json_atomic, write_png_preview)
from ._kernels import separable_kernel_from_profile, two_gaussian_kernel
from ._materials import BurleyMaterial, DirectionalLight, ProfileMaterial, STAParams, TwoGaussianMaterial
from ._profiles import BurleyProfile, burley_inverse_ccdf
from ._scene import Buffers, Camera, validate_buffers
from ._techniques import TECHNIQUES, burley, reference, separable, translucency

__all__ = ["BatchResult", "FrameResult", "Interrupted", "MANIFEST_NAME", "expand_inputs", "frames_for_process",
           "output_paths", "process_frames"]

MANIFEST_NAME = "sss_jax_manifest.json"

# Memory bound per call: pixels of one (extended) tile. Burley's dense working set is ~300 bytes per pixel (18.9 GB
# at 8000x8000), so a tile of 2^21 pixels holds ~0.6 GB; the frame's own arrays (input buffers 16-40 B/px, output
# 12 B/px) come on top.
TILE_PIXELS = 1 << 21
# Work bound per call (seconds on this project's 2-core CPU, from the README's timings): a KeyboardInterrupt lands
# between calls, so no call should run much longer than this.
CALL_SECONDS = 1.0
# Footprint pixels of the reach of the techniques' own checks (the 99%-energy footprint below which a pixel keeps
# its local shading, MIN_FOOTPRINT_PX in the techniques)
_MIN_FOOTPRINT_PX = 0.5
_BURLEY_R99 = float(np.asarray(burley_inverse_ccdf(np.float64(0.01), np.float64(1.0))))
_BURLEY_R999 = float(np.asarray(burley_inverse_ccdf(np.float64(0.001), np.float64(1.0))))
# radius (units of d) beyond which the profile's energy rounds away in float32: burley samples the whole profile
# (no truncation to the image) when this radius fits inside the frame's diagonal
_BURLEY_UNTRUNCATED = float(np.asarray(burley_inverse_ccdf(np.float64(np.finfo(np.float32).eps / 4), np.float64(1))))


@dataclasses.dataclass
class FrameResult:
    input: str
    output: str
    status: str  # "done", "skipped" (complete output of the same input and parameters there) or "failed"
    message: str = ""
    seconds: float = 0.0


@dataclasses.dataclass
class BatchResult:
    frames: list[FrameResult]
    compilations: int
    manifest: str | None = None

    @property
    def failed(self) -> list[FrameResult]:
        return [f for f in self.frames if f.status == "failed"]

    @property
    def ok(self) -> bool:
        return not self.failed


class Interrupted(KeyboardInterrupt):
    """The batch stopped on SIGINT or SIGTERM (``signum``) between frames; the manifest says what is done."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def expand_inputs(inputs: str | pathlib.Path | Iterable[str | pathlib.Path]) -> list[pathlib.Path]:
    """Paths from a list of paths and/or glob patterns, in order; a pattern matching nothing is an error."""
    if isinstance(inputs, (str, pathlib.Path)):
        inputs = [inputs]
    out: list[pathlib.Path] = []
    for item in inputs:
        s = str(item)
        if any(ch in s for ch in "*?["):
            matches = sorted(glob.glob(s))
            if not matches:
                raise SSSInputError(f"no files match {s!r}")
            out.extend(pathlib.Path(m) for m in matches)
        else:
            out.append(pathlib.Path(s))
    return out


def frames_for_process(frames: Sequence[Any], process_index: int, process_count: int) -> list[Any]:
    """This process's share of the frames: every ``process_count``-th frame starting at ``process_index``
    (disjoint, together complete, deterministic, sizes differing by at most one)."""
    if process_count < 1 or not (0 <= process_index < process_count):
        raise ValueError(f"process_index {process_index} must be in [0, {process_count})")
    return list(frames[process_index::process_count])


def output_paths(inputs: Sequence[str | pathlib.Path], out_dir: str | pathlib.Path) -> list[pathlib.Path]:
    """``out_dir / <input's path relative to the inputs' common folder>.exr``: inputs of one name in different
    folders keep their folders, so they never share an output."""
    absolute = [pathlib.Path(os.path.abspath(p)) for p in inputs]
    if not absolute:
        return []
    common = pathlib.Path(os.path.commonpath([str(p.parent) for p in absolute]))
    return [pathlib.Path(out_dir) / p.relative_to(common).with_suffix(".exr") for p in absolute]


def _identity(path: pathlib.Path) -> str:
    return os.path.normcase(str(path.resolve()))


def _check_plan(jobs: list[tuple[pathlib.Path, pathlib.Path]], png: bool, manifest: pathlib.Path | None) -> None:
    """No two frames write one file, no output is an input: checked over the whole batch (every process of a
    multi-host run plans the same batch), before anything runs."""
    if not jobs:
        return
    inputs: dict[str, list[pathlib.Path]] = {}
    for src, _ in jobs:
        inputs.setdefault(_identity(src), []).append(src)
    writes: dict[str, list[tuple[pathlib.Path, pathlib.Path]]] = {}
    for src, dst in jobs:
        for out in [dst] + ([dst.with_suffix(".png")] if png else []):
            writes.setdefault(_identity(out), []).append((src, out))
    if manifest is not None:
        writes.setdefault(_identity(manifest), []).append((pathlib.Path("(the manifest)"), manifest))
    problems = []
    for key, users in writes.items():
        if len(users) > 1:
            problems.append(f"{users[0][1]} would be written by " + " and ".join(str(s) for s, _ in users))
        if key in inputs:
            src, out = users[0]
            problems.append(f"output {out} is the input {inputs[key][0]}: an input is never overwritten")
    if problems:
        raise SSSInputError("batch refused before any frame ran: " + "; ".join(problems[:10])
                            + (f"; and {len(problems) - 10} more" if len(problems) > 10 else ""))


# What a tile runs with: a tile's edge is not the frame's, and a tile's pixel grid starts at its own corner, so the
# rules that depend on where the frame ends or on the pixel's place in it are the frame-independent ones: Burley's
# fixed spiral, and the kernel renormalised at the edge (the overlap of the kernel's reach makes that exact inside).
TILE_RULES = {"burley": dict(pattern="fixed", border="renormalise"), "separable": dict(border="renormalise"),
              "reference": dict(border="renormalise")}


def _run_technique(technique: str, buffers: Buffers, material, camera: Camera, options: dict, rules=None):
    rules = rules or {}
    if technique == "burley":
        return burley(buffers, material, camera, samples=options["samples"], **rules)
    if technique == "separable":
        return separable(buffers, material, camera, taps=options["taps"], **rules)
    if technique == "reference":
        return reference(buffers, material, camera, radius_px=options["radius_px"], **rules)
    params, light = material
    return translucency(buffers, params, camera, light, albedo=options.get("albedo"),
                        thickness=options.get("thickness"))


def _material_attributes(material) -> dict[str, str]:
    """The material's parameters for the EXR header: ``sss_jax:<field>`` = rows of comma-separated values."""
    parts = material if isinstance(material, tuple) else (material,)
    attrs = {}
    for part in parts:
        for field in dataclasses.fields(part):
            if not isinstance(getattr(part, field.name), (jax.Array, np.ndarray)):
                continue  # a profile object: its arrays are in sss_jax:parameters
            value = np.asarray(getattr(part, field.name))
            rows = value.reshape(-1, value.shape[-1]) if value.ndim else value.reshape(1, 1)
            attrs[f"sss_jax:{field.name}"] = ";".join(",".join(f"{v:.6g}" for v in row) for row in rows)
    return attrs


def _material_record(material) -> dict[str, Any]:
    """Every field of the material at full precision (the resume record compares it)."""
    parts = material if isinstance(material, tuple) else (material,)
    return {f"{type(part).__name__}.{field.name}": [np.asarray(leaf, np.float64).tolist()
                                                     for leaf in jax.tree.leaves(getattr(part, field.name))
                                                     if isinstance(leaf, (jax.Array, np.ndarray))]
            for part in parts for field in dataclasses.fields(part)}


def _file_stamp(path: pathlib.Path) -> dict[str, Any] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return {"path": str(path.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _resume_record(src: pathlib.Path, parameters: dict[str, Any]) -> tuple[dict[str, str], str]:
    """The header attributes that say what an output was made from, and their digest: the input (path, size,
    mtime; its sidecar's too), the technique and every parameter, the sss_jax version."""
    from ._version import __version__

    stamp = _file_stamp(src) or {"path": str(src)}
    record = {"input": stamp, "sidecar": _file_stamp(src.with_suffix(".json")), "parameters": parameters,
              "version": __version__}
    text = json.dumps(record, sort_keys=True)
    digest = hashlib.sha256(text.encode()).hexdigest()
    attrs = {"sss_jax:input": stamp["path"], "sss_jax:input_size": str(stamp.get("size", "")),
             "sss_jax:input_mtime_ns": str(stamp.get("mtime_ns", "")), "sss_jax:version": __version__,
             "sss_jax:parameters": json.dumps(parameters, sort_keys=True), "sss_jax:record": digest}
    return attrs, digest


def _existing_output(dst: pathlib.Path) -> dict[str, Any] | None:
    """The header of an existing output, ``{}`` for an existing file that cannot be read, ``None`` if none."""
    if not dst.exists():
        return None
    try:
        return read_header(dst)[0]
    except (OSError, ValueError):
        return {}


class _Signals:
    """SIGINT and SIGTERM raise ``Interrupted`` in the main thread, except inside ``critical()`` (writing a frame's
    files and recording them in the manifest), where they wait for its end: the manifest never lags the disk."""

    def __init__(self):
        self.depth = 0
        self.pending: int | None = None
        self.previous: dict[int, Any] = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig, default in ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL)):
                if signal.getsignal(sig) is default:  # a handler the caller installed is left alone
                    self.previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        return False

    def _handler(self, signum, frame):
        if self.depth:
            self.pending = signum
            return
        raise Interrupted(signum)

    @contextlib.contextmanager
    def critical(self):
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1
            if not self.depth and self.pending is not None:
                signum, self.pending = self.pending, None
                raise Interrupted(signum)


class _Manifest:
    """``sss_jax_manifest.json``: the run's settings and one entry per frame of this process's share (pending,
    done, failed with the message, skipped), rewritten atomically whenever a frame finishes."""

    def __init__(self, path: pathlib.Path | None, header: dict[str, Any], jobs):
        self.path = path
        self.data = dict(header, state="running", frames=[
            {"input": str(src), "output": str(dst), "status": "pending", "message": "", "seconds": 0.0}
            for src, dst in jobs])
        self.index = {str(dst): i for i, (_, dst) in enumerate(jobs)}
        self.write()

    def record(self, r: FrameResult) -> None:
        self.data["frames"][self.index[r.output]] = {"input": r.input, "output": r.output, "status": r.status,
                                                     "message": r.message, "seconds": round(r.seconds, 4)}
        self.write()

    def close(self, state: str) -> None:
        self.data["state"] = state
        self.write()

    def write(self) -> None:
        if self.path is not None:
            write_json_atomic(self.path, self.data)


# ------------------------------------------------------------------------------------------------------------------
# reach, bounds and tiles (host side, NumPy)
# ------------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Reach:
    """Host-side facts about one frame: per-pixel px per mm and material row of its SSS pixels."""

    ppm: np.ndarray  # (H, W) px per mm, 0 where no SSS
    rows: np.ndarray  # (H, W) material row
    valid: np.ndarray  # (H, W) SSS pixels

    @classmethod
    def of(cls, frame: Frame, camera: Camera, count: int) -> "_Reach":
        # float32 like the techniques (and half the memory of float64 on an 8000x8000 frame)
        depth = np.asarray(frame.depth, np.float32)
        valid = np.isfinite(depth) & (depth > 0)
        ids = frame.material_id
        if ids is not None:
            valid &= ids > 0
        rows = (np.zeros(depth.shape, np.int32) if ids is None or count == 1
                else np.clip(ids - 1, 0, count - 1).astype(np.int32))
        scale = np.float32(float(camera.focal_px) / float(camera.mm_per_unit))
        ppm = np.divide(scale, depth, out=np.zeros_like(depth), where=valid)
        return cls(ppm, rows, valid)

    def largest(self, per_row_mm: np.ndarray, *, active_r99: float | None = None) -> tuple[float, np.ndarray]:
        """Largest ``per_row_mm[row] * ppm`` over the pixels a technique computes, and that plane (px)."""
        px = per_row_mm.astype(np.float32)[self.rows] * self.ppm
        active = self.valid & (px * (active_r99 or 1.0) >= _MIN_FOOTPRINT_PX) & (px > 0)
        return float(np.max(px, where=active, initial=0.0)), np.where(active, px, np.nan)


def _separable_reach_mm(material, taps: int) -> np.ndarray:
    """Each material's kernel reach in mm: the largest tap offset, as ``separable`` builds its kernels."""
    if isinstance(material, TwoGaussianMaterial):
        rows = [two_gaussian_kernel(w, a, b, taps=taps) for w, a, b in
                zip(material.w, material.sigma_near_mm, material.sigma_far_mm)]
    elif isinstance(material, BurleyMaterial):
        rows = [separable_kernel_from_profile(BurleyProfile(d), taps=taps) for d in material.d_mm]
    else:
        rows = [separable_kernel_from_profile(material.profile, taps=taps)]
    return np.asarray([float(np.max(np.abs(np.asarray(k.offsets_mm, np.float64)))) for k in rows])


def _next_pow2(n: Real) -> int:
    return 1 << max(0, math.ceil(n) - 1).bit_length()


@dataclasses.dataclass
class _Plan:
    """How one frame runs: its effective options, the tile overlap (px) and the pixels copied into a tile's extra
    row so its separable levels span the whole frame's reach."""

    options: dict[str, Any]
    warning: str = ""
    overlap: int = 0
    min_side: int = 1
    sentinels: tuple[tuple[int, int], ...] = ()
    exact_tiles: bool = True
    seconds_per_px: float = 0.0


def _frame_plan(technique: str, frame: Frame, material, camera: Camera, options: dict) -> _Plan:
    h, w = frame.shape
    opts = dict(options)
    if technique == "sta":
        return _Plan(opts, overlap=2, min_side=8, seconds_per_px=4e-8)
    if technique == "reference":
        radius = int(opts["radius_px"])
        cap = max(1, max(h, w) - 1)  # a window past the frame reaches no further pixel
        warning = ""
        if radius > cap:
            warning = f"radius_px {radius} clamped to {cap}: the frame is {w}x{h} pixels"
            opts["radius_px"] = radius = cap
        return _Plan(opts, warning, overlap=radius + 1, min_side=2 * radius + 3,
                     seconds_per_px=3e-8 * (2 * radius + 1) ** 2)
    reach = _Reach.of(frame, camera, material.count)
    if technique == "burley":
        d_max = np.asarray(material.d_mm, np.float64).reshape(-1, 3).max(axis=-1)
        d_px, _ = reach.largest(d_max, active_r99=_BURLEY_R99)
        samples, warning = int(opts["samples"]), ""
        # a footprint (99.9% of the energy at the nearest SSS pixel) of n pixels: more than the next power of two
        # above n samples cannot help (the power of two keeps the sequence's distinct counts, and compilations, few)
        footprint = min(math.pi * (_BURLEY_R999 * d_px) ** 2, h * w)
        bound = _next_pow2(max(footprint, 1.0))
        if samples > bound:
            warning = (f"samples {samples} clamped to {bound}: the footprint has {math.ceil(footprint)} pixels, "
                       "more samples cannot help")
            opts["samples"] = samples = bound
        rho_max = float(np.asarray(burley_inverse_ccdf(np.float64(0.5 / samples), np.float64(1.0))))
        exact = d_px * _BURLEY_UNTRUNCATED <= math.hypot(h, w)  # else sampling depends on the frame's size
        return _Plan(opts, warning, overlap=math.ceil(rho_max * d_px) + 2,
                     min_side=math.ceil(_BURLEY_UNTRUNCATED * d_px / math.sqrt(2)) + 2, exact_tiles=exact,
                     seconds_per_px=1.4e-8 * samples)
    # separable
    taps, warning = int(opts["taps"]), ""
    reach_mm = _separable_reach_mm(material, taps)
    reach_px, plane = reach.largest(reach_mm)
    # a pass reads 2 reach + 1 pixels of a row: more taps than the next 2^k + 1 above that cannot help
    footprint = 2 * math.ceil(reach_px) + 1
    bound = _next_pow2(max(footprint - 1, 1)) + 1
    if taps > bound:
        warning = f"taps {taps} clamped to {bound}: a pass reaches {footprint} pixels, more taps cannot help"
        opts["taps"] = taps = bound
        reach_px, plane = reach.largest(_separable_reach_mm(material, taps))
    sentinels = ()
    if np.any(np.isfinite(plane)):
        lo = np.unravel_index(np.nanargmin(plane), plane.shape)
        hi = np.unravel_index(np.nanargmax(plane), plane.shape)
        sentinels = (tuple(int(i) for i in lo), tuple(int(i) for i in hi))
    return _Plan(opts, warning, overlap=math.ceil(reach_px) + 2, min_side=8, sentinels=sentinels,
                 seconds_per_px=9e-9 * taps)


def _tile_layout(h: int, w: int, plan: _Plan, tile_pixels: int) -> tuple[int, int] | None:
    """Inner tile size (rows, cols), or None where the frame runs whole (it fits the memory and work bounds, or
    tiles could not reproduce it exactly)."""
    budget = min(tile_pixels, int(CALL_SECONDS / plan.seconds_per_px) if plan.seconds_per_px else tile_pixels)
    if h * w <= budget or not plan.exact_tiles:
        return None
    # the inner part at least as wide as the overlap: a tile never computes more than ~9x its own pixels (a wide
    # window on a small frame then runs whole, past the work bound, rather than in tiles made of overlap)
    side = max(math.isqrt(max(budget, 1)), 3 * plan.overlap + 8, plan.min_side)
    inner = side - 2 * plan.overlap
    # as few tiles as fit, of equal size (1600 px in tiles of at most 1352: two of 800, not 1352 and a shifted 1352)
    ty, tx = -(-h // -(-h // inner)), -(-w // -(-w // inner))
    if (ty, tx) == (h, w):
        return None
    return ty, tx


def _starts(n: int, t: int) -> list[int]:
    """Tile starts along an axis: every t pixels, the last tile ending at the last pixel (overlapping the one before
    where n is no multiple of t: all tiles have one shape, one compilation)."""
    return sorted({min(s, n - t) for s in range(0, n, t)})


def _tile(frame: Frame, y0: int, x0: int, ty: int, tx: int, r: int, sentinels, use_albedo: bool):
    """The tile's buffers: rows y0-r..y0+ty+r, columns x0-r..x0+tx+r of the frame, outside it no surface (as the
    techniques treat pixels outside the image), plus one row of sentinel pixels when given (separated from every
    inner pixel by more than the reach)."""
    h, w = frame.shape
    ye0, ye1, xe0, xe1 = y0 - r, y0 + ty + r, x0 - r, x0 + tx + r
    sy0, sy1, sx0, sx1 = max(ye0, 0), min(ye1, h), max(xe0, 0), min(xe1, w)
    extra = 1 if sentinels else 0
    pads = ((sy0 - ye0, ye1 - sy1 + extra), (sx0 - xe0, xe1 - sx1))

    def cut(a, fill):
        if a is None:
            return None
        part = a[sy0:sy1, sx0:sx1]
        out = np.pad(part, pads + ((0, 0),) * (a.ndim - 2), constant_values=fill)
        for k, (sy, sx) in enumerate(sentinels):
            out[-1, k] = a[sy, sx]
        return out

    depth = cut(frame.depth, np.inf)
    if sentinels:  # only the sentinels have a surface in the extra row
        depth[-1, len(sentinels):] = np.inf
    ids = cut(frame.material_id, 0)
    opt = lambda a: None if a is None else jnp.asarray(a)
    return Buffers(irradiance=jnp.asarray(cut(frame.irradiance, 0.0)), depth=jnp.asarray(depth),
                   albedo=opt(cut(frame.albedo, 0.0)) if use_albedo else None, normal=opt(cut(frame.normal, 0.0)),
                   thickness=opt(cut(frame.thickness, 0.0)),
                   material_id=None if ids is None else jnp.asarray(ids, jnp.int32)), (ye0, xe0)


def _check_options(technique: str, options: dict) -> None:
    """Ranges of the batch-level parameters (the materials check their own), before any frame runs."""
    for name in ("samples", "taps"):
        v = options.get(name)
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    if options["taps"] % 2 == 0:
        raise ValueError(f"taps must be odd, got {options['taps']}")
    r = options.get("radius_px")
    if technique == "reference" and (not isinstance(r, (int, np.integer)) or r < 0):
        raise ValueError(f"radius_px must be a non-negative integer, got {r!r}")
    albedo = options.get("albedo")
    if albedo is not None:
        a = np.asarray(albedo, np.float64)
        if a.shape not in ((3,), (1, 3)) or not np.all((a >= 0) & (a <= 1)):  # NaN fails both
            raise ValueError(f"STA albedo must be 3 values in [0, 1], got {a.tolist()}")
    t = options.get("thickness")
    if t is not None and not (float(t) >= 0):
        raise ValueError(f"STA thickness must be >= 0 scene units (inf: infinitely thick), got {t}")


# ------------------------------------------------------------------------------------------------------------------
# the batch
# ------------------------------------------------------------------------------------------------------------------


class _Group(eqx.Module):
    buffers: Buffers
    camera: Camera


def _camera(frame: Frame) -> Camera:
    return Camera(frame.focal_px, frame.mm_per_unit if frame.mm_per_unit is not None else 1.0)


def process_frames(
    inputs: str | pathlib.Path | Iterable[str | pathlib.Path],
    technique: str,
    material,
    *,
    out_dir: str | pathlib.Path | None = None,
    outputs: Sequence[str | pathlib.Path] | None = None,
    png: bool = False,
    focal_px: float | None = None,
    mm_per_unit: float | None = None,
    channel_map=None,
    depth_kind: str = "planar",
    use_albedo_pass: bool = True,
    sta_albedo=None,
    sta_thickness: float | None = None,
    samples: int = 32,
    taps: int = 25,
    radius_px: int | None = None,
    half: bool = False,
    resume: bool = True,
    overwrite: bool = False,
    manifest: str | pathlib.Path | None | bool = True,
    tile_pixels: int = TILE_PIXELS,
    progress: bool = True,
    devices: Sequence[jax.Device] | None = None,
    process_index: int | None = None,
    process_count: int | None = None,
    on_frame_done: Callable[[FrameResult], None] | None = None,
) -> BatchResult:
    """Apply ``technique`` to every frame and write ``out_dir/<input path relative to the inputs' common folder>``
    with the ``.exr`` extension (or the given ``outputs``, one per input, each ending in ``.exr``), with an sRGB PNG
    preview beside each when ``png``.

    ``material``: a preset name or file (see ``_presets``), a ``BurleyMaterial`` / ``TwoGaussianMaterial`` (rows
    per material id), or ``(STAParams, DirectionalLight)`` for ``"sta"`` (with ``sta_albedo (3,)`` in [0, 1] where
    frames carry no albedo and ``sta_thickness`` >= 0 in scene units where they carry no thickness). ``radius_px``
    is required for ``"reference"`` (one window for the sequence).

    - ``resume``: skip a frame whose output is complete and records the same input (path, size, mtime), technique,
      parameters and sss_jax version; every other frame is computed.
    - ``overwrite``: allow replacing an existing output that was not made from the same input (refused otherwise,
      before any frame runs).
    - ``manifest``: ``True`` writes ``out_dir/sss_jax_manifest.json`` (``sss_jax_manifest.<process index>.json``
      when several processes share the batch; none with ``outputs``), a path writes there, ``None``/``False`` none.
    - ``tile_pixels``: the most pixels (overlap included) one call of the technique sees; larger frames run in
      tiles overlapping by the kernel's reach, which reproduce the untiled frame.

    Returns a per-frame status list; raises (``SSSInputError``/``ValueError``/``TypeError``, nothing written) only
    where the whole batch is impossible, and ``Interrupted`` (a ``KeyboardInterrupt``) on SIGINT/SIGTERM after
    recording the finished frames in the manifest.
    """
    if technique not in TECHNIQUES:
        raise ValueError(f"unknown technique {technique!r}; valid techniques: {', '.join(TECHNIQUES)}")
    if isinstance(material, (str, pathlib.Path)):  # a preset name or file
        from ._presets import load_preset, material_for

        material = material_for(technique, load_preset(material))
        if technique == "sta":
            raise TypeError("technique 'sta' needs material=(STAParams, DirectionalLight): a preset gives no light")
    if technique == "sta":
        if not (isinstance(material, tuple) and len(material) == 2 and isinstance(material[0], STAParams)
                and isinstance(material[1], DirectionalLight)):
            raise TypeError("technique 'sta' needs material=(STAParams, DirectionalLight)")
    elif not isinstance(material, (BurleyMaterial, TwoGaussianMaterial, ProfileMaterial)):
        raise TypeError(f"material must be a BurleyMaterial or TwoGaussianMaterial, got {type(material).__name__}")
    if technique == "reference" and radius_px is None:
        raise ValueError("technique 'reference' in a batch needs radius_px (one window for every frame)")
    if not (isinstance(tile_pixels, (int, np.integer)) and tile_pixels >= 1):
        raise ValueError(f"tile_pixels must be a positive integer, got {tile_pixels!r}")
    options = dict(samples=samples, taps=taps, radius_px=radius_px, albedo=sta_albedo, thickness=sta_thickness)
    _check_options(technique, options)

    paths = expand_inputs(inputs)
    if outputs is not None:
        if len(outputs) != len(paths):
            raise ValueError(f"{len(outputs)} outputs for {len(paths)} inputs")
        targets = [pathlib.Path(o) for o in outputs]
    elif out_dir is not None:
        out_dir = pathlib.Path(out_dir)
        targets = output_paths(paths, out_dir)
    else:
        raise ValueError("give out_dir or outputs")
    for t in targets:
        if t.suffix.lower() != ".exr":
            raise SSSInputError(f"{t}: outputs are linear float EXR and need the .exr extension "
                                "(png=True / --png adds an sRGB PNG preview beside each)")
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    if manifest is True:
        manifest = None if out_dir is None else out_dir / (MANIFEST_NAME if pc == 1 else
                                                            MANIFEST_NAME.replace(".json", f".{pi}.json"))
    manifest = pathlib.Path(manifest) if manifest not in (None, False) else None
    all_jobs = list(zip(paths, targets))
    _check_plan(all_jobs, png, manifest)
    jobs = frames_for_process(all_jobs, pi, pc)

    # the existing outputs of this share: made from the same input (resumable or recomputed) or refused
    existing: dict[pathlib.Path, dict] = {}
    foreign = []
    for src, dst in jobs:
        header = _existing_output(dst)
        if header is None:
            continue
        existing[dst] = header
        made_from = header.get("sss_jax:input")
        same_input = made_from is not None and _identity(pathlib.Path(str(made_from))) == _identity(src)
        if header and not same_input and not overwrite:
            foreign.append(f"{dst} exists and was made from {made_from or 'something other than sss_jax'}, "
                           f"not {src}")
    if foreign:
        raise SSSInputError("existing outputs would be overwritten (pass overwrite=True / --overwrite to allow it, "
                            "or choose another output folder): " + "; ".join(foreign[:10])
                            + (f"; and {len(foreign) - 10} more" if len(foreign) > 10 else ""))
    probed = set()
    for path in [dst for _, dst in jobs] + ([manifest] if manifest is not None else []):
        if path.is_dir():
            raise SSSInputError(f"{path}: output path is a directory")
        if path.parent not in probed:  # --out-dir's folders are made; a typo in -o's folder is not
            check_writable(path, create_dirs=out_dir is not None)
            probed.add(path.parent)

    devices = list(jax.devices() if devices is None else devices)
    mesh = jax.sharding.Mesh(np.asarray(devices), ("frames",))
    sharded = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("frames"))
    parameters = {"technique": technique, "material": _material_record(material), "half": bool(half),
                  "focal_px": focal_px, "mm_per_unit": mm_per_unit, "depth_kind": depth_kind,
                  "use_albedo_pass": bool(use_albedo_pass), "png": bool(png), "channel_map": _channel_map_record(
                      channel_map)}
    parameters.update({k: (np.asarray(v, np.float64).tolist() if v is not None and k == "albedo" else v)
                       for k, v in options.items() if _used(technique, k)})
    header = _material_attributes(material)
    traces = {"count": 0}

    @eqx.filter_jit
    def run_group(group: _Group, opts_key: tuple):
        traces["count"] += 1  # runs once per trace: one per (shape, buffers present, options)
        opts = dict(opts_key)
        return jax.vmap(lambda b, c: _run_technique(technique, b, material, c, opts))(group.buffers, group.camera)

    results: list[FrameResult] = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), unit="frame", desc=f"sss-jax {technique}")
    from ._version import __version__

    book = _Manifest(manifest, {"sss_jax_version": __version__, "technique": technique, "parameters": parameters,
                                "process_index": pi, "process_count": pc}, jobs)
    pending: dict[tuple, list] = {}
    signals = _Signals()

    def finish(r: FrameResult):
        with signals.critical():  # a skipped or failed frame's entry too: the manifest never lags the results
            results.append(r)
            book.record(r)
        if len(results) % 64 == 0:
            _release_free_memory()
        if bar is not None:
            bar.update(1)
            if r.status == "failed":
                bar.write(f"FAILED {r.input}: {r.message}")
        if on_frame_done is not None:
            on_frame_done(r)

    def write_frame(src, dst, image, cam, seconds, note):
        attrs = {**header, **_resume_record(src, parameters)[0], "sss_jax:technique": technique,
                 "sss_jax:focal_px": float(cam.focal_px), "sss_jax:mm_per_unit": float(cam.mm_per_unit)}
        for name in ("samples", "taps", "radius_px"):
            if _used(technique, name):
                attrs[f"sss_jax:{name}"] = int(note["options"][name])
        fresh = dst not in existing
        try:
            with signals.critical():  # the files and their manifest entry together, or neither
                write_exr(dst, image, channel_names=["R", "G", "B"], half=half, attributes=attrs, overwrite=not fresh)
                if png:
                    write_png_preview(dst.with_suffix(".png"), image, overwrite=True)
                finish(FrameResult(str(src), str(dst), "done", note["warning"], seconds=seconds))
        except (OSError, ValueError) as exc:
            finish(FrameResult(str(src), str(dst), "failed", str(exc)))

    def flush(key):
        items = pending.pop(key)
        n = len(devices)
        padded = items + [items[-1]] * (n - len(items))  # the last group repeats a frame to fill every device
        stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[_Group(it["buffers"], it["camera"]) for it in padded])
        stacked = jax.device_put(stacked, sharded)
        t0 = time.perf_counter()
        try:
            out = np.asarray(run_group(stacked, key[-1]))
        except Exception as exc:  # noqa: BLE001 - a failed group fails its frames, not the batch
            for it in items:
                finish(FrameResult(str(it["src"]), str(it["dst"]), "failed", f"{type(exc).__name__}: {exc}"))
            return
        dt = (time.perf_counter() - t0) / len(items)
        for k, it in enumerate(items):
            write_frame(it["src"], it["dst"], out[k], it["camera"], dt + it["read_s"], it)

    def run_tiled(src, dst, frame, cam, plan, layout, t0):
        ty, tx = layout
        h, w = frame.shape
        r = plan.overlap
        count = 1 if technique == "sta" else material.count
        out = np.empty((h, w, 3), np.float32)
        tiles = [(y, x) for y in _starts(h, ty) for x in _starts(w, tx)]
        tile_bar = None
        if bar is not None:
            from tqdm.auto import tqdm

            tile_bar = tqdm(total=len(tiles), unit="tile", desc=f"{src.name} ({w}x{h})", leave=False)
        cx, cy = cam.principal_point if cam.principal_point is not None else (w / 2, h / 2)
        try:
            for y, x in tiles:
                b, (ye0, xe0) = _tile(frame, y, x, ty, tx, r, plan.sentinels if technique == "separable" else (),
                                      use_albedo_pass)
                validate_buffers(b, materials=count)
                tile_cam = cam if technique != "sta" else Camera(cam.focal_px, cam.mm_per_unit,
                                                                 principal_point=(cx - xe0, cy - ye0))
                res = np.asarray(_run_technique(technique, b, material, tile_cam, plan.options,
                                                TILE_RULES.get(technique)))
                out[y:y + ty, x:x + tx] = res[r:r + ty, r:r + tx]
                if tile_bar is not None:
                    tile_bar.update(1)
        finally:
            if tile_bar is not None:
                tile_bar.close()
        write_frame(src, dst, out, cam, time.perf_counter() - t0,
                    {"options": plan.options, "warning": plan.warning})

    state = "interrupted"
    try:
        with signals:
            for src, dst in jobs:
                record = _resume_record(src, parameters)[1]
                old = existing.get(dst)
                if (resume and old and old.get("sss_jax:record") == record and exr_is_complete(dst)
                        and (not png or dst.with_suffix(".png").exists())):
                    finish(FrameResult(str(src), str(dst), "skipped", "complete output of the same input and "
                                       "parameters"))
                    continue
                t0 = time.perf_counter()
                try:
                    frame = read_frame(src, channel_map=channel_map, focal_px=focal_px, mm_per_unit=mm_per_unit,
                                       depth_kind=depth_kind)
                    if frame.focal_px is None:
                        raise SSSInputError(f"{src}: no focal length (pass focal_px or put sss_jax:focal_px in the "
                                            "header)")
                    camera = _camera(frame)
                    plan = _frame_plan(technique, frame, material if technique != "sta" else None, camera, options)
                    if plan.warning:
                        warnings.warn(f"{src}: {plan.warning}", stacklevel=2)
                    layout = _tile_layout(*frame.shape, plan, int(tile_pixels))
                    if layout is None:
                        buffers = frame.to_buffers(use_albedo=use_albedo_pass)
                        count = 1 if technique == "sta" else material.count
                        validate_buffers(buffers, materials=count)
                except (OSError, ValueError) as exc:
                    finish(FrameResult(str(src), str(dst), "failed", str(exc)))
                    continue
                if layout is not None:
                    try:
                        run_tiled(src, dst, frame, camera, plan, layout, t0)
                    except (OSError, ValueError) as exc:
                        finish(FrameResult(str(src), str(dst), "failed", str(exc)))
                    continue
                present = tuple(getattr(buffers, n) is not None
                                for n in ("albedo", "normal", "thickness", "material_id"))
                opts_key = tuple((k, _static(plan.options[k])) for k in ("samples", "taps", "radius_px", "albedo",
                                                                          "thickness") if _used(technique, k))
                key = (buffers.depth.shape, present, opts_key)
                pending.setdefault(key, []).append(dict(src=src, dst=dst, buffers=buffers, camera=camera,
                                                        read_s=time.perf_counter() - t0, options=plan.options,
                                                        warning=plan.warning))
                if len(pending[key]) == len(devices):
                    flush(key)
            for key in list(pending):
                flush(key)
        state = "complete"
    finally:
        with contextlib.suppress(OSError, ValueError):
            book.close(state)
        if bar is not None:
            bar.close()
    return BatchResult(frames=results, compilations=traces["count"], manifest=None if manifest is None
                       else str(manifest))


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc: nothing to do
        return None


def _release_free_memory() -> None:
    """Hand freed heap back to the OS. glibc keeps the frame-sized buffers a batch frees between frames: over
    1,000 frames of 256x256 the resident size grew by ~150 MiB with nothing leaking (after ``malloc_trim`` it
    stayed within a few MiB); trimming every few dozen frames keeps a long run's memory flat."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def _used(technique: str, name: str) -> bool:
    return {"samples": technique == "burley", "taps": technique == "separable",
            "radius_px": technique == "reference", "albedo": technique == "sta",
            "thickness": technique == "sta"}[name]


def _static(value):
    """A hashable form of an option (a compile-cache key)."""
    if value is None or isinstance(value, (int, float, np.integer, np.floating)):
        return value
    return tuple(float(v) for v in np.asarray(value, np.float64).ravel())


def _channel_map_record(channel_map) -> Any:
    if channel_map is None or isinstance(channel_map, dict):
        return channel_map
    stamp = _file_stamp(pathlib.Path(channel_map))
    return stamp or str(channel_map)
