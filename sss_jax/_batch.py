"""Batch processing of frame sequences: streamed, sharded over ``jax.devices()``, resumable, failure tolerant.

Frames are read one at a time and grouped by (shape, buffers present); each full group of ``len(devices)`` frames is
stacked along a leading axis sharded over the devices (``NamedSharding(Mesh(devices, ("frames",)), P("frames"))``)
and processed by one jitted, vmapped call, so every frame shape compiles once and memory holds at most one group per
shape. Outputs are written atomically and named after their inputs; a frame whose output exists is skipped, so an
interrupted run resumes where it stopped. A frame that cannot be read or is invalid is reported and skipped.

Across hosts, each process calls ``jax.distributed.initialize()`` first and then processes
``frames_for_process(frames, jax.process_index(), jax.process_count())`` (docs/batch.md shows the launch).
"""

from __future__ import annotations

import dataclasses
import glob
import pathlib
import time
from typing import Any, Callable, Iterable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._io import Frame, SSSInputError, read_frame, write_exr, write_png_preview
from ._materials import BurleyMaterial, DirectionalLight, STAParams, TwoGaussianMaterial
from ._scene import Buffers, Camera, validate_buffers
from ._techniques import TECHNIQUES, burley, reference, separable, translucency

__all__ = ["BatchResult", "FrameResult", "expand_inputs", "frames_for_process", "process_frames"]


@dataclasses.dataclass
class FrameResult:
    input: str
    output: str
    status: str  # "ok", "skipped" (output already there) or "failed"
    message: str = ""
    seconds: float = 0.0


@dataclasses.dataclass
class BatchResult:
    frames: list[FrameResult]
    compilations: int

    @property
    def failed(self) -> list[FrameResult]:
        return [f for f in self.frames if f.status == "failed"]

    @property
    def ok(self) -> bool:
        return not self.failed


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


def _run_technique(technique: str, buffers: Buffers, material, camera: Camera, options: dict):
    if technique == "burley":
        return burley(buffers, material, camera, samples=options.get("samples", 32))
    if technique == "separable":
        return separable(buffers, material, camera, taps=options.get("taps", 25))
    if technique == "reference":
        return reference(buffers, material, camera, radius_px=options["radius_px"])
    params, light = material
    return translucency(buffers, params, camera, light, albedo=options.get("albedo"),
                        thickness=options.get("thickness"))


def _material_attributes(material) -> dict[str, str]:
    """The material's parameters for the EXR header: ``sss_jax:<field>`` = rows of comma-separated values."""
    parts = material if isinstance(material, tuple) else (material,)
    attrs = {}
    for part in parts:
        for field in dataclasses.fields(part):
            value = np.asarray(getattr(part, field.name))
            rows = value.reshape(-1, value.shape[-1]) if value.ndim else value.reshape(1, 1)
            attrs[f"sss_jax:{field.name}"] = ";".join(",".join(f"{v:.6g}" for v in row) for row in rows)
    return attrs


class _Group(eqx.Module):
    buffers: Buffers
    camera: Camera


