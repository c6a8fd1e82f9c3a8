"""The error report: ``report(data, out_dir)`` lays out what the caller measured as ``out_dir/report.html`` (one
self-contained page) and ``out_dir/report.json``.

It runs no technique and times nothing: ``data`` (a ``ReportData``) holds the images and times. What it computes
are the metrics, on the SSS pixels of each frame (material id > 0 with a surface), all frames pooled:
``rel_l2 = ||out - target||_2 / ||target||_2`` over RGB, CIEDE2000's mean and 95th percentile, and HDR-ꟻLIP's
mean (NVIDIA's flip-evaluator; each frame's exposure range from the target's SSS pixels, stated in the page and in
``report.json``), against the dense reference and, where the caller gave one, against the offline render ("truth").
"""

from __future__ import annotations

import html
import json
import pathlib
from collections.abc import Sequence
from numbers import Real
from typing import Any

import numpy as np

from .._metrics import FLIP_PPD, delta_e_2000, flip, flip_exposures, rel_l2
from ._page import Page
from ._plots import heatmap, trade_figure
from ._results import FrameImages, ReportData, TechniqueRun

__all__ = ["report", "pareto_flags", "compare"]

ExtraSection = tuple[str, str] | tuple[str, str, dict]


def _delta_e_values(images: Sequence[np.ndarray], targets: Sequence[np.ndarray], frames: Sequence[FrameImages],
                    exposure: float, cache: dict, key: tuple) -> list[np.ndarray]:
    """Per frame, the CIEDE2000 map (0 off the mask); computed once per (run, target) and kept in ``cache``."""
    if key not in cache:
        cache[key] = [delta_e_2000(img, tgt, mask=f.mask, exposure=exposure)["map"]
                      for img, tgt, f in zip(images, targets, frames)]
    return cache[key]


def _flip_values(images: Sequence[np.ndarray], targets: Sequence[np.ndarray], frames: Sequence[FrameImages],
                 exposures: Sequence[tuple[float, float, int]], cache: dict, key: tuple) -> list[np.ndarray]:
    """Per frame, the HDR-ꟻLIP map (0 off the mask) at that frame's exposure range; computed once per (run,
    target) and kept in ``cache``."""
    if key not in cache:
        cache[key] = [flip(img, tgt, mask=f.mask, exposures=ex)["map"]
                      for img, tgt, f, ex in zip(images, targets, frames, exposures)]
    return cache[key]


def compare(images: Sequence[np.ndarray], targets: Sequence[np.ndarray], masks: Sequence[np.ndarray],
            delta_e_maps: Sequence[np.ndarray], flip_maps: Sequence[np.ndarray] | None = None) -> dict[str, float]:
    """``{"rel_l2", "delta_e_mean", "delta_e_p95"}`` (and ``"flip_mean"`` where ``flip_maps`` are given) over the
    masked pixels of all frames pooled."""
    out = np.concatenate([np.asarray(i, np.float64)[m] for i, m in zip(images, masks)])
    tgt = np.concatenate([np.asarray(t, np.float64)[m] for t, m in zip(targets, masks)])
    de = np.concatenate([d[m] for d, m in zip(delta_e_maps, masks)])
    result = {"rel_l2": rel_l2(out, tgt), "delta_e_mean": float(de.mean()),
              "delta_e_p95": float(np.percentile(de, 95))}
    if flip_maps is not None:
        result["flip_mean"] = float(np.concatenate([fl[m] for fl, m in zip(flip_maps, masks)]).mean())
    return result


def pareto_flags(ms: Sequence[Real | None], err: Sequence[Real]) -> list[bool]:
    """True for the runs no other run beats in both time and error (faster and at most as wrong, or as fast and
    less wrong); untimed runs are never on the front."""
    flags = []
    for i, (t, e) in enumerate(zip(ms, err)):
        if t is None:
            flags.append(False)
            continue
        dominated = any(u is not None and j != i and u <= t and f <= e and (u < t or f < e)
                        for j, (u, f) in enumerate(zip(ms, err)))
        flags.append(not dominated)
    return flags


