"""Batch processing of frame sequences: streamed, sharded over ``jax.devices()``, resumable, failure tolerant.

``process_frames`` is a short driver over small pieces:

- **plan** (before any frame runs): every output path (``out_dir`` keeps each input's path relative to the inputs'
  common folder), no two frames writing one file, no output equal to an input, no existing output made from another
  input (unless ``overwrite``), every output folder writable, the technique's options in range; a batch that fails
  these raises ``SSSInputError`` naming the inputs and writes nothing. Then the temporaries that killed runs left
  beside this run's outputs are removed.
- **the technique object** (``AbstractTechnique``: its options are its fields): the batch asks it, host side, how
  far it reaches (``reach_px``: the tile halo), what it would warn about (``check``: sampling and window warnings)
  and what count the frame's footprint can use (the clamp, with the count run and a work estimate); it never tests
  a technique's name. Until the technique classes land, an adapter over the technique functions answers for them.
- **frames**: in a pipeline of threads: the next frame is read (decoded, checked, its buffers built) in a reader
  thread and the last frame's files are written in a writer thread while the current frame computes (OpenImageIO
  and XLA release the GIL); one frame in flight each way, so memory stays bounded, and results, progress and the
  manifest keep the frames' order. On one device each frame is one call of the technique as a single call runs it
  (its host-side work, compaction and checks included); small frames (``OVERLAP_PIXELS``) whose shape and counts
  have compiled compute ``COMPUTE_THREADS`` at a time in compute threads (one call leaves a small frame's cores idle
  part of the time), each call's warnings kept for its frame (``_CallWarnings``); the rest compute in the main
  thread, alone. On several devices
  frames are grouped by (shape, buffers present, counts); each full group of ``len(devices)`` frames is stacked
  along a leading axis sharded over the devices (``NamedSharding(Mesh(devices, ("frames",)), P("frames"))``) and
  processed by one jitted, vmapped call, with the checks run on the host first.
- **tiles**: a frame larger than one tile's budget (``tile_pixels``) or whose work would keep one call busy for more
  than about a second runs in tiles overlapping by the technique's reach, each told its origin in the frame and the
  frame's shape (``origin=``, ``frame_shape=``): the rotation hash and the frame border follow the frame, so tiles
  give the untiled frame under every rule. A technique that cannot place a tile runs the frame whole.
- **records**: each output carries, in its EXR header, what made it (input path, size, mtime, the technique and
  every option that ran, the frame's seed, the material, the sss_jax version, and their digest); ``resume=True``
  skips a frame whose output carries the same record and whose files all decode (EXR and PNG preview).
- **files**: every file a run leaves (EXR, PNG preview, manifest) is written atomically (a temporary beside it,
  fsync, checked: the EXR's chunk table whole, the PNG decoded; renamed); a full disk or an I/O error fails that
  frame, naming the file, and the batch goes on.
- **manifest**: ``out_dir/sss_jax_manifest.json`` (one per process across hosts) lists every frame's input,
  output, status, message, warnings and seconds. Each finished frame's entry is appended to the run's journal beside
  it (O(1) per frame); the JSON is folded from it atomically at the first frame, about every second and at the end,
  and a killed run's journal is folded by the next run. Runs into one folder merge their entries frame by frame
  under a lock, so it never says a complete frame failed; an output made from an input since re-rendered is not
  complete: a run that fails the new input says so.
- **long frames**: a frame whose calls would pass the work bound (``call_seconds``: about a second on this
  project's 2-core CPU, by the technique's cost per pixel) runs in pieces: tiles, and where a tile (or the frame)
  is still too long, the technique's own pieces (``AbstractTechnique.pieces``: Burley's frames in groups with the
  seed that gives each group its rotations; its samples first spread over frames where a call would take several
  bounds, ``spread``). The clamp's note says what runs, in how many calls and about how long, before the frame
  runs; ``on_progress`` (or a bar) reports the calls done and the time left.
- **signals**: SIGINT and SIGTERM stop the run between frames and between a frame's calls (within about one call:
  seconds) and leave the manifest true; the interrupted frame writes nothing.

Frames of a sequence get their own rotation: a technique's ``seed`` is mixed with the frame number (``frame_seed``).
Across hosts, each process calls ``jax.distributed.initialize()`` first and then processes
``frames_for_process(frames, jax.process_index(), jax.process_count())`` (docs/batch.md shows the launch).
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import ctypes
import ctypes.util
import dataclasses
import fcntl
import functools
import glob
import hashlib
import inspect
import json
import math
from numbers import Real
import os
import pathlib
import re
import signal
import socket
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._checks import check_host_count, is_bool
from ._io import (EXR_MAGIC, Frame, SSSInputError, Window, _frame_from_decoded, _identity, _read_image,
                  check_depth_kind, check_writable, exr_is_complete, load_channel_map, no_focal_length, output_problems,
                  png_attribute, read_header, write_exr, write_json_atomic, write_png_preview)
from ._materials import DirectionalLight, ProfileMaterial, STAParams
from ._scene import Buffers, Camera, remember_validated, validate_buffers, validate_planes
from ._errors import HalfRangeWarning, ReferenceWindowWarning, SamplingWarning, TilePlacementError
from ._techniques import AbstractTechnique, get_technique
from ._techniques import technique as make_technique
from ._techniques._burley_spec import BURLEY_R99, unit_radius
from ._techniques._common import MIN_FOOTPRINT_PX

__all__ = ["BatchResult", "FrameResult", "Interrupted", "MANIFEST_NAME", "expand_inputs", "frame_number",
           "frame_seed", "frames_for_process", "output_paths", "process_frames", "remove_stale_temporaries"]

MANIFEST_NAME = "sss_jax_manifest.json"

# Memory bound per call: pixels of one (extended) tile. Burley's dense working set is ~300 bytes per pixel (18.9 GB
# at 8000x8000), so a tile of 2^21 pixels holds ~0.6 GB; the frame's own arrays (input buffers 16-40 B/px, output
# 12 B/px) come on top.
TILE_PIXELS = 1 << 21
# Work bound per call (seconds on this project's 2-core CPU, from the README's timings): a KeyboardInterrupt lands
# between calls, so no call should run much longer than this. SSS_JAX_CALL_SECONDS overrides it (a test forces
# pieces on a small frame with it).
CALL_SECONDS = 1.0
# A tile that computes only the pixels it keeps (``keep``) keeps at least this many rows and columns (where the frame
# has them): below ~128x128 px a call's arrays are too small to keep XLA's threads busy.
MIN_KEPT_SIDE = 128
# Pieces are cut to a quarter of the work bound by the estimate: the estimate is this project's 2-core CPU, and a
# loaded or slower machine takes several times as long per call (a call costs little more than its work).
PIECES_PER_BOUND = 4
# A call estimated past this many work bounds spreads its technique's work (``AbstractTechnique.spread``: Burley's
# samples into frames) so that it can run in pieces; below it only exact pieces are taken (tiles, frame groups).
SPREAD_CALLS = 4
# Progress inside a frame: one line at most this often (seconds), for a frame that runs in several calls.
PROGRESS_EVERY_S = 2.0
# Frames of at most this many pixels that run as one call on one device compute COMPUTE_THREADS at a time, each in a
# thread of its own: one call leaves a small frame's cores idle part of the time (its host-side work, Burley's count
# and compaction, the loop's start and end, the threads' hand-offs), which the other frame's call fills. The
# technique called on the same frames one after another, and two at a time in two threads (2026-12-02, 2 cores, load
# ~1): Burley 32 at 256x256 8.1 -> 6.2 ms a frame, at 640x360 36.2 -> 30.1 ms; separable 25 at 256x256 5.3 -> 3.5 ms;
# at 1920x1080 two at a time are slower (Burley 469 -> 545 ms a frame: the two working sets leave the caches), so
# larger frames compute one at a time, as do tiles and pieces (their calls are long already) and a frame whose
# shape, counts and calls have not run yet (it compiles, alone).
OVERLAP_PIXELS = 1 << 18
COMPUTE_THREADS = 2
# the radius holding 99.9% of a Burley profile's energy, in units of d: the footprint that bounds useful samples
_BURLEY_R999 = unit_radius(0.001)


@dataclasses.dataclass
class FrameResult:
    input: str
    output: str
    status: str  # "done", "skipped" (complete output of the same input and parameters there) or "failed"
    message: str = ""
    seconds: float = 0.0
    warnings: list[str] = dataclasses.field(default_factory=list)  # the clamp's and the technique's, this frame

    def failure_line(self) -> str:
        """``FAILED <input>: <why>`` for a progress line, the input named once (most messages start with it)."""
        why = self.message.removeprefix(f"{self.input}: ")
        return f"FAILED {self.input}: {why}"


@dataclasses.dataclass
class BatchResult:
    frames: list[FrameResult]
    compilations: int  # programs this batch traced for its vmapped groups (a one-device batch runs frames eagerly)
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


def expand_inputs(inputs: str | os.PathLike | Iterable[str | os.PathLike], what: str = "input frames"
                  ) -> list[pathlib.Path]:
    """Paths from a list of paths and/or glob patterns, in order; a pattern matching nothing is an error, and so is
    no path at all (an empty list: ``what`` names them). A file that exists is itself even where its name holds a
    pattern's characters (``shot[v2].exr``); ``**`` matches any depth of folders, as in a shell with globstar."""
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if isinstance(inputs, (bytes, dict)) or not isinstance(inputs, Iterable):
        raise TypeError(f"{what}: give a path, a glob pattern or a list of them, got {type(inputs).__name__}")
    out: list[pathlib.Path] = []
    for item in inputs:
        if not isinstance(item, (str, os.PathLike)):
            raise TypeError(f"{what}: each must be a path or a glob pattern, got {item!r}")
        s = os.fspath(item)
        if any(ch in s for ch in "*?[") and not os.path.isfile(s):
            matches = sorted(glob.glob(s, recursive=True))
            if not matches:
                raise SSSInputError(f"no files match {s!r}")
            out.extend(pathlib.Path(m) for m in matches)
        else:
            out.append(pathlib.Path(s))
    if not out:
        raise SSSInputError(f"no {what}: the list is empty")
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


def _check_plan(jobs: list[tuple[pathlib.Path, pathlib.Path]], png: bool, manifest: pathlib.Path | None) -> None:
    """No two frames write one file, no output is an input: checked over the whole batch (every process of a
    multi-host run plans the same batch), before anything runs."""
    if not jobs:
        return
    writes = [(str(src), out) for src, dst in jobs for out in [dst] + ([dst.with_suffix(".png")] if png else [])]
    if manifest is not None:
        writes.append(("(the manifest)", manifest))
    problems = output_problems(writes, [src for src, _ in jobs])
    if problems:
        raise SSSInputError("batch refused before any frame ran: " + "; ".join(problems[:10])
                            + (f"; and {len(problems) - 10} more" if len(problems) > 10 else ""))


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
    mtime; its sidecar's too), the technique and every parameter, the sss_jax version and how it reads a file
    (``_io.READER_REVISION``)."""
    from ._io import READER_REVISION
    from ._version import __version__

    stamp = _file_stamp(src) or {"path": str(src)}
    record = {"input": stamp, "sidecar": _file_stamp(src.with_suffix(".json")), "parameters": parameters,
              "version": __version__, "reader": READER_REVISION}
    text = json.dumps(record, sort_keys=True)
    digest = hashlib.sha256(text.encode()).hexdigest()
    attrs = {"sss_jax:input": stamp["path"], "sss_jax:input_size": str(stamp.get("size", "")),
             "sss_jax:input_mtime_ns": str(stamp.get("mtime_ns", "")), "sss_jax:version": __version__,
             "sss_jax:parameters": json.dumps(parameters, sort_keys=True), "sss_jax:record": digest}
    return attrs, digest


def _exr_magic(path: pathlib.Path) -> bool:
    """Whether the file is empty or starts as an OpenEXR file does (its magic number), damaged or not."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError:
        return False
    return head in (b"", EXR_MAGIC)