def _to_arrays(frame: Frame, use_albedo: bool) -> tuple[Buffers, Camera]:
    b = frame.to_buffers(use_albedo=use_albedo)
    return b, Camera(frame.focal_px, frame.mm_per_unit if frame.mm_per_unit is not None else 1.0)


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
    skip_existing: bool = True,
    progress: bool = True,
    devices: Sequence[jax.Device] | None = None,
    process_index: int | None = None,
    process_count: int | None = None,
    on_frame_done: Callable[[FrameResult], None] | None = None,
) -> BatchResult:
    """Apply ``technique`` to every frame and write ``out_dir/<input stem>.exr`` (or the given ``outputs``, one per
    input), with an sRGB PNG preview beside each when ``png``.

    ``material``: a preset name or file (see ``_presets``), a ``BurleyMaterial`` / ``TwoGaussianMaterial`` (rows
    per material id), or ``(STAParams,
    DirectionalLight)`` for ``"sta"`` (with ``sta_albedo (3,)`` where frames carry no albedo and ``sta_thickness``
    in scene units where they carry no thickness). ``radius_px`` is required for ``"reference"`` (one window for the sequence).
    Returns a per-frame status list; raises only for arguments that make the whole batch impossible.
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
    elif not isinstance(material, (BurleyMaterial, TwoGaussianMaterial)):
        raise TypeError(f"material must be a BurleyMaterial or TwoGaussianMaterial, got {type(material).__name__}")
    if technique == "reference" and radius_px is None:
        raise ValueError("technique 'reference' in a batch needs radius_px (one window for every frame)")
    paths = expand_inputs(inputs)
    if outputs is not None:
        if len(outputs) != len(paths):
            raise ValueError(f"{len(outputs)} outputs for {len(paths)} inputs")
        targets = [pathlib.Path(o) for o in outputs]
    elif out_dir is not None:
        out_dir = pathlib.Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        targets = [out_dir / (p.stem + ".exr") for p in paths]
    else:
        raise ValueError("give out_dir or outputs")
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    jobs = frames_for_process(list(zip(paths, targets)), pi, pc)
    devices = list(jax.devices() if devices is None else devices)
    mesh = jax.sharding.Mesh(np.asarray(devices), ("frames",))
    sharded = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("frames"))
    options = dict(samples=samples, taps=taps, radius_px=radius_px, albedo=sta_albedo, thickness=sta_thickness)

    header = _material_attributes(material)
    traces = {"count": 0}

    @jax.jit
    def run_group(group: _Group):
        traces["count"] += 1  # runs once per trace: one per (shape, buffers present)
        return jax.vmap(lambda b, c: _run_technique(technique, b, material, c, options))(group.buffers, group.camera)

    results: list[FrameResult] = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), unit="frame", desc=f"sss-jax {technique}")
    pending: dict[tuple, list[tuple[pathlib.Path, pathlib.Path, Buffers, Camera, float]]] = {}

    def finish(r: FrameResult):
        results.append(r)
        if bar is not None:
            bar.update(1)
            if r.status == "failed":
                bar.write(f"FAILED {r.input}: {r.message}")
        if on_frame_done is not None:
            on_frame_done(r)

    def flush(key):
        items = pending.pop(key)
        n = len(devices)
        padded = items + [items[-1]] * (n - len(items))  # the last group repeats a frame to fill every device
        stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[_Group(b, c) for _, _, b, c, _ in padded])
        stacked = jax.device_put(stacked, sharded)
        t0 = time.perf_counter()
        try:
            out = np.asarray(run_group(stacked))
        except Exception as exc:  # noqa: BLE001 - a failed group fails its frames, not the batch
            for src, dst, _, _, _ in items:
                finish(FrameResult(str(src), str(dst), "failed", f"{type(exc).__name__}: {exc}"))
            return
        dt = (time.perf_counter() - t0) / len(items)
        for k, (src, dst, _, cam, read_s) in enumerate(items):
            try:
                attrs = {**header, "sss_jax:technique": technique, "sss_jax:input": str(src),
                         "sss_jax:focal_px": float(cam.focal_px), "sss_jax:mm_per_unit": float(cam.mm_per_unit)}
                if technique in ("burley", "separable"):
                    attrs["sss_jax:samples" if technique == "burley" else "sss_jax:taps"] = (
                        samples if technique == "burley" else taps)
                write_exr(dst, out[k], channel_names=["R", "G", "B"], half=half, attributes=attrs)
                if png:
                    write_png_preview(dst.with_suffix(".png"), out[k])
                finish(FrameResult(str(src), str(dst), "ok", seconds=dt + read_s))
            except (OSError, ValueError) as exc:
                finish(FrameResult(str(src), str(dst), "failed", str(exc)))

    try:
        for src, dst in jobs:
            if skip_existing and dst.exists():
                finish(FrameResult(str(src), str(dst), "skipped", "output exists"))
                continue
            t0 = time.perf_counter()
            try:
                frame = read_frame(src, channel_map=channel_map, focal_px=focal_px, mm_per_unit=mm_per_unit,
                                   depth_kind=depth_kind)
                if frame.focal_px is None:
                    raise SSSInputError(f"{src}: no focal length (pass focal_px or put sss_jax:focal_px in the header)")
                buffers, camera = _to_arrays(frame, use_albedo_pass)
                count = material[0].scale.shape[0] if technique == "sta" else material.count
                validate_buffers(buffers, materials=1 if technique == "sta" else count)
            except (OSError, ValueError) as exc:
                finish(FrameResult(str(src), str(dst), "failed", str(exc)))
                continue
            present = tuple(getattr(buffers, n) is not None for n in ("albedo", "normal", "thickness", "material_id"))
            key = (buffers.depth.shape, present)
            pending.setdefault(key, []).append((src, dst, buffers, camera, time.perf_counter() - t0))
            if len(pending[key]) == len(devices):
                flush(key)
        for key in list(pending):
            flush(key)
    finally:
        if bar is not None:
            bar.close()
    return BatchResult(frames=results, compilations=traces["count"])