def _check_extra(extra_sections: Sequence[ExtraSection]) -> list[tuple[str, str, dict]]:
    out = []
    for i, item in enumerate(extra_sections):
        if not isinstance(item, (tuple, list)) or len(item) not in (2, 3):
            raise ValueError(f"extra_sections[{i}] must be (title, html_fragment) or (title, html_fragment, data), "
                             f"got {type(item).__name__}")
        title, fragment, *rest = item
        if not isinstance(title, str) or not isinstance(fragment, str):
            raise ValueError(f"extra_sections[{i}]: title and html_fragment must be str")
        data = rest[0] if rest else {}
        if not isinstance(data, dict):
            raise ValueError(f"extra_sections[{i}]: data must be a dict, got {type(data).__name__}")
        out.append((title, fragment, data))
    return out


def _best_runs(runs: Sequence[TechniqueRun]) -> list[TechniqueRun]:
    """Per technique, the run with the largest count (the one the maps show)."""
    best: dict[tuple[str, str], TechniqueRun] = {}
    for r in runs:
        cur = best.get((r.technique, r.tag))
        if cur is None or (r.count or 0) > (cur.count or 0):
            best[(r.technique, r.tag)] = r
    return list(best.values())


def _jsonable(value):
    """An option's value for JSON: numbers, strings, booleans and None as they are, anything else as text."""
    return value if isinstance(value, (str, int, float, bool, type(None))) else str(value)


def _scale(maps: dict[str, np.ndarray], keys: Sequence[str], mask: np.ndarray) -> float:
    return max((float(np.percentile(maps[k][mask], 99.5)) for k in keys), default=1.0) or 1.0