def _size(path: pathlib.Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


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


# ------------------------------------------------------------------------------------------------------------------
# reach and tiles (host side, NumPy)
# ------------------------------------------------------------------------------------------------------------------


def _largest_px(frame, camera: Camera, per_row_mm: np.ndarray, *, active_r99: float) -> float:
    """The largest footprint in px over the pixels a technique computes: ``per_row_mm[row] * ppm`` (``ppm =
    focal_px / mm_per_unit / depth``, float32 as the techniques compute it; the row is the material id - 1, or the
    first row for a frame without ids or a single material), over the SSS pixels (finite positive depth, id >= 1)
    whose footprint ``px * active_r99`` reaches the techniques' ``MIN_FOOTPRINT_PX``; 0 where none does.

    Each row's largest value is at its nearest surface (float32 division and multiplication by a positive number
    keep the order: the same value as the per-pixel plane, to the bit), so it takes one pass per row over the
    depth, not per-pixel planes of the frame."""
    depth = np.asarray(frame.depth, np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    count = len(per_row_mm)
    ids = None if frame.material_id is None else np.asarray(frame.material_id)
    if ids is not None:
        valid &= ids > 0
    scale = np.float32(float(camera.focal_px) / float(camera.mm_per_unit))
    per_row = per_row_mm.astype(np.float32)
    best = 0.0
    by_id = ids is not None and count > 1  # else every pixel takes the first row
    rows = np.clip(ids - 1, 0, count - 1) if by_id else None
    for row in range(count if by_id else 1):
        where = valid & (rows == row) if by_id else valid
        nearest = np.min(depth, where=where, initial=np.inf)
        if not np.isfinite(nearest):
            continue
        px = per_row[row] * (scale / nearest)  # float32, and so is its product with the Python float below
        if px * active_r99 >= MIN_FOOTPRINT_PX and px > 0:
            best = max(best, float(px))
    return best


def _next_pow2(n: Real) -> int:
    return 1 << max(0, math.ceil(n) - 1).bit_length()


def _starts(n: int, t: int) -> list[int]:
    """Tile starts along an axis: every t pixels, the last tile ending at the last pixel (overlapping the one before
    where n is no multiple of t: all tiles have one shape, one compilation)."""
    return sorted({min(s, n - t) for s in range(0, n, t)})


def _tile(frame: Frame, y0: int, x0: int, ty: int, tx: int, r: int, use_albedo: bool):
    """The tile's buffers: rows y0-r..y0+ty+r, columns x0-r..x0+tx+r of the frame, moved inside the frame where
    they would pass its edge (more halo on the other side: the technique knows where the frame ends from
    ``frame_shape``), so every tile of a frame has one shape (one compilation); and the tile's origin in the
    frame."""
    h, w = frame.shape
    ey, ex = min(ty + 2 * r, h), min(tx + 2 * r, w)
    sy0, sx0 = min(max(y0 - r, 0), h - ey), min(max(x0 - r, 0), w - ex)
    sy1, sx1 = sy0 + ey, sx0 + ex
    cut = lambda a: None if a is None else jnp.asarray(np.ascontiguousarray(a[sy0:sy1, sx0:sx1]))
    ids = None if frame.material_id is None else jnp.asarray(frame.material_id[sy0:sy1, sx0:sx1], jnp.int32)
    return Buffers(irradiance=cut(frame.irradiance), depth=cut(frame.depth),
                   albedo=cut(frame.albedo) if use_albedo else None, normal=cut(frame.normal),
                   thickness=cut(frame.thickness), material_id=ids), (sy0, sx0)


# ------------------------------------------------------------------------------------------------------------------
# what the batch asks of the technique object (sss_jax._techniques._base.AbstractTechnique): its options, reach and
# checks; the clamp and the work estimate follow from its count option
# ------------------------------------------------------------------------------------------------------------------


def _hashable(value):
    """A hashable, JSON-able form of an option value (a record, a compile-cache key)."""
    if value is None or isinstance(value, (bool, str, int, float)):
        return value
    if isinstance(value, (np.integer, np.floating, np.bool_)):
        return value.item()
    if isinstance(value, (jax.Array, np.ndarray)) and np.ndim(value) == 0:
        return np.asarray(value).item()
    if isinstance(value, eqx.Module):
        return _material_record(value)
    return tuple(float(v) for v in np.asarray(value, np.float64).ravel())


_NAMED_AS = {"albedo": "sta_albedo", "thickness": "sta_thickness"}  # process_frames' names for STA's two options


def _technique_object(technique, options: dict[str, Any], material, named: dict[str, Any] | None = None):
    """The technique object a batch runs and its material: one given (an ``AbstractTechnique``), or the one
    registered under a name with ``options`` (``technique_options``: one it does not have is refused, the error
    lists the valid names) and ``named``, the counts and STA options ``process_frames`` takes by name: one the
    technique does not have (``taps`` for burley) is not used, with a warning (a script may pass every count for
    whichever technique it runs, as the CLI does). A ``(params, light)`` pair gives a technique with a ``light``
    field its light."""
    named = dict(named or {})
    if isinstance(technique, str):
        cls = get_technique(technique)
        fields = {f.name for f in dataclasses.fields(cls)}
        unused = sorted(k for k in named if k not in fields)
        if unused:
            warnings.warn(f"{', '.join(_NAMED_AS.get(k, k) for k in unused)}: not an option of {technique!r}, not "
                          "used", UserWarning, stacklevel=3)
        options = {**{k: v for k, v in named.items() if k in fields}, **options}
        if isinstance(material, tuple) and len(material) == 2 and "light" in fields:
            material, options = material[0], {**options, "light": material[1]}
        tech = make_technique(technique, **options)  # an option it does not have is refused
    else:
        if not isinstance(technique, AbstractTechnique):
            raise TypeError(f"technique must be a technique name or object, got {type(technique).__name__}")
        if options or named:
            raise TypeError(f"options {sorted({**named, **options})} go on the technique object itself, not to "
                            "process_frames")
        tech = technique
    if isinstance(material, (str, pathlib.Path)):  # a preset name or file
        from ._presets import load_preset, material_for

        material = material_for(tech, load_preset(material))
    tech.check_material(material)
    if getattr(tech, "radius_px", 0) is None:
        raise ValueError(f"technique {tech.name!r} in a batch needs radius_px (one window for every frame)")
    _check_ranges(tech)
    return tech, material


def _check_ranges(tech) -> None:
    """Ranges of the options a technique takes as plain values (checked when it runs; a batch checks them before
    any frame)."""
    albedo = getattr(tech, "albedo", None)
    if albedo is not None:
        a = np.asarray(albedo, np.float64)
        if a.shape not in ((3,), (1, 3)) or not np.all((a >= 0) & (a <= 1)):  # NaN fails both
            raise ValueError(f"{tech.name}: albedo must be 3 values in [0, 1], got {a.tolist()}")
    t = getattr(tech, "thickness", None)
    if t is not None and not np.all(np.asarray(t, np.float64) >= 0):
        raise ValueError(f"{tech.name}: thickness must be >= 0 scene units (inf: infinitely thick), got {t}")


def _technique_options(tech) -> dict[str, Any]:
    """The technique's name and every option (the rules that ran: the records say what made an output), and its
    other fields (a light) as records."""
    out: dict[str, Any] = {"technique": tech.name}
    for f in dataclasses.fields(tech):
        out[f.name] = _hashable(getattr(tech, f.name))
    return out


def _has_seed(tech) -> bool:
    return any(f.name == "seed" for f in dataclasses.fields(tech))


def _with_seed(tech, seed):
    """The technique with ``seed`` (an integer or a traced one): each frame of a sequence its own rotation."""
    return tech.replace(seed=seed)


def frame_number(path: str | pathlib.Path, index: int) -> int:
    """The frame number of a sequence's file: the last run of digits in its name (``shot.0042.exr`` -> 42), else its
    place in the batch. It goes into the rotation seed, so a frame gets the same rotation whichever share, resume
    or subset of the sequence computes it."""
    digits = re.findall(r"\d+", pathlib.Path(path).stem)
    return int(digits[-1]) if digits else index


def frame_seed(base: int, number: int) -> int:
    """The seed of frame ``number``: ``base`` mixed with the frame number (Knuth's multiplicative hash), so frames
    differ and neighbouring (seed, frame) pairs do not collide; reproducible."""
    return (int(base) ^ ((int(number) * 0x9E3779B1) & 0xFFFFFFFF)) & 0xFFFFFFFF


def _under_a_pixel(material) -> str:
    """The rest of a clamp's message where the material scatters less than a pixel: what the frame gets, and the
    unit a d of metres typed as millimetres would have gone wrong in."""
    d = getattr(material, "d_mm", None)
    widest = f" (the widest d {float(np.max(np.asarray(d))):.3g} mm)" if d is not None else ""
    return (f": the frame keeps its local shading{widest}; if that is not meant, the material's lengths are in "
            "millimetres and the camera's unit is --mm-per-unit")


def _clamp(tech, buffers: Buffers, material, camera: Camera):
    """The technique with its count clamped to what the frame's footprint can use, and the message (or ""): samples
    of a 2D profile beyond the next power of two above the pixels of its 99.9%-energy footprint, taps of a 1D pass
    beyond the next 2^k + 1 above the pixels it reaches, a window beyond the frame."""
    h, w = buffers.depth.shape[-2:]
    option = getattr(tech, "count_option", None)
    if option == "samples" and hasattr(material, "d_mm"):
        samples = int(tech.samples)
        d_max = np.asarray(material.d_mm, np.float64).reshape(-1, 3).max(axis=-1)
        d_px = _largest_px(buffers, camera, d_max, active_r99=BURLEY_R99)
        # the power of two keeps the sequence's distinct counts, and compilations, few
        footprint = min(math.pi * (_BURLEY_R999 * d_px) ** 2, h * w)
        bound = _next_pow2(max(footprint, 1.0))
        if samples > bound:
            if footprint < 1:
                return tech.replace(samples=bound), (f"samples {samples} clamped to {bound}: no pixel's footprint "
                                                     f"reaches a neighbouring pixel{_under_a_pixel(material)}")
            return tech.replace(samples=bound), (f"samples {samples} clamped to {bound}: the footprint has "
                                                 f"{math.ceil(footprint)} pixels, more samples cannot help")
    elif option == "taps":
        taps = int(tech.taps)
        footprint = 2 * int(tech.reach_px(buffers, material, camera)) + 1  # a pass reads 2 reach + 1 pixels of a row
        # 2^k + 1 taps (odd, a centre and symmetric pairs); a pass that reaches no other pixel needs its centre only
        bound = 1 if footprint <= 1 else _next_pow2(footprint - 1) + 1
        if taps > bound:
            if footprint <= 1:
                return tech.replace(taps=bound), (f"taps {taps} clamped to {bound}: a pass reaches no neighbouring "
                                                  f"pixel{_under_a_pixel(material)}")
            return tech.replace(taps=bound), (f"taps {taps} clamped to {bound}: a pass reaches {footprint} pixels, "
                                              "more taps cannot help")
    radius = getattr(tech, "radius_px", None)
    if isinstance(radius, (int, np.integer)) and radius > max(1, max(h, w) - 1):
        cap = max(1, max(h, w) - 1)  # a window past the frame reaches no further pixel
        return tech.replace(radius_px=cap), f"radius_px {radius} clamped to {cap}: the frame is {w}x{h} pixels"
    return tech, ""


# Seconds per pixel per unit of a technique's count (samples x frames, taps, window pixels, TAA frames) on this
# project's 2-core CPU: the work estimate before the batch has measured a frame of its own. Measured on the demo frame
# at its defaults, 640x360 and 1920x1080, second call (2026-12-07, load 1.5-1.8): jimenez 1.6-1.8e-8 a tap (its taps
# in a loop), reference 6.2-7.4e-8 a window pixel (the former shared figures were 2.5-7x short of these: the first
# frame's plan let calls run several times the bound). The techniques that compute only SSS pixels
# (``sss_pixels_only``) are costed per SSS pixel (``_work_share``; 24% of the demo frame, 2026-12-07 17:55, load
# 0.8-1.5): burley 1.6-1.8e-8 a sample, hdrp 4.8-5.2e-8 a sample, eevee-next 1.9-4.1e-7 a TAA frame. separable
# (2.8-4.0e-9 a tap on the demo frame) computes its blocks' pixels only: its figure holds a frame that is all skin.
_SECONDS_PER_UNIT = {"burley": 1.7e-8, "hdrp": 5e-8, "separable": 9e-9, "jimenez": 2e-8, "reference": 7.5e-8,
                     "eevee-next": 2.8e-7}


def _seconds_per_px(tech) -> float:
    """Rough cost per pixel on this project's 2-core CPU (``_SECONDS_PER_UNIT``), from the technique's counts: the
    work estimate before the batch has measured a frame of its own."""
    frames = int(getattr(tech, "frames", 1) or 1)
    unit = _SECONDS_PER_UNIT.get(getattr(tech, "name", None))
    if isinstance(getattr(tech, "samples", None), (int, np.integer)):
        return (unit or 1.4e-8) * int(tech.samples) * frames
    if isinstance(getattr(tech, "taps", None), (int, np.integer)):
        return (unit or 9e-9) * int(tech.taps)
    if isinstance(getattr(tech, "radius_px", None), (int, np.integer)):
        return (unit or 7.5e-8) * (2 * int(tech.radius_px) + 1) ** 2
    return (unit or 4e-8) * frames  # (EEVEE Next's 16 samples a TAA frame: its frames are its count)


def call_seconds() -> float:
    """The work bound per call: ``SSS_JAX_CALL_SECONDS`` where set (a positive number), else ``CALL_SECONDS``."""
    text = os.environ.get("SSS_JAX_CALL_SECONDS")
    if not text:
        return CALL_SECONDS
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0:
        raise ValueError(f"SSS_JAX_CALL_SECONDS must be a positive number of seconds, got {text!r}")
    return value


# ------------------------------------------------------------------------------------------------------------------
# the run's files: manifest (merged by frame under a lock), stale temporaries
# ------------------------------------------------------------------------------------------------------------------

_RANK = {"done": 3, "skipped": 3, "failed": 1, "pending": 0}


@contextlib.contextmanager
def _folder_lock(folder: pathlib.Path):
    """An exclusive ``flock`` on the folder itself (no lock file left behind): runs sharing an output folder take
    turns merging the manifest."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


# The manifest's JSON is folded from the journal at most this often (seconds) while a run goes on, and at its end;
# a fold rewrites the whole manifest (O(frames)), so on a long batch it waits at least FOLD_COST_RATIO times what the
# last fold took: folding stays a few percent of the run however many frames the manifest lists.
FOLD_SECONDS = 1.0
FOLD_COST_RATIO = 20
_JOURNAL = re.compile(r"^\.(?P<name>.+)\.sss_jax-(?P<host>.+)-(?P<pid>\d+)\.journal$")


def _journal_path(manifest: pathlib.Path) -> pathlib.Path:
    """Where a run appends its manifest entries between folds: a hidden file beside the manifest naming the writer
    (host and pid), so a later run can tell the journal of a run that is gone (SIGKILL) from a live one's."""
    return manifest.parent / f".{manifest.name}.sss_jax-{socket.gethostname()}-{os.getpid()}.journal"


def _journal_entries(path: pathlib.Path) -> list[dict[str, Any]]:
    """The entries of a journal, in order; a line cut short by a kill (the last one) is ignored."""
    out = []
    with contextlib.suppress(OSError):
        for line in path.read_bytes().splitlines():
            with contextlib.suppress(ValueError):
                entry = json.loads(line)
                if isinstance(entry, dict) and "output" in entry:
                    out.append(entry)
    return out


def _merge_entry(frames: dict[str, Any], entry: dict[str, Any]) -> None:
    """Put ``entry`` in ``frames``, unless the entry there is another run's, says the output is complete while
    ``entry`` does not, and that output exists (the disk holds it) made from what ``entry`` was to be made from:
    its ``record`` (the digest of its resume record, ``_resume_record``), where it has one. An output an earlier
    run made from an input since re-rendered is not this frame's: a run that fails the new input says so."""
    out = entry.get("output")
    old = frames.get(out)
    keep_old = (old is not None and old.get("run") != entry.get("run")
                and _RANK.get(old.get("status"), 0) > _RANK.get(entry.get("status"), 0) and os.path.exists(out)
                and _made_from(out, entry.get("record")))
    if not keep_old:
        frames[out] = entry


def _made_from(output: str, record: str | None) -> bool:
    """Whether the existing ``output`` carries the resume record ``record`` (any output where ``record`` is None:
    an entry that does not say what it was made from)."""
    if record is None:
        return True
    header = _existing_output(pathlib.Path(output))
    return bool(header) and header.get("sss_jax:record") == record


class _Manifest:
    """The manifest: the settings of the runs and one entry per frame (pending, done, failed with the message,
    skipped, and the warnings).

    Each finished frame's entry is appended to this run's journal (one JSON line, ``os.write`` on an ``O_APPEND``
    file: O(1) per frame, in the OS's hands before the next frame starts, so a kill loses none); the manifest JSON is
    folded from it (rewritten atomically, the journal emptied) at the first frame, at most every ``FOLD_SECONDS``
    (longer on a long batch, see ``FOLD_COST_RATIO``) and when the run ends or is interrupted, after which the journal
    is removed. A run finds the journals of runs on this host that are gone (killed) and folds them in at its start
    and end.

    Runs into one folder at once share it: each fold merges, under a lock on the folder, this run's entries into what
    is on disk, frame by frame; an entry that says an output is complete (done/skipped) is not replaced by another
    run's pending or failed one while that output exists (the disk holds it; that run's own result says it failed).
    So the manifest never says a complete frame failed. Complete means made from the same input and parameters: an
    entry says what it was to be made from (``record``, its resume record's digest), and an earlier run's output
    of an input since re-rendered does not hide a run that fails the new input."""

    def __init__(self, path: pathlib.Path | None, run: dict[str, Any], jobs: list["_Job"]):
        self.path = path
        self.run = dict(run, state="running")
        self.run_id = f"{socket.gethostname()}-{os.getpid()}-{time.time_ns()}"
        # entries keyed by the output's absolute path: runs that spell the folder differently ("out", its absolute
        # path) share one entry per file (before, the earlier run's "failed" stayed beside the later "done")
        self.mine = {os.path.abspath(j.dst): {"input": os.path.abspath(j.src), "output": os.path.abspath(j.dst),
                                              "status": "pending", "message": "", "warnings": [], "seconds": 0.0,
                                              "run": self.run_id} for j in jobs}
        self.last: tuple[int, int] | None = None  # (inode, mtime_ns) of this run's last write: unchanged -> no merge
        self.by_name: dict[str, list[str]] | None = None  # this run's outputs by file name (``_absolute``)
        self.data: dict[str, Any] = {}
        self.failed = False
        self.journal = None if path is None else _journal_path(path)
        self.journal_fd: int | None = None
        self.records = 0
        self.folded_at = -math.inf
        self.fold_s = 0.0  # what the last fold took
        self.write(dead_journals=True)

    def record(self, r: "FrameResult", digest: str | None = None) -> None:
        """The frame's entry; ``digest``: its resume record's (``_resume_record``), where the run computed it."""
        entry = {"input": os.path.abspath(r.input), "output": os.path.abspath(r.output), "status": r.status,
                 "message": r.message, "warnings": list(r.warnings), "seconds": round(r.seconds, 4),
                 "run": self.run_id}
        if digest is not None:
            entry["record"] = digest
        self.mine[entry["output"]] = entry
        if self.path is None:
            return
        self.records += 1
        appended = self._append(entry)
        now = time.perf_counter()
        # the first entry folds at once (a watcher sees the run progress), then at most every FOLD_SECONDS
        due = now - self.folded_at >= max(FOLD_SECONDS, FOLD_COST_RATIO * self.fold_s)
        if not appended or self.failed or self.records == 1 or due:
            self.write()

    def close(self, state: str) -> None:
        self.run["state"] = state
        self.write(dead_journals=True)
        if self.path is not None:
            # the journal goes once its entries are in the manifest; else it stays for the next run to fold
            self._drop_journal(unlink=not self.failed)

    def _append(self, entry: dict[str, Any]) -> bool:
        try:
            if self.journal_fd is None:
                self.journal_fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
            line = (json.dumps(entry, default=str) + "\n").encode()
            if os.write(self.journal_fd, line) != len(line):  # a short write (full disk): the fold rewrites all
                return False
        except OSError:
            return False
        return True

    def _drop_journal(self, *, unlink: bool) -> None:
        if self.journal_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self.journal_fd)
            self.journal_fd = None
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.journal.unlink()

    def _dead_journals(self) -> list[pathlib.Path]:
        """Journals of this manifest left by runs on this host that are gone (their entries not folded)."""
        host, out = socket.gethostname(), []
        with contextlib.suppress(OSError):
            for entry in os.scandir(self.path.parent):
                m = _JOURNAL.match(entry.name)
                if (m is not None and m["name"] == self.path.name and m["host"] == host
                        and _gone(int(m["pid"]), entry)):
                    out.append(pathlib.Path(entry.path))
        return out

    def _stamp(self) -> tuple[int, int] | None:
        try:
            st = self.path.stat()
        except OSError:
            return None
        return st.st_ino, st.st_mtime_ns

    def _merged(self, dead: list[pathlib.Path]) -> dict[str, Any]:
        theirs: dict[str, Any] = {}
        if self.last is None or self._stamp() != self.last:  # another run wrote since: merge with it
            with contextlib.suppress(OSError, ValueError):
                theirs = json.loads(self.path.read_text())
        if not isinstance(theirs, dict):
            theirs = {}
        runs = {r.get("run"): r for r in theirs.get("runs", []) if isinstance(r, dict)} if theirs else {
            r["run"]: r for r in self.data.get("runs", [])}
        runs[self.run_id] = dict(self.run, run=self.run_id)
        frames = {}
        for f in (theirs or self.data).get("frames", []):
            if isinstance(f, dict):
                f = self._absolute(f)
                frames[f.get("output")] = f
        for journal in dead:  # a killed run's last entries, then this run's
            for entry in _journal_entries(journal):
                _merge_entry(frames, self._absolute(entry))
        for entry in self.mine.values():
            _merge_entry(frames, entry)
        return dict(self.run, runs=list(runs.values()), frames=list(frames.values()))

    def _absolute(self, entry: dict[str, Any]) -> dict[str, Any]:
        """An entry of a manifest written before entries held absolute paths (its output as the run spelled it,
        relative to a folder it did not record) under this run's output that ends with that path, where exactly one
        does: one entry per file, not an old "done" beside a new "failed". Other entries as they are."""
        out = entry.get("output")
        if not isinstance(out, str) or not out or os.path.isabs(out):
            return entry
        if self.by_name is None:
            self.by_name = {}
            for key in self.mine:
                self.by_name.setdefault(os.path.basename(key), []).append(key)
        tail = os.sep + os.path.normpath(out)
        match = [key for key in self.by_name.get(os.path.basename(out), []) if key.endswith(tail)]
        return dict(entry, output=match[0]) if len(match) == 1 else entry

    def write(self, *, dead_journals: bool = False) -> None:
        """Fold: the manifest rewritten atomically with every entry so far, then this run's journal emptied (and
        the dead runs' journals that were folded in removed)."""
        if self.path is None:
            return
        t0 = time.perf_counter()
        try:
            with _folder_lock(self.path.parent):
                dead = self._dead_journals() if dead_journals else []
                self.data = self._merged(dead)
                write_json_atomic(self.path, self.data)
                self.last = self._stamp()
                if self.journal_fd is not None:  # its entries are in the manifest now
                    os.ftruncate(self.journal_fd, 0)
                for journal in dead:
                    with contextlib.suppress(FileNotFoundError):
                        journal.unlink()
        except OSError as exc:  # a full disk: the frames go on, the manifest is folded whole at the next frame
            if not self.failed:
                warnings.warn(f"{self.path}: the manifest could not be written ({_describe(exc)}); it is retried "
                              "as each frame finishes", UserWarning, stacklevel=2)
            self.failed = True
        else:
            self.failed = False
        self.folded_at = time.perf_counter()
        self.fold_s = self.folded_at - t0


_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.sss_jax-(?P<host>.+)-(?P<pid>\d+)\.[^.]+\.tmp(\.[^.]+)?$")
_OLD_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]{8}\.tmp(\.[^.]+)?$")  # before the host-pid names
_OLD_TEMPORARY_AGE_S = 600


