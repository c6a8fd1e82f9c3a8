"""Run and time every technique on the user's own EXR frames, against a cached dense reference and, optionally, an
offline render of the same view: the measuring half of ``sss-jax report`` (``sss_jax.report`` lays it out).

The dense reference is the slow part; it is computed once per frame and kept in ``cache_dir`` under a key of
everything it depends on (the input file's bytes, material, camera, window radius, reading options, package
version), so a second report on the same frame reads it back.
"""

from __future__ import annotations

import collections
import hashlib
import io
import json
import math
import os
import pathlib
import sys
import warnings
import zipfile
import zlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from ._checks import check_host_count
from ._io import (Frame, SSSInputError, Window, _blender_layers, _read_image, no_focal_length, read_frame,
                  write_bytes_atomic)
from ._machine import machine_info
from ._materials import BurleyMaterial, DirectionalLight, ProfileMaterial, STAParams, TwoGaussianMaterial
from ._report import FrameImages, ReportData, TechniqueRun
from ._techniques._base import AbstractTechnique, missing_fields
from ._cost import frame_cost
from ._sweep import changed_options
from ._timing import time_call

__all__ = ["evaluate_frames", "read_truth", "REPORT_TECHNIQUES"]

# what a report runs: the techniques and the engines' own passes (the reference is what they are measured against)
REPORT_TECHNIQUES = ("sta", "separable", "burley", "hdrp", "eevee-next", "jimenez")
_CACHE_VERSION = 1


def read_truth(path: str | os.PathLike, channels: str | Sequence[str] | None = None,
               shape: tuple[int, int] | None = None, *, frame: Frame | None = None) -> np.ndarray:
    """An offline render's RGB ``(H, W, 3)`` (linear). ``channels``: a pass name (``"Combined"``: Blender's
    ``<ViewLayer>.Combined.R/G/B``, the default for a Blender multilayer file), or three channel names (``"R,G,B"``,
    the default otherwise). ``shape``: the ``(H, W)`` it must have. ``frame``: the input frame it is compared with
    (its shape then the one the truth must have): a truth black on every SSS pixel of it is an error naming the
    file (nothing to compare with: a wrong pass or layer), negative radiance there a warning (compared as it is)."""
    if frame is not None:
        shape = frame.shape
    chans, _, _, got, window = _read_image(path)
    # the view layer, only where a pass is named by itself (three channel names, or a pass's full name, need none)
    blender = lambda: _blender_layers(list(chans), path, choose="name its channels (--truth-channels "
                                      "{layer}.Combined.R,{layer}.Combined.G,{layer}.Combined.B)")
    if channels is None:
        channels = "Combined" if "Combined.R" in blender() else "R,G,B"
    names = [c.strip() for c in channels.split(",")] if isinstance(channels, str) else list(channels)
    if len(names) == 1:
        p = names[0]
        names = ([f"{p}.{c}" for c in "RGB"] if all(f"{p}.{c}" in chans for c in "RGB")
                 else [blender().get(f"{p}.{c}") or f"{p}.{c}" for c in "RGB"])
    if len(names) != 3:
        raise SSSInputError(f"{path}: truth channels must be a pass name or three channel names, got {channels!r}")
    missing = [n for n in names if n not in chans]
    if missing:
        found = ", ".join(list(chans)[:24]) + (" ..." if len(chans) > 24 else "")
        raise SSSInputError(f"{path}: truth channel(s) {missing} not found; channels found: {found}")
    rgb = np.stack([chans[n] for n in names], axis=-1).astype(np.float32)
    if frame is not None and got != tuple(shape):
        rgb = _frame_region(path, rgb, window, frame)
    elif shape is not None and got != tuple(shape):
        raise SSSInputError(f"{path}: truth is {got[1]}x{got[0]} but the input frame is {shape[1]}x{shape[0]}")
    if not np.all(np.isfinite(rgb)):
        raise SSSInputError(f"{path}: truth has {int(np.sum(~np.isfinite(rgb)))} non-finite values")
    if frame is not None:
        _check_truth(path, rgb, frame)
    return rgb


