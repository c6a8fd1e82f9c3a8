"""The candidates for the techniques' default options, measured on path-traced frames: prints the table.

    nice -n 10 .venv/bin/python scripts/default_candidates.py [--json OUT]

Frames: the Blender 3.4 / Cycles render in ../shared/reference/blender and three of our own in tests/data/cycles
(scripts/render_blender.py: a close-up cut by the frame, grazing light, a far view; Cycles' own Christensen-Burley SSS
as the truth, d = radius / (4 pi) as Cycles >= 3.0 converts it) and the Mitsuba 3 scenes in tests/data/mitsuba
(scripts/render_mitsuba.py: volpath through a measured medium). Metric: relative L2 over the SSS pixels (id > 0)
against the path-traced truth, and its ratio to local shading's (albedo x irradiance, no SSS): below 1 the technique
is closer to the truth than no SSS at all.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import warnings

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MITSUBA = ROOT / "tests" / "data" / "mitsuba"
BLENDER = ROOT.parent / "shared" / "reference" / "blender"
CYCLES = ROOT / "tests" / "data" / "cycles"
MITSUBA_SCENES = ("skin_closeup", "marble_objects", "skin_occlusion")
MITSUBA_SCENES = tuple(n for n in MITSUBA_SCENES if (MITSUBA / f"{n}_truth.exr").exists())
CYCLES_SCENES = ("closeup", "grazing", "far")
CYCLES_SCENES = tuple(n for n in CYCLES_SCENES if (CYCLES / f"burley_{n}.exr").exists())

# (technique, options): the candidates; the first of each technique's block is the old default
CANDIDATES = (
    ("burley", {"samples": 32, "border": "leaves", "pattern": "rotated"}),
    ("burley", {"samples": 32, "border": "renormalise", "pattern": "rotated"}),
    ("burley", {"samples": 32, "border": "leaves", "pattern": "fixed"}),
    ("burley", {"samples": 32, "border": "renormalise", "pattern": "fixed"}),
    ("burley", {"samples": 32, "border": "renormalise", "pattern": "rotated", "interpolation": "nearest"}),
    ("separable", {"taps": 25, "border": "leaves"}),
    ("separable", {"taps": 25, "border": "renormalise"}),
    ("separable", {"taps": 25, "border": "renormalise", "interpolation": "nearest"}),
    ("separable", {"taps": 25, "border": "renormalise", "follow_surface": False}),
)


def load_blender(root: pathlib.Path = BLENDER, name: str = "backlit"):
    """(buffers, camera, material, truth, mask) of a Cycles frame: ``irradiance_<name>.exr`` (the white render) and
    ``burley_<name>.exr`` (Cycles' SSS) with the latter's JSON sidecar (scripts/render_blender.py's layout)."""
    import sss_jax as sj
    from sss_jax import _io

    scene = json.loads((root / f"burley_{name}.json").read_text())
    f = _io.read_frame(root / f"irradiance_{name}.exr")
    truth = _io.read_frame(root / f"burley_{name}.exr", channel_map={
        "irradiance": ["ViewLayer.Combined.R", "ViewLayer.Combined.G", "ViewLayer.Combined.B"],
        "depth": "ViewLayer.Combined.A"}).irradiance  # a frame needs a depth: the truth's own is not read
    a = np.asarray(scene["material"]["subsurface_color"], np.float64)
    radius_mm = np.asarray(scene["material"]["radius_m"], np.float64) * scene["scene_unit_mm"]
    mat = sj.BurleyMaterial(a.astype(np.float32), (radius_mm / (4 * math.pi)).astype(np.float32))
    # the white render's DiffCol is 1: the material's colour is the albedo
    return f.to_buffers(use_albedo=False), sj.Camera(f.focal_px, f.mm_per_unit), mat, truth, f.material_id > 0


def load_mitsuba(name: str, root: pathlib.Path = MITSUBA):
    """(buffers, camera, material, truth, mask) of a scene of scripts/render_mitsuba.py."""
    import sss_jax as sj
    from sss_jax import _io

    f = _io.read_frame(root / f"{name}_buffers.exr")
    meta = json.loads((root / f"{name}_buffers.json").read_text())
    truth = _io.read_frame(root / f"{name}_truth.exr", channel_map={"irradiance": ["R", "G", "B"],
                                                                    "depth": "R"}).irradiance
    mat = sj.BurleyMaterial(np.asarray(meta["material"]["albedo"], np.float32),
                            np.asarray(meta["material"]["d_mm"], np.float32))
    return f.to_buffers(), sj.Camera(f.focal_px, f.mm_per_unit), mat, truth, f.material_id > 0


def frames() -> dict:
    out = {"Cycles (Blender 3.4), back-lit sphere + Suzanne": load_blender}
    for name in CYCLES_SCENES:
        out[f"Cycles {name}"] = lambda name=name: load_blender(CYCLES, name)
    for name in MITSUBA_SCENES:
        out[f"Mitsuba {name}"] = lambda name=name: load_mitsuba(name)
    return out


def measure(technique: str, options: dict, buffers, camera, material, truth, mask) -> float:
    import sss_jax as sj
    from sss_jax._metrics import rel_l2

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sampling warnings: the table states the counts
        out = np.asarray(getattr(sj, technique)(buffers, material, camera, **options), np.float64)
    return rel_l2(out, truth, mask=mask)


def local_error(buffers, material, truth, mask) -> float:
    from sss_jax._metrics import rel_l2

    albedo = np.asarray(buffers.albedo) if buffers.albedo is not None else np.asarray(material.albedo)[0]
    return rel_l2(albedo * np.asarray(buffers.irradiance), truth, mask=mask)


def label(technique: str, options: dict) -> str:
    return technique + " " + ", ".join(f"{k}={v}" for k, v in options.items())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=pathlib.Path, help="also write the table as JSON")
    args = ap.parse_args(argv)
    results = {}
    for frame, load in frames().items():
        b, cam, mat, truth, mask = load()
        local = local_error(b, mat, truth, mask)
        rows = {label(t, o): measure(t, o, b, cam, mat, truth, mask) for t, o in CANDIDATES}
        results[frame] = {"local_shading": local, "candidates": rows}
        print(f"{frame}: local shading {local:.4f}", flush=True)
    names = [label(t, o) for t, o in CANDIDATES]
    print("\n| candidate | " + " | ".join(results) + " |")
    print("|---|" + "---|" * len(results))
    for n in names:
        cells = [f"{r['candidates'][n]:.4f} ({r['candidates'][n] / r['local_shading']:.3f})" for r in results.values()]
        print(f"| {n} | " + " | ".join(cells) + " |")
    print("| local shading (albedo x irradiance) | " + " | ".join(f"{r['local_shading']:.4f} (1)"
                                                              for r in results.values()) + " |")
    if args.json:
        from sss_jax._io import write_json_atomic

        write_json_atomic(args.json, results)


if __name__ == "__main__":
    main()