_LOADED_AT = time.time()  # before any file this process writes through sss_jax


def _gone(pid: int, entry: os.DirEntry) -> bool:
    """Whether the process of this host that left ``entry`` (named with its pid) is gone: another pid that is not
    alive, or this process's own pid on a file older than this module, left by an earlier process that had the same
    pid (a container restarted after a kill runs as pid 1 again)."""
    if pid != os.getpid():
        return not _alive(pid)
    try:
        return entry.stat(follow_symlinks=False).st_mtime < _LOADED_AT
    except OSError:
        return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(outputs: Iterable[pathlib.Path]) -> list[pathlib.Path]:
    """Remove the temporaries that writers of these outputs left behind (a run killed by SIGKILL mid-write): those
    of a process of this host that is gone, and unnamed ones older than 10 minutes. A live writer's are kept."""
    wanted: dict[pathlib.Path, set[str]] = {}
    for p in outputs:
        wanted.setdefault(p.parent, set()).add(p.name)
    host, removed = socket.gethostname(), []
    for folder, names in wanted.items():
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            if not entry.name.startswith(".") or ".tmp" not in entry.name:
                continue
            m = _TEMPORARY.match(entry.name)
            if m is not None:
                stale = m["name"] in names and m["host"] == host and _gone(int(m["pid"]), entry)
            else:
                m = _OLD_TEMPORARY.match(entry.name)
                stale = False  # a name that cannot be stat'ed (gone meanwhile, a dangling link) is left alone
                with contextlib.suppress(OSError):
                    stale = (m is not None and m["name"] in names
                             and time.time() - entry.stat().st_mtime > _OLD_TEMPORARY_AGE_S)
            if m is not None and stale:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(entry.path)
                    removed.append(pathlib.Path(entry.path))
    return removed