def _frame_region(path, rgb: np.ndarray, window: Window, frame: Frame) -> np.ndarray:
    """The truth's pixels where the frame's lie on the image plane (their data windows: a truth rendered with an
    overscan margin, or a frame cut from a larger render), where both share one display window and the truth holds
    them all; else the sizes' error."""
    h, w = frame.shape
    fwin = frame.window or Window(0, 0, (0, 0, w, h))
    y0, x0 = fwin.y - window.y, fwin.x - window.x
    if window.display == fwin.display and 0 <= y0 and 0 <= x0 and y0 + h <= rgb.shape[0] and x0 + w <= rgb.shape[1]:
        return rgb[y0:y0 + h, x0:x0 + w]
    where = lambda win, hw: f"{hw[1]}x{hw[0]} at ({win.x}, {win.y}) of display window {win.display[2]}x{win.display[3]}"
    raise SSSInputError(f"{path}: truth is {rgb.shape[1]}x{rgb.shape[0]} but the input frame is {w}x{h} (truth "
                        f"{where(window, rgb.shape)}, frame {where(fwin, (h, w))}): it does not hold the frame's pixels")


def frame_sss_mask(frame: Frame) -> np.ndarray:
    """The frame's SSS pixels: material id > 0 (every pixel without ids) on a surface (finite depth)."""
    ids = frame.material_id if frame.material_id is not None else np.ones(frame.shape, np.int32)
    return (ids > 0) & np.isfinite(frame.depth)


def _check_truth(path, rgb: np.ndarray, frame: Frame) -> None:
    """A truth black on every SSS pixel is refused; negative radiance there (beyond a codec's ringing, a thousandth
    of the largest value) is said."""
    mask = frame_sss_mask(frame)
    if not mask.any():
        return
    on = rgb[mask]
    if not np.any(on > 0):
        name = pathlib.Path(frame.path).name if frame.path else "the frame"
        raise SSSInputError(f"{path}: the truth is black on every SSS pixel of {name} ({int(mask.sum())} pixels): "
                            "nothing to compare with (the right pass, layer or file?)")
    negative = on < -1e-3 * float(np.max(np.abs(on)))
    if negative.any():
        warnings.warn(f"{path}: {int(np.sum(np.any(negative, axis=-1)))} SSS pixel(s) of the truth are negative (down "
                      f"to {float(on.min()):.4g}); an offline render's radiance is >= 0: compared as they are",
                      UserWarning, stacklevel=3)