def report(data: ReportData, out_dir: str | pathlib.Path, *,
           extra_sections: Sequence[ExtraSection] = (), images: bool = False) -> pathlib.Path:
    """Write ``out_dir/report.html`` and ``out_dir/report.json``; return the HTML's path.

    ``report.json``: ``{"inputs": [...], "material": {...}, "machine": {...}, "techniques": [{"technique", "count",
    "ms_per_frame", "vs_reference": {"rel_l2", "delta_e_mean", "delta_e_p95", "flip_mean"}, "vs_truth": {...} or
    null, "worse_than_local_shading": {"vs_reference": bool, "vs_truth": bool or null}}], "local_shading":
    {"vs_reference", "vs_truth"}, "notes": [...], "flip": {"tonemapper", "ppd", "exposures": [{"frame", "target",
    "start", "stop", "count"}]}}``: local shading (albedo x irradiance) is the floor, every technique doing worse
    than it is flagged and named in ``notes`` (with the report's own notes: cache use, techniques left out)
    (plus ``"sections"`` with the data of the extra sections that carry any). ``extra_sections``: ``(title,
    html_fragment)`` or ``(title, html_fragment, data)`` sections from other parts of a workflow (a fit's
    before/after, the demo's profiles), placed after the trade. ``images``: also write every image compared as
    float32 EXR, ``out_dir/images/<frame>/<technique>[_<count>].exr`` (and ``reference.exr``), linear RGB.

    Everything is written to a staging folder beside ``out_dir`` and moved in when complete (each file by an atomic
    rename, the HTML last), so a failure leaves nothing partial in ``out_dir``; ``out_dir`` is created if missing."""
    extras = _check_extra(extra_sections)
    frames, runs = data.frames, list(data.runs)
    exposure = data.exposure
    has_truth = all(f.truth is not None for f in frames)
    masks = [f.mask for f in frames]
    refs = [f.reference for f in frames]
    truths = [f.truth for f in frames] if has_truth else None
    de_cache: dict = {}
    flip_cache: dict = {}
    # HDR-FLIP's exposure range follows the target (FLIP's reference image), one per frame and target
    flip_ranges = {"reference": [flip_exposures(f.reference, mask=f.mask) for f in frames]}
    if has_truth:
        flip_ranges["truth"] = [flip_exposures(f.truth, mask=f.mask) for f in frames]

    def flip_maps(run: TechniqueRun, which: str) -> list[np.ndarray]:
        return _flip_values(run.images, refs if which == "reference" else truths, frames, flip_ranges[which],
                            flip_cache, (run.label, which))

    target_images = {"reference": refs, "truth": truths}  # what each comparison is against

    def metrics(run: TechniqueRun, which: str):
        targets = target_images[which]
        des = _delta_e_values(run.images, targets, frames, exposure, de_cache, (run.label, which))
        return compare(run.images, targets, masks, des, flip_maps(run, which))

    entries = []
    all_runs = runs + ([data.reference_run] if data.reference_run is not None else [])
    for run in all_runs:
        entries.append({"technique": run.technique, "count": run.count, "label": run.label,
                        "options": {k: _jsonable(v) for k, v in run.options.items()},
                        "cost_per_pixel": run.cost_per_pixel,
                        "ms_per_frame": None if run.ms_per_frame is None else float(run.ms_per_frame),
                        "vs_reference": metrics(run, "reference"),
                        "vs_truth": metrics(run, "truth") if has_truth else None})
    timed = entries[:len(runs)]
    # local shading (albedo x irradiance, no SSS) is the floor: a technique that does worse than it on this frame
    # is flagged, against the reference and, when given, against the truth
    local_run = TechniqueRun("local shading", None, None, tuple(f.shaded for f in frames))
    local = {"vs_reference": metrics(local_run, "reference"), "vs_truth": metrics(local_run, "truth") if has_truth
             else None}
    flag_notes = []
    for e in timed:
        worse = {k: (None if local[k] is None else bool(e[k]["rel_l2"] > local[k]["rel_l2"]))
                 for k in ("vs_reference", "vs_truth")}
        e["worse_than_local_shading"] = worse
        for k, what in (("vs_truth", "the truth"), ("vs_reference", "the reference")):
            if worse[k]:
                label = e["label"]
                flag_notes.append(f"{label} does worse than local shading against {what} on these frames: rel L2 "
                                  f"{e[k]['rel_l2']:.4f} against {local[k]['rel_l2']:.4f} (no SSS at all).")
    notes = tuple(data.notes) + tuple(flag_notes)
    for key in ("vs_reference", "vs_truth"):
        if key == "vs_truth" and not has_truth:
            continue
        flags = pareto_flags([e["ms_per_frame"] for e in timed], [e[key]["rel_l2"] for e in timed])
        for e, f in zip(timed, flags):
            e[f"pareto_{key}"] = f

    page = Page(data.title, subtitle=", ".join(f.name for f in frames))
    flip_info = {"tonemapper": "ACES", "ppd": FLIP_PPD,
                 "exposures": [{"frame": f.name, "target": which, "start": ex[0], "stop": ex[1], "count": ex[2]}
                               for which, ranges in flip_ranges.items() for f, ex in zip(frames, ranges)]}
    flip_note = (f"ACES tone mapping at {FLIP_PPD:.0f} pixels per degree, exposures from the target's SSS pixels: "
                 + "; ".join(f"{e['frame']} vs {e['target']} {e['start']:+.2f} to {e['stop']:+.2f} stops in "
                             f"{e['count']} steps" for e in flip_info["exposures"]))
    names = data.material.get("names") or []

    # summary
    sec = page.section("Summary", "Each technique on the pixels with subsurface scattering (material id &gt; 0), all "
                       "frames pooled: relative L2 <code>||out - target|| / ||target||</code> over RGB, CIEDE2000 "
                       f"(mean, 95th percentile; exposure {exposure:+g} stops, linear sRGB white = L* 100) and "
                       "HDR-ꟻLIP (mean; NVIDIA's flip-evaluator, 0 = identical, 1 = most different; "
                       f"{html.escape(flip_note)}), against "
                       "the dense reference" + (" and against the offline render (truth)" if has_truth else "")
                       + ". Times are medians per frame after compilation, on the machine below (the reference's "
                       "is its one run per frame, compilation included, or the run a cache kept). The cost per pixel "
                       "is what the technique's shader (the engine's own, for the engines' passes) executes per SSS "
                       "pixel and frame: samples or taps, texels fetched, arithmetic, counted from the formulation "
                       "and the same on any machine (a TAA pass pays it once per frame it accumulates). Rows on the "
                       "Pareto front (nothing both faster and closer to the reference) are shaded.")
    rows = []
    for e in entries:
        cost = e["cost_per_pixel"] or {}
        row = {"technique": e["technique"], "count": e["count"],
               "options": " ".join(f"{k}={v}" for k, v in e["options"].items()) or None,
               "ms / frame": e["ms_per_frame"], "samples / px": cost.get("samples"),
               "fetches / px": cost.get("fetches"), "flops / px": cost.get("flops"),
               "rel L2 vs ref": e["vs_reference"]["rel_l2"], "ΔE mean vs ref": e["vs_reference"]["delta_e_mean"],
               "ΔE p95 vs ref": e["vs_reference"]["delta_e_p95"], "ꟻLIP vs ref": e["vs_reference"]["flip_mean"]}
        if has_truth:
            row.update({"rel L2 vs truth": e["vs_truth"]["rel_l2"], "ΔE mean vs truth": e["vs_truth"]["delta_e_mean"],
                        "ΔE p95 vs truth": e["vs_truth"]["delta_e_p95"], "ꟻLIP vs truth": e["vs_truth"]["flip_mean"]})
        rows.append(row)
    row = {"technique": "local shading (no SSS)", "count": None, "options": None, "ms / frame": None,
           "samples / px": None, "fetches / px": None, "flops / px": None,
           "rel L2 vs ref": local["vs_reference"]["rel_l2"], "ΔE mean vs ref": local["vs_reference"]["delta_e_mean"],
           "ΔE p95 vs ref": local["vs_reference"]["delta_e_p95"],
           "ꟻLIP vs ref": local["vs_reference"].get("flip_mean")}
    if has_truth:  # (its ꟻLIP was computed and left out of the table: "-" beside the techniques' values)
        row.update({"rel L2 vs truth": local["vs_truth"]["rel_l2"], "ΔE mean vs truth": local["vs_truth"]["delta_e_mean"],
                    "ΔE p95 vs truth": local["vs_truth"]["delta_e_p95"],
                    "ꟻLIP vs truth": local["vs_truth"].get("flip_mean")})
    rows.append(row)
    page.table(sec, rows, "time and error per technique and count", key="techniques",
               highlight=[bool(e.get("pareto_vs_reference")) for e in entries] + [False])
    if notes:
        page.raw(sec, "<ul class=note>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")

    shown = _best_runs(runs)
    # renders
    sec = page.section("Renders", "Linear renders through the sRGB display transform"
                       f" (exposure {exposure:+g} stops). Each technique at its largest count; pixels without "
                       "subsurface scattering are shaded locally in every image.")
    for f in frames:
        if len(frames) > 1:
            page.raw(sec, f"<h3>{html.escape(f.name)}</h3>")
        page.raw(sec, "<div class=grid>")
        page.image(sec, f.shaded, "input: albedo × irradiance (no SSS)", exposure)
        page.image(sec, f.reference, "dense reference", exposure)
        if f.truth is not None:
            page.image(sec, f.truth, "truth (offline render)", exposure)
        for run in shown:
            page.image(sec, run.images[frames.index(f)], run.label, exposure)
        page.raw(sec, "</div>")

    # difference and CIEDE2000 maps
    targets = [("reference", "Against the reference", "Absolute difference to the dense reference (mean over RGB), "
                "CIEDE2000 and HDR-ꟻLIP per pixel, SSS pixels only. Scattering techniques share one scale; STA, "
                "which adds light instead of redistributing it, has its own; ꟻLIP maps use ꟻLIP's own 0 to 1 scale.")]
    if has_truth:
        targets.append(("truth", "Against the truth", "The same against the offline render. The reference's own "
                        "distance from it (first pair) is what screen space cannot know: light entering surfaces "
                        "the camera does not see, silhouettes, and the offline render's noise."))
    for which, title, text in targets:
        sec = page.section(title, text)
        for fi, f in enumerate(frames):
            if len(frames) > 1:
                page.raw(sec, f"<h3>{html.escape(f.name)}</h3>")
            tgt = target_images[which][fi]
            cmp_runs = ([data.reference_run] if which == "truth" and data.reference_run is not None else []) + shown
            diffs, des, flips = {}, {}, {}
            for run in cmp_runs:
                diffs[run.label] = np.abs(np.asarray(run.images[fi], np.float64) - tgt).mean(-1) * f.mask
                des[run.label] = _delta_e_values(run.images, target_images[which], frames,
                                                 exposure, de_cache, (run.label, which))[fi]
                flips[run.label] = flip_maps(run, which)[fi]
            sta = [r.label for r in cmp_runs if r.adds_light]  # kept apart: it adds light by design
            rest = [k for k in diffs if k not in sta]
            page.raw(sec, "<div class=grid>")
            for run in cmp_runs:
                keys = sta if run.label in sta else rest
                page.figure(sec, heatmap(diffs[run.label], f"|{run.label} − {which}|", _scale(diffs, keys, f.mask)),
                            f"{run.label}: absolute difference to the {which}")
                page.figure(sec, heatmap(des[run.label], f"ΔE2000 {run.label} vs {which}",
                                         _scale(des, keys, f.mask), "viridis"), f"{run.label}: CIEDE2000 to the {which}")
                page.figure(sec, heatmap(flips[run.label], f"ꟻLIP {run.label} vs {which}", 1.0, "magma"),
                            f"{run.label}: HDR-ꟻLIP to the {which}")
            page.raw(sec, "</div>")

    # per material
    sec = page.section("Per material", "The same metrics per frame and material id (SSS pixels of that id only).")
    for fi, f in enumerate(frames):
        ids = sorted(int(k) for k in np.unique(np.asarray(f.material_id)[f.mask]))
        mrows = []
        for k in ids:
            m = f.mask & (np.asarray(f.material_id) == k)
            label = names[k - 1] if k - 1 < len(names) else (names[0] if len(names) == 1 else None)
            for run in all_runs:
                row = {"material id": k, **({"material": label} if names else {}), "pixels": int(m.sum()),
                       "technique": run.label}
                for which, tgt in (("ref", f.reference), ("truth", f.truth)):
                    if tgt is None:
                        continue
                    de = _delta_e_values(run.images, refs if which == "ref" else truths, frames, exposure, de_cache,
                                         (run.label, "reference" if which == "ref" else "truth"))[fi]
                    fl = flip_maps(run, "reference" if which == "ref" else "truth")[fi]
                    c = compare([run.images[fi]], [tgt], [m], [de], [fl])
                    row.update({f"rel L2 vs {which}": c["rel_l2"], f"ΔE mean vs {which}": c["delta_e_mean"],
                                f"ΔE p95 vs {which}": c["delta_e_p95"], f"ꟻLIP vs {which}": c["flip_mean"]})
                mrows.append(row)
        page.table(sec, mrows, f"{f.name}: per material", key=f"frame{fi}")

    # the trade
    sec = page.section("Speed against accuracy", "Time per frame against relative L2 for every technique and count "
                       "on these frames; the dashed line joins the Pareto front (nothing both faster and more "
                       "accurate).")
    panels = [("vs_reference", "against the reference")] + ([("vs_truth", "against the truth")] if has_truth else [])
    if any(e["ms_per_frame"] is not None for e in timed):
        page.figure(sec, trade_figure(timed, panels), "time per frame against error; numbers are taps or "
                    "samples, words the options telling two runs of one count apart")
    # each run by its label (technique, count and, where two runs share those, the options that tell them apart:
    # hdrp at quality low and high were two rows "hdrp | - | ..." that no one could tell apart)
    trade_rows = [{"run": e["label"], "ms / frame": e["ms_per_frame"],
                   "rel L2 vs ref": e["vs_reference"]["rel_l2"], "Pareto (ref)": e.get("pareto_vs_reference"),
                   **({"rel L2 vs truth": e["vs_truth"]["rel_l2"], "Pareto (truth)": e.get("pareto_vs_truth")}
                      if has_truth else {})} for e in timed]
    page.table(sec, trade_rows, "the Pareto front", key="trade",
               highlight=[bool(e.get("pareto_vs_reference")) for e in timed])

    for title, fragment, sdata in extras:
        sec = page.section(title)
        page.raw(sec, fragment)
        page.data["sections"][title] = sdata

    # inputs and machine
    sec = page.section("Inputs", "The frames, camera and material this report was made from.")
    # file names in the table (the JSON keeps the full paths)
    shown_inputs = [{k: (pathlib.Path(v).name if k in ("path", "truth") and isinstance(v, str) else v)
                     for k, v in i.items() if not isinstance(v, dict) and k != "name"} for i in data.inputs]
    page.table(sec, shown_inputs, "frames", key="inputs")
    page.table(sec, [{"parameter": k, "value": v if isinstance(v, str) else json.dumps(v, default=str)}
                     for k, v in data.material.items()], "material", key="material")
    sec = page.section("Machine", "Where the times were measured.")
    page.table(sec, [{"what": k, "value": v} for k, v in data.machine.items()], "machine", key="machine")

    doc: dict[str, Any] = {"inputs": data.inputs, "material": data.material, "machine": data.machine,
                           "techniques": [{k: e[k] for k in ("technique", "count", "label", "options",
                                                             "cost_per_pixel", "ms_per_frame", "vs_reference",
                                                             "vs_truth", "worse_than_local_shading") if k in e}
                                          for e in entries],
                           "local_shading": local, "notes": list(notes), "flip": flip_info}
    extra_data = {t: d for t, _, d in extras if d}
    if extra_data:
        doc["sections"] = extra_data
    return _write(out_dir, doc, page.html(), frames, all_runs if images else [])