def _describe(exc: BaseException, path: pathlib.Path | None = None) -> str:
    """An error message that names the file (an ``OSError`` from a full disk says only "No space left")."""
    text = str(exc)
    if isinstance(exc, OSError) and exc.strerror and not isinstance(exc, SSSInputError):
        text = exc.strerror if exc.errno is None else f"{exc.strerror} (errno {exc.errno})"
    elif not isinstance(exc, (OSError, ValueError)):  # not a reader's message: what went wrong, by its type
        text = f"{type(exc).__name__}: {text}"
    name = path or getattr(exc, "filename", None)
    if name is not None and str(name) not in text and pathlib.Path(str(name)).name not in text:
        text = f"{name}: {text}"
    return text


# ------------------------------------------------------------------------------------------------------------------
# plan: the jobs, the existing outputs, the frame's technique
# ------------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Job:
    src: pathlib.Path
    dst: pathlib.Path
    number: int  # the frame number (rotation seed)

    def files(self, png: bool) -> list[pathlib.Path]:
        return [self.dst] + ([self.dst.with_suffix(".png")] if png else [])


def _targets(paths, out_dir, outputs) -> list[pathlib.Path]:
    if outputs is not None and out_dir is not None:
        raise ValueError("give out_dir or outputs, not both (outputs name every file; out_dir is their folder)")
    if outputs is not None:
        if len(outputs) != len(paths):
            raise ValueError(f"{len(outputs)} outputs for {len(paths)} inputs")
        targets = [pathlib.Path(o) for o in outputs]
    elif out_dir is not None:
        targets = output_paths(paths, out_dir)
    else:
        raise ValueError("give out_dir or outputs")
    for t in targets:
        if t.suffix.lower() != ".exr":
            raise SSSInputError(f"{t}: outputs are linear float EXR and need the .exr extension "
                                "(png=True / --png adds an sRGB PNG preview beside each)")
    return targets


def _existing_outputs(jobs: list[_Job], overwrite: bool, png: bool = False) -> dict[pathlib.Path, dict]:
    """The existing outputs of this share: made from the same input (resumable or recomputed) or refused. With
    ``png``, a PNG where a frame's preview goes is taken as that frame's only beside its own EXR (made from the same
    input); any other is someone's image, refused as a foreign EXR is."""
    existing: dict[pathlib.Path, dict] = {}
    foreign = []
    for job in jobs:
        header = _existing_output(job.dst)
        made_from = (header or {}).get("sss_jax:input")
        same_input = _same_input(made_from, job.src)
        preview = job.dst.with_suffix(".png")
        # the preview records its input too (written first: a run killed before its EXR leaves one alone)
        if png and not overwrite and preview.is_file() and not (
                same_input or _same_input(png_attribute(preview, "sss_jax:input"), job.src)):
            foreign.append(f"{preview} exists and is not the preview of an output made from {job.src}")
        if header is None:
            continue
        existing[job.dst] = header
        if overwrite:
            continue
        if not header and job.dst.is_file() and not _exr_magic(job.dst):  # notes, a PNG named .exr: not ours (a
            # damaged EXR is recomputed, as resume does; a folder there is named by the output checks)
            foreign.append(f"{job.dst} exists and is not an EXR ({_size(job.dst)} bytes)")
        elif header and not same_input:
            foreign.append(f"{job.dst} exists and was made from {made_from or 'something other than sss_jax'}, "
                           f"not {job.src}")
    if foreign:
        raise SSSInputError("existing outputs would be overwritten (pass overwrite=True / --overwrite to allow it, "
                            "or choose another output folder): " + "; ".join(foreign[:10])
                            + (f"; and {len(foreign) - 10} more" if len(foreign) > 10 else ""))
    return existing


def _same_input(made_from: str | None, src: pathlib.Path) -> bool:
    """Whether an output's recorded input (``sss_jax:input``, None where it records none) is the file ``src``."""
    return made_from is not None and _identity(pathlib.Path(str(made_from))) == _identity(src)


def _check_folders(paths: list[pathlib.Path], create_dirs: bool) -> None:
    for path in paths:  # every path first: a refusal leaves no folder made for the others
        if path.is_dir():
            raise SSSInputError(f"{path}: output path is a directory")
    probed = set()
    for path in paths:
        if path.parent not in probed:  # --out-dir's folders are made; a typo in -o's folder is not
            check_writable(path, create_dirs=create_dirs)
            probed.add(path.parent)


def _is_complete(job: _Job, png: bool, header: dict | None, record: str) -> bool:
    """What --resume skips for: the output records the same input and parameters, and every file of the frame
    decodes (the EXR and, with png, its preview)."""
    return bool(header) and header.get("sss_jax:record") == record and all(
        exr_is_complete(p) for p in job.files(png))


@dataclasses.dataclass
class _FramePlan:
    """How one frame runs: its technique (counts clamped, work spread, the frame's seed), the clamp's message and
    work estimate, the tile layout (None: whole) and the pieces each tile runs as (None: one call)."""

    tech: Any
    notes: list[str]
    layout: tuple[int, int] | None = None
    overlap: int = 0
    pieces: tuple[tuple[Any, float], ...] | None = None
    tiles: int = 1
    estimate_s: float = 0.0
    share: float = 1.0  # the share of the frame's pixels its work follows (``_work_share``)

    @property
    def calls(self) -> int:
        return self.tiles * (1 if self.pieces is None else len(self.pieces))


# the least share of a frame's pixels a technique that computes only SSS pixels is costed at: its set-up, the
# compaction and the scatter back run over every pixel
MIN_WORK_SHARE = 1 / 16


def _work_share(tech, buffers: Buffers) -> float:
    """The share of the frame's pixels a call's work follows: all, or for a technique that computes only the SSS
    pixels (``sss_pixels_only``: burley, hdrp, eevee-next) theirs, at least ``MIN_WORK_SHARE``. HDRP over the demo
    scene at 1920x1080 (SSS on 24% of it): 0.9 s a call, where every pixel computed took 2.9 s."""
    if not getattr(type(tech), "sss_pixels_only", False):
        return 1.0
    from ._techniques._common import sss_mask_of

    # on the host (the planes' NumPy views): a JAX reduction here waited behind the frames computing on the device,
    # 2.3 ms a 256x256 frame in a batch of Burley against 0.13 ms alone (2026-12-07)
    ids = None if buffers.material_id is None else np.asarray(buffers.material_id)
    mask = sss_mask_of(np.asarray(buffers.depth), ids)
    return max(float(np.count_nonzero(mask)) / max(mask.size, 1), MIN_WORK_SHARE)