def _sha256_file(path: pathlib.Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _leaves(material) -> dict[str, Any]:
    import dataclasses

    return {f.name: np.asarray(getattr(material, f.name)).tolist() for f in dataclasses.fields(material)
            if not isinstance(getattr(material, f.name), (str, type(None)))}


def _reference_key(frame_hash: str, material, camera, radius_px: int, reading: Mapping[str, Any]) -> str:
    from importlib import metadata

    try:
        version = metadata.version("sss_jax")
    except metadata.PackageNotFoundError:  # a source tree on sys.path, not installed
        version = "source"
    blob = json.dumps({"v": _CACHE_VERSION, "sss_jax": version, "frame": frame_hash,
                       "material": {type(material).__name__: _leaves(material)},
                       "camera": [float(camera.focal_px), float(camera.mm_per_unit)], "radius_px": int(radius_px),
                       "reading": {k: str(v) for k, v in sorted(reading.items())}}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def _cached_reference(cache_dir: pathlib.Path | None, key: str, shape) -> tuple[np.ndarray, float] | None:
    if cache_dir is None:
        return None
    path = cache_dir / f"reference-{key}.npz"
    try:
        with np.load(path) as z:
            img, seconds = np.asarray(z["image"]), float(z["seconds"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error):  # missing or damaged:
        return None  # computed again (and stored over the damaged file)
    ok = img.shape == (*shape, 3) and bool(np.all(np.isfinite(img))) and math.isfinite(seconds)
    return (img, seconds) if ok else None


def _store_reference(cache_dir: pathlib.Path, key: str, image: np.ndarray, seconds: float) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, image=image.astype(np.float32), seconds=np.float64(seconds))
    cache_dir.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(cache_dir / f"reference-{key}.npz", buf.getvalue())


def _tidy(values) -> Any:
    """Parameters for people to read: float32 values as the 7 significant digits they hold."""
    a = np.asarray(values, np.float64)
    return np.vectorize(lambda v: float(f"{v:.7g}"))(a).tolist() if a.size else a.tolist()


def _counts(name: str, values: Iterable[int], odd: bool = False) -> tuple[int, ...]:
    out = tuple(values)
    if not out:
        raise ValueError(f"{name}: give at least one count")
    for v in out:
        if not isinstance(v, (int, np.integer)) or v < 1 or (odd and v % 2 == 0):
            raise ValueError(f"{name} must be {'odd ' if odd else ''}positive integers, got {v!r}")
    return out


def _material_albedo(material, ids: np.ndarray) -> np.ndarray:
    """Per-pixel albedo ``(H, W, 3)`` from a material table (id k -> row k-1; one row serves every id)."""
    table = np.asarray(material.albedo, np.float32).reshape(-1, 3)
    rows = np.clip(ids - 1, 0, table.shape[0] - 1) if table.shape[0] > 1 else np.zeros_like(ids)
    return table[rows]


def _technique_object(t: str | AbstractTechnique, context: Mapping[str, Any],
                      burley_options: Mapping[str, Any]) -> AbstractTechnique:
    """The technique object a report runs for ``t``: ``t`` itself, or the class registered under the name ``t``
    built with what the call gives that it has fields for (the STA's light, thickness, albedo; Burley's
    ``burley_options``). Errors name the technique and what is wrong."""
    import dataclasses

    from ._techniques import TECHNIQUES

    if isinstance(t, AbstractTechnique):
        return t
    if t not in REPORT_TECHNIQUES:
        raise SSSInputError(f"unknown technique(s) [{t!r}]; valid: {', '.join(REPORT_TECHNIQUES)}")
    cls = TECHNIQUES[t]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    options = {k: v for k, v in context.items() if k in fields and v is not None}
    own = {"burley": burley_options}.get(t, {})
    extra = sorted(set(own) - set(fields) | ({cls.count_option} & set(own)))
    if extra:
        valid = ", ".join(sorted(set(cls.option_fields_names()) - {cls.count_option}))
        raise ValueError(f"burley_options {extra} not accepted here; sss_jax.burley takes {valid} (samples come "
                         "from `samples`)")
    missing = [f.name for f in missing_fields(cls, options)]
    if missing:
        raise SSSInputError(f"the {t} technique needs its {' and '.join(missing)}: light=DirectionalLight(...) and "
                            "sta=STAParams(...) (on the command line --light-dir X,Y,Z)")
    return cls(**options, **own)


def _pooled_cost(per_frame: list[tuple[dict, int]]) -> dict[str, Any] | None:
    """The frames' costs per SSS pixel pooled over their SSS pixels (the rule and frames of the first)."""
    if not per_frame:
        return None
    weights = np.asarray([n for _, n in per_frame], np.float64)
    pooled = dict(per_frame[0][0])
    for key in ("samples", "fetches", "flops", "active_fraction"):
        values = np.asarray([c[key] for c, _ in per_frame], np.float64)
        pooled[key] = round(float(np.sum(values * weights) / max(weights.sum(), 1.0)), 4)
    return pooled


def evaluate_frames(
    inputs: str | os.PathLike | Iterable[str | os.PathLike],
    material: BurleyMaterial | ProfileMaterial,
    *,
    truth: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
    truth_channels: str | Sequence[str] | None = None,
    techniques: Sequence[str | AbstractTechnique] = REPORT_TECHNIQUES,
    taps: Iterable[int] = (9, 17, 25),
    samples: Iterable[int] = (8, 16, 32, 64),
    separable_material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial | None = None,
    sta: STAParams | tuple[STAParams, DirectionalLight] | None = None,
    light: DirectionalLight | None = None,
    sta_thickness: float | None = None,
    burley_options: Mapping[str, Any] | None = None,
    focal_px: float | None = None,
    mm_per_unit: float | None = None,
    channel_map: str | os.PathLike | Mapping[str, Any] | None = None,
    depth_kind: str = "planar",
    use_albedo_pass: bool = True,
    radius_px: int | None = None,
    cache_dir: str | os.PathLike | None = None,
    repeats: int = 3,
    material_info: Mapping[str, Any] | None = None,
    progress: bool = False,
) -> ReportData:
    """Render, time and collect what ``sss_jax.report`` lays out, for EXR frames read as ``sss-jax apply`` reads them.

    ``techniques``: registry names (of ``REPORT_TECHNIQUES``: the engines' passes ``hdrp``, ``eevee-next``,
    ``jimenez`` among them) or technique objects (``sj.Burley(pattern="fixed")``, ``sj.HdrpPass(quality="high")``);
    each technique whose ``count_option`` is ``"taps"`` or ``"samples"`` runs once per count of ``taps``/``samples``,
    the others once (two objects of one technique are told apart by their options in the labels). Each run records
    its cost per SSS pixel as its shader executes it (``_cost.frame_cost``: samples, texels, flops; pooled over the
    frames' SSS pixels) beside its wall time.
    ``material``: the Burley (or tabulated-profile) material table of the reference and of ``burley`` (one row per
    material id, or one row for every id > 0); ``separable_material`` (default ``material``) the separable's
    kernels; ``sta``: the ``STAParams`` of the STA (the material it takes) and ``light`` its back light, required
    when ``techniques`` holds it (``sta=(STAParams, DirectionalLight)`` is accepted too); ``sta_thickness``: its
    constant thickness in scene units where a frame has no thickness channel (else 0).
    ``truth``: one offline render per input (``truth_channels`` as in ``read_truth``). ``taps``/``samples``: the
    separable's taps and Burley's samples to run (one run per count). ``burley_options``: further keyword arguments
    of ``sss_jax.burley`` (e.g. a sampling pattern), checked against its signature. Camera: ``focal_px`` (px) and
    ``mm_per_unit`` (mm per scene unit of depth), else the EXR header or the ``<name>.json`` sidecar.
    ``radius_px``: the reference's window (default: 99.9% of the widest profile's energy, capped at 96 px).
    ``cache_dir``: where the reference is kept between runs (None: not kept). ``repeats``: timed runs per frame
    after the compiling one (0: the first run's time). Times are medians in ms per frame, averaged over frames.

    Raises ``SSSInputError`` (a ``ValueError``) naming the input and what is wrong, before any rendering.
    """
    from tqdm import tqdm

    from ._batch import expand_inputs
    from ._techniques import reference, reference_radius_px

    # ---- every check first: nothing is rendered or written for bad input
    if not isinstance(material, (BurleyMaterial, ProfileMaterial)):
        raise TypeError(f"material must be a BurleyMaterial or ProfileMaterial, got {type(material).__name__}")
    if isinstance(sta, tuple):  # the older (STAParams, DirectionalLight) pair: the light belongs to the technique
        sta, light = sta
    table = np.asarray(material.albedo, np.float32).reshape(-1, 3)
    # the STA takes one albedo where the buffers carry none: the material's when there is one material
    sta_albedo = table[0] if table.shape[0] == 1 else None
    # what a technique built from its name takes from this call, where it has such a field
    context = {"light": light, "thickness": sta_thickness, "albedo": sta_albedo}
    burley_options = dict(burley_options or {})
    if isinstance(techniques, (str, AbstractTechnique)):  # one technique, not the letters of its name
        techniques = (techniques,)
    objects = tuple(_technique_object(t, context, burley_options) for t in techniques)
    if not objects:
        raise SSSInputError(f"unknown technique(s) (none given); valid: {', '.join(REPORT_TECHNIQUES)}")
    sweeps = {"taps": (taps, True), "samples": (samples, False)}
    counts = {opt: _counts(opt, values, odd=odd) for opt, (values, odd) in sweeps.items()
              if any(t.count_option == opt for t in objects)}
    check_host_count(repeats, "repeats", lo=0)  # (True is not 1)
    if radius_px is not None:
        check_host_count(radius_px, "radius_px")
    sep_material = material if separable_material is None else separable_material
    # the material each technique takes: the separable's own kernels and the STA's parameters where given
    own = {"separable": sep_material, "sta": sta}
    materials = [own.get(t.name, material) for t in objects]
    for t, m in zip(objects, materials):
        if m is None:
            raise SSSInputError(f"the {t.name} technique needs its material (sta=STAParams(...)) and light "
                                "(light=DirectionalLight(...); on the command line --light-dir X,Y,Z)")
        t.check_material(m)
    paths = expand_inputs(inputs)
    truths = [] if truth is None else expand_inputs(truth, "truth files")
    if truths and len(truths) != len(paths):
        raise SSSInputError(f"{len(truths)} truth file(s) for {len(paths)} input frame(s): give one per input")
    if len(set(map(str, paths))) != len(paths):
        twice = sorted(p for p, n in collections.Counter(map(str, paths)).items() if n > 1)
        raise SSSInputError(f"an input frame is given twice: {', '.join(twice)}")

    frames: list[Frame] = []
    for p in paths:
        f = read_frame(p, channel_map=channel_map, focal_px=focal_px, mm_per_unit=mm_per_unit, depth_kind=depth_kind)
        if f.focal_px is None:
            raise no_focal_length(p)
        ids = f.material_id if f.material_id is not None else np.ones(f.shape, np.int32)
        mask = frame_sss_mask(f)
        if not mask.any():
            raise SSSInputError(f"{p}: no pixel with subsurface scattering (material id > 0 on a surface)")
        rows = np.asarray(material.albedo).reshape(-1, 3).shape[0]
        if rows > 1 and int(ids.max()) > rows:
            raise SSSInputError(f"{p}: material id {int(ids.max())} in the frame but only {rows} materials given")
        frames.append(f)
    truth_images = [read_truth(t, truth_channels, frame=f) for t, f in zip(truths, frames)]

    # ---- rendering and timing
    cache = None if cache_dir is None else pathlib.Path(cache_dir)
    # one run per technique and count: (technique object, its material, the count or None)
    configs: list[tuple[AbstractTechnique, Any, int | None]] = []
    for t, m in zip(objects, materials):
        if t.count_option in counts:
            configs += [(t.replace(**{t.count_option: n}), m, n) for n in counts[t.count_option]]
        else:
            configs.append((t, m, None))
    # two runs of one technique and count (e.g. hdrp at two quality levels) are told apart by their options; checked before
    # any frame is computed
    plain = [t.name if n is None else f"{t.name} {n}" for t, _, n in configs]
    tags = [" ".join(f"{k}={v}" for k, v in changed_options(t).items()) if plain.count(p) > 1 else ""
            for p, (t, _, _) in zip(plain, configs)]
    labels = [p + (f" {g}" if g else "") for p, g in zip(plain, tags)]
    if len(set(labels)) != len(labels):
        twice = sorted({lab for lab in labels if labels.count(lab) > 1})
        raise SSSInputError(f"technique run(s) given twice (--techniques, --taps or --samples): {', '.join(twice)}")
    bar = tqdm(total=len(frames) * (1 + len(configs)), desc="sss-jax report", unit="run", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    reading = {"channel_map": json.dumps(channel_map, sort_keys=True, default=str) if channel_map else None,
               "depth_kind": depth_kind, "use_albedo_pass": use_albedo_pass}
    images: list[list[np.ndarray]] = [[] for _ in configs]
    seconds: list[list[float]] = [[] for _ in configs]
    costs: list[list[tuple[dict, int]]] = [[] for _ in configs]  # (cost per SSS pixel, SSS pixels) per frame
    frame_images, inputs_info, notes, ref_images, ref_seconds = [], [], [], [], []
    try:
        for f in frames:
            name = pathlib.Path(f.path).name
            b = f.to_buffers(use_albedo=use_albedo_pass)
            cam = f.camera()
            ids = f.material_id if f.material_id is not None else np.ones(f.shape, np.int32)
            mask = frame_sss_mask(f)
            albedo = (f.albedo if use_albedo_pass and f.albedo is not None else _material_albedo(material, ids))
            shaded = np.where(mask[..., None], albedo * f.irradiance,
                              f.irradiance * (f.albedo if f.albedo is not None else 1.0)).astype(np.float32)
            finish = lambda img: np.where(mask[..., None], np.asarray(img, np.float32), shaded)

            radius = radius_px if radius_px is not None else reference_radius_px(b, material, cam)
            key = _reference_key(_sha256_file(pathlib.Path(f.path)), material, cam, radius, reading)
            bar.set_postfix_str(f"{name}: reference")
            hit = _cached_reference(cache, key, f.shape)
            if hit is not None:
                ref, ref_s = hit
                notes.append(f"{name}: dense reference (radius {radius} px) read from the cache "
                             f"(reference-{key}.npz; computing it took {ref_s:.1f} s)")
            else:
                ref, ref_s, _ = time_call(lambda: reference(b, material, cam, radius_px=radius), 0)
                if cache is not None:
                    _store_reference(cache, key, ref, ref_s)
                notes.append(f"{name}: dense reference (radius {radius} px) computed in {ref_s:.1f} s"
                             + (f" and cached as reference-{key}.npz" if cache is not None else ""))
            bar.update(1)
            ref_images.append(finish(ref))
            ref_seconds.append(ref_s)
            for k, (tech, tech_material, n) in enumerate(configs):
                bar.set_postfix_str(f"{name}: {tech.name}" + ("" if n is None else f" {n}"))
                img, sec, _ = time_call(lambda: tech(b, tech_material, cam), repeats)
                images[k].append(finish(img))
                seconds[k].append(sec)
                cost = frame_cost(tech, b, tech_material, cam)
                if cost is not None:
                    costs[k].append((cost, int(mask.sum())))
                bar.update(1)
            frame_images.append(FrameImages(name=name, shaded=shaded, reference=ref_images[-1], material_id=ids,
                                            truth=truth_images[len(frame_images)] if truth_images else None,
                                            mask=mask, window=f.window, header=f.metadata))
            inputs_info.append({"path": str(f.path), "name": name, "width": f.shape[1], "height": f.shape[0],
                                "layout": f.layout, "focal_px": f.focal_px, "mm_per_unit": f.scene_unit_mm,
                                "sss_pixels": int(mask.sum()), "reference_radius_px": int(radius),
                                "truth": str(truths[len(inputs_info)]) if truths else None})
    finally:
        bar.close()

    runs = tuple(TechniqueRun(t.name, n, 1e3 * float(np.mean(seconds[k])), tuple(images[k]),
                              options=changed_options(t), conserves_energy=t.conserves_energy,
                              cost_per_pixel=_pooled_cost(costs[k]), tag=tags[k])
                 for k, (t, _, n) in enumerate(configs))
    ref_run = TechniqueRun("reference", None, 1e3 * float(np.mean(ref_seconds)), tuple(ref_images))
    info = {"albedo": _tidy(material.albedo)}
    if isinstance(material, BurleyMaterial):
        info["d_mm"] = _tidy(material.d_mm)
    info["separable_kernel"] = ("two-Gaussian" if isinstance(sep_material, TwoGaussianMaterial)
                                else "pre-integrated profile")
    if any(isinstance(m, STAParams) for m in materials):
        info["sta"] = {**{k: _tidy(v) for k, v in _leaves(sta).items()}, "light_direction": _tidy(light.direction),
                       "light_colour": _tidy(light.colour), "thickness_units": sta_thickness}
    if burley_options:
        info["burley_options"] = {k: str(v) for k, v in burley_options.items()}
    info.update(material_info or {})
    if repeats == 0:  # the page's times are then no measure of the technique's cost: say so where they are read
        notes.append("repeats=0: every time is the first run of its technique on a frame, compilation included, not "
                     "a median after compilation; the times and the Pareto front by them do not compare techniques")
    return ReportData(frames=tuple(frame_images), runs=runs, inputs=inputs_info, material=info,
                      machine=machine_info(), title="sss_jax error report", reference_run=ref_run,
                      notes=tuple(notes))