def check_inputs_outside_images(out_dir: pathlib.Path, inputs: Sequence[Any]) -> None:
    """No frame or truth of a report lies in ``out_dir/images``, the folder the report fills and clears: an earlier
    report's image given as the truth would be replaced (same name) or removed as stale (another); refused naming
    it, before any work where the caller checks first."""
    from .._io import SSSInputError

    images = (pathlib.Path(out_dir) / "images").resolve()
    for path in inputs:
        resolved = pathlib.Path(path).resolve()
        if resolved.is_relative_to(images):
            raise SSSInputError(f"{path} lies in {pathlib.Path(out_dir) / 'images'}, which this report fills and "
                                "clears of earlier reports' images: copy it elsewhere, or give the report another "
                                "folder")


def _write(out_dir, doc: dict, page_html: str, frames: Sequence[FrameImages], runs: Sequence[TechniqueRun]):
    import os
    import shutil
    import tempfile

    from .._io import (
        SSSInputError,
        output_problems,
        write_bytes_atomic,
        write_exr,
        write_json_atomic,
    )

    out_dir = pathlib.Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir}: exists and is not a directory")
    stems = [pathlib.Path(f.name).stem or f"frame{i}" for i, f in enumerate(frames)]
    if len(set(stems)) < len(stems):  # frames of one name from several folders
        stems = [f"{i}_{s}" for i, s in enumerate(stems)]
    images = [(fi, run, pathlib.Path("images", stem, run.label.replace(" ", "_") + ".exr"))
              for fi, stem in enumerate(stems) for run in runs]
    pages = [pathlib.Path("report.json"), pathlib.Path("report.html")]
    planned = list(dict.fromkeys([rel for _, _, rel in images] + pages))
    inputs = [pathlib.Path(v) for i in doc.get("inputs", []) for k, v in i.items()
              if k in ("path", "truth") and isinstance(v, str)]
    check_inputs_outside_images(out_dir, inputs)
    problems = output_problems([("the report", out_dir / rel) for rel in planned], inputs)
    if problems:
        raise SSSInputError("report not written: " + "; ".join(problems))
    parent = out_dir.parent
    parent.mkdir(parents=True, exist_ok=True)
    staging = pathlib.Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging-", dir=parent))
    try:
        for fi, run, rel in images:
            (staging / rel).parent.mkdir(parents=True, exist_ok=True)
            write_exr(staging / rel, np.asarray(run.images[fi], np.float32),
                      attributes={"sss_jax:technique": run.technique, "sss_jax:count": run.count or 0},
                      window=frames[fi].window, like=frames[fi].header)
        write_json_atomic(staging / "report.json", doc)
        write_bytes_atomic(staging / "report.html", page_html.encode())
        files = [rel for _, _, rel in images] + pages
        out_dir.mkdir(parents=True, exist_ok=True)
        for rel in files:
            (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / rel, out_dir / rel)
        _drop_stale_images(out_dir, {out_dir / rel for rel in files})
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out_dir / "report.html"


def _drop_stale_images(out_dir: pathlib.Path, kept: set[pathlib.Path]) -> None:
    """An earlier report's images in ``out_dir/images`` that this one did not write (another technique, count or
    frame): removed, so the folder shows this report's runs only. Only files a report wrote (an EXR with the
    report's ``sss_jax:technique`` and ``sss_jax:count`` attributes) go; anything else stays."""
    from .._io import read_header

    images = out_dir / "images"
    if not images.is_dir():
        return
    for path in sorted(images.glob("*/*.exr")):
        if path in kept:
            continue
        try:
            attrs = read_header(path)[0]
        except (OSError, ValueError):
            continue
        if "sss_jax:technique" in attrs and "sss_jax:count" in attrs:
            path.unlink(missing_ok=True)
    for folder in images.iterdir():
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