def _plan_frame(tech, buffers: Buffers, material, camera: Camera, tile_pixels: int, cost: "_Cost",
                tiles_allowed: bool = True) -> _FramePlan:
    """The frame's plan: counts clamped to the footprint; tiles where the frame passes the memory bound
    (``tile_pixels``) or the work bound (``call_seconds``); and where one call (the frame, or a tile: it computes
    its halo too unless the technique takes ``keep``) would still pass the work bound, the technique's own pieces
    (``AbstractTechnique.pieces``; its work spread first where a call would take several bounds), so that progress
    shows and a signal lands within a few seconds."""
    notes = []
    tech, message = _clamp(tech, buffers, material, camera)
    clamped = tech
    h, w = buffers.depth.shape[-2:]
    bound = call_seconds()
    share = _work_share(tech, buffers)
    seconds_per_px = cost.per_px(tech) * share  # per pixel of the frame
    budget = min(tile_pixels, int(bound / seconds_per_px) if seconds_per_px else tile_pixels)
    plan = _FramePlan(tech, notes, share=share)
    call_px = h * w
    if h * w > budget and tiles_allowed:
        overlap = int(tech.reach_px(buffers, material, camera))
        # the inner part at least as wide as the overlap: a tile never holds more than ~9x its own pixels (a wide
        # window on a small frame then runs whole, or in pieces, rather than in tiles made of overlap)
        least = overlap + 8
        keeps = _takes_keep(tech)
        if keeps:
            # a tile computes only the pixels it keeps (its halo read, not computed): the work bound sizes the kept
            # part, the memory bound the tile with its halo (HDRP on a 3840x2160 close-up: 112 tiles of 745x745 px
            # keeping 345x345 each, 135.9 s, against 17.3 s for the frame whole)
            # (kept parts of at least MIN_KEPT_SIDE^2 px where the memory bound allows: smaller calls run slower per
            # pixel, the reference with a 16-px window over a 640x360 frame in 24 tiles keeping 90x107 px 7.5 s of
            # compute, whole 5.6 s)
            work_side = math.isqrt(max(int(bound / seconds_per_px), 1)) if seconds_per_px else h + w
            inner = max(min(max(work_side, MIN_KEPT_SIDE), math.isqrt(tile_pixels) - 2 * overlap), least)
        else:
            inner = max(math.isqrt(max(budget, 1)) - 2 * overlap, least)
        # as few tiles as fit, of equal size (1600 px in tiles of at most 1352: two of 800, not 1352 and a shifted
        # 1352)
        ty, tx = -(-h // -(-h // inner)), -(-w // -(-w // inner))
        tiles = len(_starts(h, ty)) * len(_starts(w, tx))
        tile_px = min(ty + 2 * overlap, h) * min(tx + 2 * overlap, w)
        computed_px = min(ty, h) * min(tx, w) if keeps else tile_px
        # tiles only for the work bound (the frame fits the memory bound) that would compute their halos over and
        # over: the frame whole, in the technique's pieces where it has them, else in one call longer than the bound
        # (an HDRP pass over a 1920x1080 frame ran in 6 tiles of 1080x1212 px, 3.6x the work: 17.8 s against 5.0 s)
        wasteful = h * w <= tile_pixels and tiles * computed_px > 1.5 * h * w
        if (ty, tx) != (h, w) and not wasteful:
            plan.layout, plan.overlap, plan.tiles, call_px = (ty, tx), overlap, tiles, computed_px
    call_s = seconds_per_px * call_px
    if call_s > bound:
        plan.tech, plan.pieces = _spread_pieces(tech, call_s, bound)
    plan.estimate_s = seconds_per_px * call_px * plan.tiles
    if message:
        note = (f"{message}; it runs {_count_text(plan.tech)}, about {_seconds_text(plan.estimate_s)} per frame on "
                f"this machine ({cost.source(plan.tech)})")
        if plan.calls > 1:
            note += f", in {plan.calls} calls"
        if plan.tech is not clamped:
            note += (f" ({_count_text(clamped)} run as {_count_text(plan.tech)}: the work spread so that each call "
                     "is short, progress shows and Ctrl-C stops it within seconds)")
        notes.append(note)
    return plan


def _spread_pieces(tech, call_s: float, bound: float):
    """The technique (its work spread where one call would take several bounds) and its pieces for a call of
    ``call_s`` seconds (None: it does not split)."""
    want = math.ceil(PIECES_PER_BOUND * call_s / bound)
    if call_s > SPREAD_CALLS * bound:
        tech = tech.spread(want)
    return tech, tech.pieces(want)


def _count_text(tech) -> str:
    opts = _technique_options(tech)
    name = lambda k: k.replace("_", " ").removesuffix("s" if opts[k] == 1 and k != "radius_px" else "")
    shown = [f"{opts[k]} {name(k)}" for k in ("samples", "taps", "radius_px", "frames") if k in opts
             and not (k == "frames" and opts[k] == 1)]
    return ", ".join(shown) or "its options"


def _seconds_text(s: float) -> str:
    return f"{s:.2g} s" if s < 10 else (f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min")


class _Cost:
    """Seconds per pixel per unit of the technique's count, as this batch measures them (frame seconds over the
    estimate from the technique's own figure): the work estimate for the next frames."""

    def __init__(self):
        self.ratio: float | None = None
        self.seen: set[tuple] = set()

    def per_px(self, tech) -> float:
        return _seconds_per_px(tech) * (self.ratio or 1.0)

    def source(self, tech) -> str:
        return "measured on this batch's frames" if self.ratio else "the technique's cost per pixel on a 2-core CPU"

    @staticmethod
    def key(tech, shape: tuple[int, ...], calls: int) -> tuple:
        return tuple(shape), calls, _count_text(tech)

    def has_run(self, tech, shape: tuple[int, ...], calls: int) -> bool:
        """Whether a frame of this shape, counts and calls has run (compiled) in this batch."""
        return self.key(tech, shape, calls) in self.seen

    def measured(self, tech, pixels: Real, seconds: float, *, shape: tuple[int, ...] = (), calls: int = 1) -> None:
        """Learn from a frame's seconds, except the first frame of each shape, counts and calls: it compiled (a 256x256
        Burley frame: ~1 s of compile against ~10 ms of work), and taken as work it made the next frames run in
        pieces, compiling again."""
        key = self.key(tech, shape, calls)
        if key not in self.seen:
            self.seen.add(key)
            return
        if pixels and seconds > 0:
            r = seconds / (_seconds_per_px(tech) * pixels)
            self.ratio = r if self.ratio is None else 0.7 * self.ratio + 0.3 * r


# ------------------------------------------------------------------------------------------------------------------
# running a frame: whole (eager: the technique's host-side work, compaction and checks, as a single call gets),
# vmapped over devices, or in tiles
# ------------------------------------------------------------------------------------------------------------------

_TECHNIQUE_WARNINGS = (SamplingWarning, ReferenceWindowWarning)
# what a frame's result and manifest entry record: its technique's warnings and its writer's (a half output's clamp)
_FRAME_WARNINGS = (*_TECHNIQUE_WARNINGS, HalfRangeWarning)


def _material_count(material) -> int:
    """Rows of the material table (one for STA's (params, light) pair)."""
    return int(getattr(material, "count", 1))


class _CallWarnings:
    """The technique warnings of each call, kept for the frame it computes, in whichever thread computes it.
    ``warnings.catch_warnings`` swaps process-wide state, so two frames computing at once could not each use it: this
    is installed once for the run (``installed``, in the main thread), and each call records into a list of its own
    thread's (``call``). Warnings raised outside a call (the main thread's, where it says a frame's warnings to the
    user) go where they went before; while the run goes, the technique warnings are always shown or recorded (a
    call records them for every frame; the batch says each once, ``_Warnings``)."""

    def __init__(self):
        self.local = threading.local()

    @contextlib.contextmanager
    def installed(self):
        with warnings.catch_warnings():
            previous = warnings.showwarning

            def show(message, category, filename, lineno, file=None, line=None):
                caught = getattr(self.local, "caught", None)
                if caught is None:
                    previous(message, category, filename, lineno, file, line)
                elif issubclass(category, _FRAME_WARNINGS):  # a call's other warnings are not the frame's
                    caught.append(str(message))

            warnings.showwarning = show
            for category in _FRAME_WARNINGS:
                warnings.simplefilter("always", category)
            yield self

    def call(self, fn: Callable, *args) -> tuple[Any, list[str]]:
        """``fn(*args)`` and the technique warnings it raised (in this thread)."""
        self.local.caught = []
        try:
            out = fn(*args)
        finally:
            caught, self.local.caught = self.local.caught, None
        return out, caught


def _run_whole(tech, buffers, material, camera, recorder: _CallWarnings) -> tuple[Any, list[str]]:
    """One frame, as a single call of the technique runs it; its own warnings are the frame's. The result is the
    call's array, perhaps still computing (JAX dispatches asynchronously): ``np.asarray`` waits for it."""
    return recorder.call(tech, buffers, material, camera)


_TRACES = [0]


@eqx.filter_jit
def _run_group(tech, material, buffers: Buffers, camera: Camera, seeds):
    _TRACES[0] += 1  # runs once per trace: one per (technique, shape, buffers present)

    def one(b, c, seed):
        t = tech if seeds is None else _with_seed(tech, seed)
        return t(b, material, c)

    return jax.vmap(one)(buffers, camera, seeds)


def _run_pieces(plan: _FramePlan, buffers: Buffers, material, camera: Camera, on_call, **place) -> np.ndarray:
    """One buffer (the frame or a tile) as the plan's pieces: each a call, weighted and summed; ``on_call`` after
    each (progress; a signal lands between calls). The frame's warnings were computed on the whole frame."""
    pieces = ((plan.tech, 1.0),) if plan.pieces is None else plan.pieces
    total = None
    with warnings.catch_warnings():
        for category in _TECHNIQUE_WARNINGS:
            warnings.simplefilter("ignore", category)
        for tech, weight in pieces:
            res = np.asarray(tech(buffers, material, camera, **place))
            if len(pieces) == 1:
                total = res
            else:  # float64 sums: the pieces' rounding stays below the result's
                total = res.astype(np.float64) * weight if total is None else total + res.astype(np.float64) * weight
            on_call()
    return np.asarray(total, dtype=res.dtype)


def _takes_keep(tech) -> bool:
    """Whether the technique's call takes ``keep`` (the pixels a tile keeps: only they are computed)."""
    return "keep" in inspect.signature(type(tech).__call__).parameters


def _run_tiled(tech, frame: Frame, use_albedo: bool, material, camera: Camera, plan: _FramePlan, on_tile) -> np.ndarray:
    """The frame in tiles overlapping by the technique's reach; each tile says where it lies in the frame
    (``origin``, ``frame_shape``), so the rotation hash and the frame border are the frame's; a technique whose call
    takes ``keep`` (Burley, the reference, HDRP, EEVEE Next) is told the pixels the tile keeps and computes only those
    (its halo read, not computed: a 3840x2160 close-up through HDRP in 18 tiles 16.9 s, where 112 tiles computing
    their halos took 135.9 s). ``on_tile`` after each call (a tile runs as the plan's pieces)."""
    ty, tx = plan.layout
    h, w = frame.shape
    r = plan.overlap
    out = np.empty((h, w, 3), np.float32)
    count = _material_count(material)
    keeps = _takes_keep(tech)
    for y, x in [(y, x) for y in _starts(h, ty) for x in _starts(w, tx)]:
        b, (oy, ox) = _tile(frame, y, x, ty, tx, r, use_albedo)
        validate_buffers(b, materials=count)
        keep = {"keep": (y - oy, x - ox, ty, tx)} if keeps else {}
        res = _run_pieces(dataclasses.replace(plan, tech=tech), b, material, camera, on_tile, origin=(oy, ox),
                          frame_shape=(h, w), **keep)
        out[y:y + ty, x:x + tx] = res[y - oy:y - oy + ty, x - ox:x - ox + tx]
    return out


class _CallbackRaised(Exception):
    """What a caller's callback raised, carried past the handlers that fail one frame for an ``OSError`` or a
    ``ValueError`` (the callback's error is not the frame's) to ``process_frames``, which raises the original."""

    def __init__(self, name: str, original: Exception):
        super().__init__(name, original)
        self.name, self.original = name, original


def _call_back(name: str, fn: Callable, *args) -> None:
    """A caller's callback (``on_frame_done``, ``on_progress``): whatever it raises stops the batch (see
    ``process_frames``), never fails a frame in its place."""
    try:
        fn(*args)
    except Exception as exc:  # re-raised as it was by process_frames
        raise _CallbackRaised(name, exc) from exc


class _FrameProgress:
    """Progress inside a frame that runs in several calls (tiles, pieces): a tqdm bar under the batch's, or lines
    for ``on_progress`` (at most one every ``PROGRESS_EVERY_S``, the time left from the calls so far)."""

    def __init__(self, name: str, plan: _FramePlan, bar, on_progress):
        self.name, self.total, self.printer = name, plan.calls, on_progress
        self.done, self.t0 = 0, time.perf_counter()
        self.last, self.first = self.t0, None
        self.bar = None
        if bar is not None and on_progress is None and self.total > 1:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=self.total, unit="call", desc=name, leave=False)
        if self.printer is not None and self.total > 1:
            _call_back("on_progress", self.printer,
                       f"{name}: {self.total} calls ({plan.tiles} tile(s) x {self.total // plan.tiles} piece(s)), "
                       f"about {_seconds_text(plan.estimate_s)} by the estimate")

    def tick(self) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.update(1)
        now = time.perf_counter()
        if self.first is None:
            self.first = now  # the first call compiles: the rate comes from the calls after it, once there are some
        if self.printer is not None and self.total > 1 and (now - self.last >= PROGRESS_EVERY_S
                                                            or self.done == self.total):
            elapsed = now - self.t0
            per_call = (now - self.first) / (self.done - 1) if self.done > 1 else elapsed
            left = per_call * (self.total - self.done)
            _call_back("on_progress", self.printer,
                       f"{self.name}: {self.done} of {self.total} calls ({100 * self.done // self.total}%), "
                       f"{_seconds_text(elapsed)}, about {_seconds_text(left)} left")
            self.last = now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ------------------------------------------------------------------------------------------------------------------
# warnings reach the user: once per batch where they repeat
# ------------------------------------------------------------------------------------------------------------------


class _Warnings:
    def __init__(self, bar):
        self.seen: dict[str, int] = {}
        self.bar = bar

    def frame(self, src: pathlib.Path, messages: list[str]) -> None:
        for m in messages:
            n = self.seen.get(m, 0)
            self.seen[m] = n + 1
            if n == 0:
                warnings.warn(f"{src}: {m}", _category(m), stacklevel=3)

    def summary(self) -> None:
        for m, n in self.seen.items():
            if n > 1:
                text = f"the same warning for {n - 1} more frame(s): {m}"
                if self.bar is not None:
                    self.bar.write(text)
                else:
                    print(f"sss_jax: {text}", file=sys.stderr)


def _category(message: str) -> type[Warning]:
    if message.startswith("reference:"):
        return ReferenceWindowWarning
    if "clamped to" in message:
        return UserWarning
    if "beyond half's range" in message:
        return HalfRangeWarning
    return SamplingWarning


# ------------------------------------------------------------------------------------------------------------------
# the batch
# ------------------------------------------------------------------------------------------------------------------


def _camera(frame: Frame) -> Camera:
    """The frame's camera: one ``Camera`` per (focal length, unit) and precision, shared by the frames of a sequence
    (immutable; building one is device work: two conversions and two reads back)."""
    return _camera_for(frame.focal_px, frame.scene_unit_mm, frame.principal_point,
                       jax.dtypes.canonicalize_dtype(jnp.float64))


@functools.lru_cache(maxsize=64)
def _camera_for(focal_px, mm_per_unit, principal_point, widest) -> Camera:
    """``Frame.camera``, kept. ``widest``: the widest float JAX makes now (float64 with x64 on): a Camera's
    precision follows it."""
    return Camera(focal_px, mm_per_unit, principal_point)


@dataclasses.dataclass
class _Computing:
    """A frame computing in a compute thread: what its write needs, and the future of its image."""

    job: _Job
    plan: _FramePlan
    camera: Camera
    shape: tuple[int, int]
    read_s: float
    future: concurrent.futures.Future


class _Batch:
    """One run's state: the technique and material, the records, the manifest, the results, the progress."""

    def __init__(self, tech, material, *, parameters, header, png, half, existing, book, signals, bar, on_frame_done,
                 devices, on_progress=None):
        self.tech, self.material, self.parameters, self.header = tech, material, parameters, header
        self.png, self.half, self.existing, self.book, self.signals = png, half, existing, book, signals
        self.bar, self.on_frame_done, self.devices = bar, on_frame_done, devices
        self.on_progress = on_progress
        self.results: list[FrameResult] = []
        self.warned = _Warnings(bar)
        self.cost = _Cost()
        self.pending: dict[tuple, list[dict]] = {}
        self.reader: concurrent.futures.ThreadPoolExecutor | None = None  # decodes the next frame's input
        self.writer: concurrent.futures.ThreadPoolExecutor | None = None  # writes the last frame's files
        self.ahead: tuple[_Job, concurrent.futures.Future] | None = None
        # the frame whose files the writer writes: its job, result, resume record's digest and the write
        self.in_flight: tuple[_Job, FrameResult, str, concurrent.futures.Future] | None = None
        self.computer: concurrent.futures.ThreadPoolExecutor | None = None  # small frames, COMPUTE_THREADS at once
        self.computing: collections.deque[_Computing] = collections.deque()  # in the frames' order
        self.call_warnings = _CallWarnings()
        self.records: dict[_Job, tuple[dict[str, str], str]] = {}
        # each frame's windows and header from its read to its write (the output lies where the input does, an
        # overscan margin kept, and keeps its colour primaries and camera)
        self.framing: dict[_Job, tuple[Window | None, Mapping[str, Any]]] = {}
        self.read_said: dict[_Job, list[str]] = {}  # what reading each frame warned, for its result
        self.seeded = _has_seed(tech)
        self.tiles_allowed = True
        self.base_seed = int(np.asarray(tech.seed)) if self.seeded else 0
        if len(devices) > 1:
            mesh = jax.sharding.Mesh(np.asarray(devices), ("frames",))
            self.sharded = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("frames"))

    # -- records
    def seed_of(self, job: _Job) -> int | None:
        return frame_seed(self.base_seed, job.number) if self.seeded else None

    def record(self, job: _Job, tech=None) -> tuple[dict[str, str], str]:
        """The job's resume record, computed when the run first looks at the frame (resume's decision, one frame
        ahead of its read) and kept until its files are handed to the writer or the frame fails or is skipped
        (``forget``): the input is stamped before it is read, so an input rewritten meanwhile (a re-render) does
        not pass for the one the output was made from, however many frames compute or wait in between."""
        if job not in self.records:
            params = dict(self.parameters)
            if self.seeded:
                params["frame_seed"] = self.seed_of(job)
            self.records[job] = _resume_record(job.src, params)
        return self.records[job]

    def forget(self, job: _Job) -> str | None:
        """The job's record dropped: the frame is written, failed or skipped. Returns the record's digest (None where
        the run had not computed it), which the frame's manifest entry keeps (``_Manifest.record``)."""
        known = self.records.pop(job, None)
        self.framing.pop(job, None)
        self.read_said.pop(job, None)
        return None if known is None else known[1]

    # -- results
    def finish(self, r: FrameResult, digest: str | None = None) -> None:
        self.settle()  # the frames computing and the frame in flight first: results and manifest in the frames' order
        self.collect()
        self.append(r, digest)

    def append(self, r: FrameResult, digest: str | None = None) -> None:
        """A frame's result recorded (the frames before it are)."""
        with self.signals.critical():  # a skipped or failed frame's entry too: the manifest never lags the results
            self.record_result(r, digest)
        self.report(r)

    def record_result(self, r: FrameResult, digest: str | None = None) -> None:
        """(Inside a critical section.) The result in the run's results and the manifest (``digest``: the frame's
        resume record's, ``_Manifest.record``)."""
        self.results.append(r)
        self.book.record(r, digest)

    def report(self, r: FrameResult) -> None:
        if len(self.results) % 64 == 0:
            _release_free_memory()
        if self.bar is not None:
            self.bar.update(1)
            if r.status == "failed":
                self.bar.write(r.failure_line())
        if self.on_frame_done is not None:
            _call_back("on_frame_done", self.on_frame_done, r)

    def fail(self, job: _Job, exc: BaseException, path: pathlib.Path | None = None) -> None:
        self.finish(self.failure(job, exc, path), self.forget(job))

    @staticmethod
    def failure(job: _Job, exc: BaseException, path: pathlib.Path | None = None) -> FrameResult:
        return FrameResult(str(job.src), str(job.dst), "failed", _describe(exc, path or job.src))

    def write(self, job: _Job, image: np.ndarray, camera: Camera, tech, seconds: float, notes: list[str],
              warned: list[str]) -> None:
        """The frame's files, handed to the writer thread (it writes them while the next frame computes); the
        frame before it is collected first (its files written, its result recorded), so one frame at most is in
        flight and the results and the manifest keep the frames' order."""
        preview = job.dst.with_suffix(".png")
        if not self.png and preview.exists():  # not removed (it may be the user's), but never paired in silence
            warned = [*warned, f"{preview}: a preview of an earlier output, not of this one (png=True, --png, "
                               "replaces it)"]
        self.warned.frame(job.src, warned)  # the notes (the clamp) were said before the frame ran
        read = self.read_said.pop(job, [])  # and so were the reader's (no pixel to scatter, ...): in its warnings
        options = _technique_options(tech)
        rules = {k: v for k, v in options.items() if k != "technique"}
        attrs = {**self.header, **self.record(job)[0], "sss_jax:technique": options["technique"],
                 "sss_jax:focal_px": float(camera.focal_px), "sss_jax:mm_per_unit": float(camera.mm_per_unit),
                 "sss_jax:rules": json.dumps(rules, sort_keys=True)}
        for name in ("samples", "taps", "radius_px"):
            if isinstance(rules.get(name), int):
                attrs[f"sss_jax:{name}"] = int(rules[name])
        if self.seeded:
            attrs["sss_jax:seed"] = str(self.seed_of(job))  # a uint32: past a header int
        framing = self.framing.get(job, (None, {}))
        self.forget(job)
        done = FrameResult(str(job.src), str(job.dst), "done", "; ".join(notes + warned), seconds=seconds,
                           warnings=read + notes + warned)
        self.collect()
        if self.writer is None:
            self.writer = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sss_jax-write")
        self.in_flight = (job, done, attrs["sss_jax:record"],
                          self.writer.submit(self.write_files, job, image, attrs, job.dst in self.existing, *framing))

    def write_files(self, job: _Job, image: np.ndarray, attrs: dict, overwrite: bool, window: Window | None = None,
                    like: Mapping[str, Any] | None = None) -> tuple[tuple | None, list[str]]:
        """(In the writer thread.) ``_write_files`` and what it warned (a half output's clamp): the frame's."""
        return self.call_warnings.call(self._write_files, job, image, attrs, overwrite, window, like)

    def _write_files(self, job: _Job, image: np.ndarray, attrs: dict, overwrite: bool, window: Window | None = None,
                     like: Mapping[str, Any] | None = None):
        """The frame's files, atomically: the PNG preview first, then the EXR (an EXR with its resume record means
        the frame is complete). Returns None, or ``(error, file)`` of a failed write (a fresh preview of a frame
        that has no EXR removed)."""
        preview = job.dst.with_suffix(".png")
        fresh_png = self.png and not preview.exists()
        current = preview if self.png else job.dst
        placed = None
        try:
            if self.png:
                # a preview that was not there is placed only if it still is not (another run may place its own
                # meanwhile, as it may the EXR): one there already is this frame's to replace
                write_png_preview(preview, image, overwrite=overwrite or not fresh_png,
                                  attributes={"sss_jax:input": attrs.get("sss_jax:input", str(job.src))})
                placed = preview.stat().st_ino
            current = job.dst
            write_exr(job.dst, image, channel_names=["R", "G", "B"], half=self.half, attributes=attrs,
                      overwrite=overwrite, window=window, like=like)
        except (OSError, ValueError) as exc:
            if current == job.dst and fresh_png:  # no preview of a frame that has no output: this run's own only
                with contextlib.suppress(OSError):
                    if preview.stat().st_ino == placed:
                        preview.unlink()
            return exc, current
        return None

    def collect(self) -> None:
        """The frame in flight: wait for its files, record its result (a failed write names the file and fails
        the frame; the batch goes on). A signal waits until the files and their manifest entry are written."""
        if self.in_flight is None:
            return
        with self.signals.critical():  # the files and their manifest entry together, or neither
            job, r, digest, future = self.in_flight
            failed, said = future.result()
            self.in_flight = None
            if failed is not None:
                r = self.failure(job, *failed)
            elif said:  # the writer's warnings are the frame's too (before: printed, not in its result or entry)
                self.warned.frame(job.src, said)
                r = dataclasses.replace(r, message="; ".join(filter(None, [r.message, *said])),
                                        warnings=[*r.warnings, *said])
            self.record_result(r, digest)
        self.report(r)

    def close(self) -> None:
        """The frame in flight collected and the threads ended (also when the run is interrupted: what is on disk
        is in the manifest; frames still computing then write nothing, as the frame a signal stops in the main
        thread does)."""
        try:
            self.collect()
        finally:
            for pool in (self.computer, self.reader, self.writer):
                if pool is not None:
                    pool.shutdown(wait=True, cancel_futures=True)

    # -- computing
    def prefetch(self, job: _Job, read_options: dict, use_albedo: bool) -> None:
        """Read the job's frame in the reader thread while the current frame computes (one frame ahead)."""
        if self.reader is None:
            self.reader = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="sss_jax-read")
        self.ahead = (job, self.reader.submit(self.decode, job, read_options, use_albedo))

    def decode(self, job: _Job, read_options: dict, use_albedo: bool):
        """(In the reader thread, or inline.) The frame, its buffers and camera, checked, or the error of a bad
        frame; and the warnings reading it raised, for the main thread to say."""
        said: list[tuple[str, type[Warning]]] = []
        try:
            frame = _frame_from_decoded(job.src, _read_image(job.src), **read_options,
                                        warn=lambda message, category: said.append((message, category)))
            if frame.focal_px is None:
                raise no_focal_length(job.src)
            # checked on the host, then put on the device: JAX's CPU backend runs one computation after another, and
            # a frame put there is readable only once the frames computing before it are done (the check read it)
            host, materials = frame.host_planes(use_albedo=use_albedo), _material_count(self.material)
            validate_planes(host.irradiance, albedo=host.albedo, normal=host.normal, thickness=host.thickness,
                            material_id=host.material_id, materials=materials)
            buffers = host.to_buffers()
            remember_validated(buffers, materials=materials)
        except Exception as exc:  # noqa: BLE001 - a frame that cannot be read fails alone; the batch goes on
            return None, exc, said
        return (frame, buffers, _camera(frame)), None, said

    def read(self, job: _Job, read_options: dict, use_albedo: bool):
        ahead, self.ahead = self.ahead, None
        if ahead is not None and ahead[0] == job:
            read, error, said = ahead[1].result()
        else:
            read, error, said = self.decode(job, read_options, use_albedo)
        for message, category in said:
            warnings.warn(message, category, stacklevel=4)
        if error is None:  # what reading the frame said is the frame's too (its result, the manifest)
            self.read_said[job] = [message for message, _ in said]
        if error is not None:
            raise error
        return read

    def run(self, job: _Job, read_options: dict, use_albedo: bool, tile_pixels: int,
            following: _Job | None = None) -> None:
        """One frame: read (decoded ahead, while the frame before computed), planned, computed, handed to the
        writer; ``following``, the frame that runs next, is decoded meanwhile."""
        t0 = time.perf_counter()
        try:
            frame, buffers, camera = self.read(job, read_options, use_albedo)
        except Exception as exc:  # noqa: BLE001 - any error reading a frame fails that frame; the batch goes on
            self.fail(job, exc)
            return
        try:
            self.framing[job] = (frame.window, frame.metadata)
            if following is not None and frame.shape[0] * frame.shape[1] <= tile_pixels:
                # a sequence of frames that fit one call: the next one read meanwhile (larger frames, in tiles,
                # gain nothing from it and would hold two frames in memory)
                self.prefetch(following, read_options, use_albedo)
            tech = self.tech if not self.seeded else _with_seed(self.tech, self.seed_of(job))
            plan = _plan_frame(tech, buffers, self.material, camera, tile_pixels, self.cost, self.tiles_allowed)
            self.warned.frame(job.src, plan.notes)  # the clamp, what runs and its estimate: before it runs
            if plan.calls == 1 and len(self.devices) > 1 and plan.tech.traces_camera(self.material):
                # several devices: frames grouped and vmapped; checks on the host before tracing
                warned = [str(w) for w in plan.tech.check(buffers, self.material, camera)]
                self.queue(job, buffers, camera, plan, warned, time.perf_counter() - t0)
                return
            if plan.calls == 1 and self.overlaps(plan, frame.shape):
                self.start(job, plan, buffers, camera, frame.shape, time.perf_counter() - t0)
                return
            self.settle()  # alone: the frames computing are written first (their order), no compile beside them
            if plan.calls == 1:
                image, warned = _run_whole(plan.tech, buffers, self.material, camera, self.call_warnings)
            else:
                warned = [str(w) for w in plan.tech.check(buffers, self.material, camera)]
                try:
                    image = self.in_calls(job, frame, buffers, camera, plan, use_albedo)
                except TilePlacementError:  # this technique cannot place a tile: its frames run whole (or in pieces)
                    self.tiles_allowed = False
                    plan = _plan_frame(tech, buffers, self.material, camera, tile_pixels, self.cost, False)
                    image = self.in_calls(job, frame, buffers, camera, plan, use_albedo)
        except (OSError, ValueError) as exc:
            self.fail(job, exc)
            return
        # the frame before is recorded (its files waited for, its manifest entry, the callbacks) while this one
        # computes; its time is not this frame's
        t1 = time.perf_counter()
        self.collect()
        t0 += time.perf_counter() - t1
        try:
            image = np.asarray(image)
        except (OSError, ValueError) as exc:
            self.fail(job, exc)
            return
        self.computed(job, plan, camera, frame.shape, image, warned, time.perf_counter() - t0)

    def computed(self, job: _Job, plan: _FramePlan, camera: Camera, shape: tuple[int, int], image: np.ndarray,
                 warned: list[str], seconds: float) -> None:
        """A computed frame: its seconds taught to the work estimate, its files handed to the writer."""
        self.cost.measured(plan.tech, shape[0] * shape[1] * plan.share, seconds, shape=shape, calls=plan.calls)
        self.write(job, image, camera, plan.tech, seconds, plan.notes, warned)

    def overlaps(self, plan: _FramePlan, shape: tuple[int, int]) -> bool:
        """Whether this one-call frame computes beside others (``OVERLAP_PIXELS``): small, and its shape, counts
        and calls have run (compiled) already."""
        return (COMPUTE_THREADS > 1 and shape[0] * shape[1] <= OVERLAP_PIXELS
                and self.cost.has_run(plan.tech, shape, plan.calls))

    def start(self, job: _Job, plan: _FramePlan, buffers: Buffers, camera: Camera, shape: tuple[int, int],
              read_s: float) -> None:
        """The frame computed in a compute thread; the oldest computing frames settled while more than
        ``COMPUTE_THREADS - 1`` wait (so at most that many compute beside the next frame's reading and planning)."""
        if self.computer is None:
            self.computer = concurrent.futures.ThreadPoolExecutor(COMPUTE_THREADS, thread_name_prefix="sss_jax-compute")
        future = self.computer.submit(self.compute, plan.tech, buffers, camera)
        self.computing.append(_Computing(job, plan, camera, shape, read_s, future))
        self.settle(keep=COMPUTE_THREADS - 1)

    def compute(self, tech, buffers: Buffers, camera: Camera) -> tuple[np.ndarray, list[str], float]:
        """(In a compute thread.) The frame's image, its technique warnings and the call's seconds."""
        t0 = time.perf_counter()
        image, warned = _run_whole(tech, buffers, self.material, camera, self.call_warnings)
        image = np.asarray(image)
        return image, warned, time.perf_counter() - t0

    def settle(self, keep: int = 0) -> None:
        """The oldest frames computing in the compute threads, until ``keep`` are left: each waited for and handed
        to the writer (its results in the frames' order), or failed."""
        while len(self.computing) > keep:
            c = self.computing.popleft()
            try:
                image, warned, seconds = c.future.result()
            except (OSError, ValueError) as exc:
                digest = self.forget(c.job)
                self.collect()
                self.append(self.failure(c.job, exc), digest)
                continue
            self.computed(c.job, c.plan, c.camera, c.shape, image, warned, c.read_s + seconds)

    def in_calls(self, job, frame, buffers, camera, plan, use_albedo) -> np.ndarray:
        """The frame as the plan's calls (tiles, each as the plan's pieces), with progress."""
        h, w = frame.shape
        progress = _FrameProgress(f"{job.src.name} ({w}x{h})", plan, self.bar, self.on_progress)
        try:
            if plan.layout is None:
                return _run_pieces(plan, buffers, self.material, camera, progress.tick)
            return _run_tiled(plan.tech, frame, use_albedo, self.material, camera, plan, progress.tick)
        finally:
            progress.close()

    def queue(self, job, buffers, camera, plan, warned, read_s) -> None:
        present = tuple(getattr(buffers, n) is not None for n in ("albedo", "normal", "thickness", "material_id"))
        key = (buffers.depth.shape, present, camera.principal_point, _technique_options(plan.tech).get("samples"),
               _technique_options(plan.tech).get("taps"), _technique_options(plan.tech).get("radius_px"))
        self.pending.setdefault(key, []).append(dict(job=job, buffers=buffers, camera=camera, plan=plan,
                                                     warned=warned, read_s=read_s))
        if len(self.pending[key]) == len(self.devices):
            self.flush(key)

    def flush(self, key) -> None:
        items = self.pending.pop(key)
        n = len(self.devices)
        padded = items + [items[-1]] * (n - len(items))  # the last group repeats a frame to fill every device
        stack = lambda *xs: jnp.stack(xs)
        buffers = jax.device_put(jax.tree.map(stack, *[it["buffers"] for it in padded]), self.sharded)
        cameras = jax.device_put(jax.tree.map(stack, *[it["camera"] for it in padded]), self.sharded)
        seeds = None
        tech = items[0]["plan"].tech
        if self.seeded:  # one program for the group, the frames' seeds traced
            seeds = jax.device_put(jnp.asarray([self.seed_of(it["job"]) for it in padded], jnp.uint32), self.sharded)
            tech = _with_seed(tech, 0)
        t0 = time.perf_counter()
        try:
            out = np.asarray(_run_group(tech, self.material, buffers, cameras, seeds))
        except Exception as exc:  # noqa: BLE001 - a failed group fails its frames, not the batch
            for it in items:
                self.fail(it["job"], exc)
            return
        dt = (time.perf_counter() - t0) / len(items)
        for k, it in enumerate(items):
            self.write(it["job"], out[k], it["camera"], it["plan"].tech, dt + it["read_s"], it["plan"].notes,
                       it["warned"])

    def flush_all(self) -> None:
        for key in list(self.pending):
            self.flush(key)


def process_frames(
    inputs: str | pathlib.Path | Iterable[str | pathlib.Path],
    technique,
    material,
    *,
    out_dir: str | pathlib.Path | None = None,
    outputs: Sequence[str | pathlib.Path] | None = None,
    png: bool = False,
    focal_px: Real | None = None,
    mm_per_unit: Real | None = None,
    channel_map=None,
    depth_kind: str = "planar",
    use_albedo_pass: bool = True,
    sta_albedo=None,
    sta_thickness: float | None = None,
    samples: int | None = None,
    taps: int | None = None,
    radius_px: int | None = None,
    technique_options: dict[str, Any] | None = None,
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
    on_progress: Callable[[str], None] | None = None,
) -> BatchResult:
    """Apply ``technique`` to every frame and write ``out_dir/<input path relative to the inputs' common folder>``
    with the ``.exr`` extension (or the given ``outputs``, one per input, each ending in ``.exr``), with an sRGB PNG
    preview beside each when ``png``.

    ``technique``: a technique object (its options are its fields) or a registered name with its options
    (``samples`` for burley, ``taps`` for separable, ``radius_px`` for reference (required: one window for the
    sequence), ``sta_albedo (3,)`` in [0, 1] and ``sta_thickness`` >= 0 scene units for sta, any other option of the
    technique in ``technique_options``, e.g. ``{"pattern": "fixed", "border": "renormalise", "seed": 7}``; a count
    the technique does not have, ``taps`` for burley, is said with a warning and not used; an unknown
    ``technique_options`` key is an error).
    ``material``: a preset name or file (see ``_presets``), the technique's material (rows per material id), or
    ``(STAParams, DirectionalLight)`` for ``"sta"``. A technique with a ``seed`` gets, per frame, the seed mixed with
    the frame number (the last digits of the file name; ``frame_seed``): each frame its own rotation, reproducibly.

    - ``resume``: skip a frame whose output records the same input (path, size, mtime), technique, options and seed,
      parameters and sss_jax version, and whose files all decode (the EXR and, with ``png``, the preview); every
      other frame is computed.
    - ``overwrite``: allow replacing an existing output that was not made from the same input (refused otherwise,
      before any frame runs).
    - ``manifest``: ``True`` writes ``out_dir/sss_jax_manifest.json`` (``sss_jax_manifest.<process index>.json``
      when several processes share the batch; none with ``outputs``), a path writes there, ``None``/``False`` none.
      Runs into one folder merge their entries frame by frame under a lock on the folder.
    - ``tile_pixels``: the most pixels (overlap included) one call of the technique sees; larger frames (or frames
      whose work would keep one call busy for more than about a second) run in tiles overlapping by the technique's
      reach, each told its origin in the frame and the frame's shape: the untiled frame's pixels. A call still past
      the work bound runs as the technique's pieces (``AbstractTechnique.pieces``), so a signal lands within seconds.
    - ``on_progress``: called with a line of text as a frame that runs in several calls progresses (the calls done,
      the time so far and left), at most every two seconds; without it, ``progress`` shows a bar per frame.
    - ``on_frame_done``: called with each frame's ``FrameResult`` once it is recorded, in the frames' order.
      Whatever a callback raises stops the batch and reaches the caller as it was raised (a note names the callback
      and the frames finished); it never fails a frame in its place. The frames recorded stay on disk and in the
      manifest (state ``stopped``: a signal's is ``interrupted``), so a rerun with ``resume`` goes on from there.

    Every file is written atomically (a temporary beside it, fsync, verified: the EXR from its chunk table, the PNG
    decoded; renamed); temporaries that killed runs left beside this run's outputs are removed first. Counts beyond
    what the frame's footprint can use are clamped, with the count run and a work estimate; the technique's sampling
    and window warnings are computed for every frame, warned about once per batch, and recorded per frame (message,
    manifest).

    Returns a per-frame status list; raises (``SSSInputError``/``ValueError``/``TypeError``, nothing written) only
    where the whole batch is impossible, and ``Interrupted`` (a ``KeyboardInterrupt``) on SIGINT/SIGTERM after
    recording the finished frames in the manifest.
    """
    for name, flag in (("png", png), ("half", half), ("resume", resume), ("overwrite", overwrite),
                       ("progress", progress)):
        if not isinstance(flag, (bool, np.bool_)):  # png="no" is truthy
            raise TypeError(f"{name} must be True or False, got {flag!r}")
    if is_bool(sta_thickness):  # True read as 1 scene unit (its range is the technique's check)
        raise TypeError(f"sta_thickness must be a number (scene units), not a bool, got {sta_thickness!r}")
    named = {k: v for k, v in dict(samples=samples, taps=taps, radius_px=radius_px, albedo=sta_albedo,
                                    thickness=sta_thickness).items() if v is not None}
    tech, material = _technique_object(technique, dict(technique_options or {}), material, named)
    focal_px, mm_per_unit = (_positive_option(name, value) for name, value in (("focal_px", focal_px),
                                                                             ("mm_per_unit", mm_per_unit)))
    check_host_count(tile_pixels, "tile_pixels")
    # the reading options, the same for every frame: checked once, before any frame (each frame failed alone)
    check_depth_kind(depth_kind)
    if channel_map is not None:
        load_channel_map(channel_map)
    if out_dir is not None and not str(out_dir).strip():
        raise ValueError("out_dir is empty: give the outputs' folder ('.' for the current one)")
    call_seconds()  # the work bound from the environment, checked before any frame
    if devices is not None:
        devices = list(devices)
        if not devices or not all(isinstance(d, jax.Device) for d in devices):
            raise ValueError(f"devices must be jax devices (at least one; None: every device), got {devices!r}")

    paths = expand_inputs(inputs)
    targets = _targets(paths, None if out_dir is None else pathlib.Path(out_dir), outputs)
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    if manifest is True:
        manifest = None if out_dir is None else pathlib.Path(out_dir) / (
            MANIFEST_NAME if pc == 1 else MANIFEST_NAME.replace(".json", f".{pi}.json"))
    manifest = pathlib.Path(manifest) if manifest not in (None, False) else None
    all_jobs = [_Job(src, dst, frame_number(src, i)) for i, (src, dst) in enumerate(zip(paths, targets))]
    _check_plan([(j.src, j.dst) for j in all_jobs], png, manifest)
    jobs = frames_for_process(all_jobs, pi, pc)
    existing = _existing_outputs(jobs, overwrite, png)
    _check_folders([j.dst for j in jobs] + ([manifest] if manifest is not None else []), out_dir is not None)
    remove_stale_temporaries([p for j in jobs for p in j.files(png)] + ([manifest] if manifest is not None else []))

    from ._version import __version__

    parameters = {**_technique_options(tech), "material": _material_record(material), "half": bool(half),
                  "focal_px": focal_px, "mm_per_unit": mm_per_unit, "depth_kind": depth_kind,
                  "use_albedo_pass": bool(use_albedo_pass), "png": bool(png),
                  "channel_map": _channel_map_record(channel_map)}
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), unit="frame", desc=f"sss-jax {parameters['technique']}")
    book = _Manifest(manifest, {"sss_jax_version": __version__, "technique": parameters["technique"],
                                "parameters": parameters, "process_index": pi, "process_count": pc}, jobs)
    signals = _Signals()
    run = _Batch(tech, material, parameters=parameters, header=_material_attributes(material), png=png, half=half,
                 existing=existing, book=book, signals=signals, bar=bar, on_frame_done=on_frame_done,
                 devices=list(jax.devices() if devices is None else devices), on_progress=on_progress)
    read_options = dict(channel_map=channel_map, focal_px=focal_px, mm_per_unit=mm_per_unit, depth_kind=depth_kind)
    traces = _TRACES[0]
    state = "interrupted"
    decided: dict[int, bool] = {}

    def skipped(k: int) -> bool:
        if k not in decided:
            job = jobs[k]
            digest = run.record(job)[1]  # also without resume: the record stamps the input before it is read
            decided[k] = resume and _is_complete(job, png, existing.get(job.dst), digest)
        return decided[k]

    try:
        with signals, run.call_warnings.installed():
            try:
                for k, job in enumerate(jobs):
                    if skipped(k):
                        run.forget(job)
                        run.finish(FrameResult(str(job.src), str(job.dst), "skipped", "complete output of the same "
                                               "input and parameters"))
                        continue
                    following = jobs[k + 1] if k + 1 < len(jobs) and not skipped(k + 1) else None
                    run.run(job, read_options, use_albedo_pass, int(tile_pixels), following)
                run.settle()
                run.flush_all()
            finally:
                run.close()  # the last frame's files and entry (also when interrupted: the manifest is the disk)
        state = "complete"
    except _CallbackRaised as raised:  # the caller's own error, as it raised it, with what the batch did
        state = "stopped"  # by the caller's code, not by a signal or an error of the batch
        exc = raised.original
        where = f"; {manifest} lists the frames finished" if manifest is not None else ""
        if hasattr(exc, "add_note"):  # Python >= 3.11
            exc.add_note(f"raised by process_frames' {raised.name} callback: the batch stopped after "
                         f"{len(run.results)} frame(s){where}")
        raise exc from None
    finally:
        with contextlib.suppress(OSError, ValueError):
            book.close(state)
        if bar is not None:
            bar.close()
        run.warned.summary()
    return BatchResult(frames=run.results, compilations=_TRACES[0] - traces,
                       manifest=None if manifest is None else str(manifest))


def _positive_option(name: str, value) -> float | None:
    """A length option as a Python float (a NumPy scalar too: it goes into the resume record's JSON), or None."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real) or not 0 < value < math.inf:
        raise ValueError(f"{name} must be a positive number (finite), got {value!r}")
    return float(value)


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


def _channel_map_record(channel_map) -> Any:
    if channel_map is None or isinstance(channel_map, dict):
        return channel_map
    stamp = _file_stamp(pathlib.Path(channel_map))
    return stamp or str(channel_map)
