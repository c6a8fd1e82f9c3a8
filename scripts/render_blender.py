"""Cycles renders of the kind ``../shared/reference/blender`` holds, for scenes of our own: the buffers a screen-space
pass reads and Cycles' own path-traced Christensen-Burley SSS as the truth.

    blender -b --factory-startup -P scripts/render_blender.py -- --scene closeup [--samples 256] [--out DIR]

Runs inside Blender (3.4 was used: ``apt install blender`` on Debian 12); Blender is not a dependency of sss_jax.
Each scene is rendered twice, as the reference was (its README and JSON sidecars describe it): ``irradiance_<scene>``
with the sphere and Suzanne white (Principled BSDF, base colour 1, no subsurface, specular 0, roughness 1) and
``burley_<scene>`` with the material's Christensen-Burley SSS, each a multi-layer float32 ZIP EXR with the passes
``Combined``, ``Depth``, ``DiffDir``, ``DiffInd``, ``DiffCol``, ``Normal`` and ``IndexOB`` (sphere 1, Suzanne 2,
ground 0), plus a JSON sidecar in the reference's layout (camera, lights, objects, material, samples, seconds).
``--half --passes minimal`` (how ``tests/data/cycles`` was made) writes half-float colour passes (Blender keeps
``Depth`` and ``IndexOB`` in float32, as it does for any compositor) and only the passes sss_jax reads: the white
render's ``Combined``, ``Depth``, ``DiffDir``, ``DiffInd``, ``IndexOB``, the SSS render's ``Combined`` and ``IndexOB``.
The reference's Suzanne is turned in a way its JSON does not record: ``reference`` matches its sphere pixel for pixel
and its mean irradiance within the noise, not Suzanne's silhouette.

``--scene reference`` rebuilds the reference's own scene (a check of this script against the shipped frames).

Scenes (320x240, 50 mm lens on a 36 mm sensor, a ground of albedo 0.5, a dim white world):
- ``reference``: the shipped frame's scene (sun from the front left, a point light behind Suzanne's ears).
- ``closeup``: the camera 2.3 m nearer, the sphere and Suzanne cut by the frame, twice the reference's radius, the
  sun only: most SSS pixels near the frame's edge, as a close-up of a face is.
- ``grazing``: the sun low from the right (light grazing the surfaces: long terminators, where SSS shows most),
  a jade-like green-white material with a wide radius.
- ``far``: the camera 2.5x farther, a quarter of the reference's radius: footprints of a pixel or two, where the
  passes must keep the local shading they cannot improve.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

import bpy
from mathutils import Vector

SCENES = {
    "reference": {"camera": (0.0, -5.6, 1.9), "look_at": (0.0, 0.0, 1.0), "sun_from": (-5.0, -1.0, 2.5),
                  "sun_W_m2": 4.0, "back_point_W": 300.0, "colour": (0.85, 0.75, 0.55),
                  "radius": (0.8, 0.5, 0.3), "radius_scale": 0.5},
    "closeup": {"camera": (0.1, -3.3, 1.35), "look_at": (0.05, 0.0, 1.0), "sun_from": (-5.0, -1.0, 2.5),
                "sun_W_m2": 4.0, "back_point_W": 0.0, "colour": (0.85, 0.75, 0.55),
                "radius": (0.8, 0.5, 0.3), "radius_scale": 1.0},
    "grazing": {"camera": (0.0, -5.6, 1.9), "look_at": (0.0, 0.0, 1.0), "sun_from": (5.0, 0.6, 0.9),
                "sun_W_m2": 5.0, "back_point_W": 0.0, "colour": (0.75, 0.85, 0.7),
                "radius": (0.7, 0.9, 0.6), "radius_scale": 0.6},
    "far": {"camera": (0.0, -14.0, 3.2), "look_at": (0.0, 0.0, 1.0), "sun_from": (-5.0, -1.0, 2.5),
            "sun_W_m2": 4.0, "back_point_W": 300.0, "colour": (0.85, 0.75, 0.55),
            "radius": (0.8, 0.5, 0.3), "radius_scale": 0.125},
}
RESOLUTION = (320, 240)
LENS_MM, SENSOR_MM = 50.0, 36.0
SPHERE = {"pass_index": 1, "center": (-1.25, 0.0, 1.0), "radius_m": 1.0}
SUZANNE = {"pass_index": 2, "location": (1.35, 0.2, 1.0), "size": 2.0, "subsurf_levels": 2}
BACK_POINT = (1.6, 2.2, 2.2)
WORLD = 0.03
PASSES = "all"  # --passes minimal: only the passes sss_jax reads (smaller files, for tests/data)
HALF = False  # --half: 16-bit colour passes (Blender keeps Depth in float32), as a compositor would ask for
GROUND_ALBEDO = 0.5


def _principled(name: str, *, colour, subsurface: float, radius, method: str | None):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Subsurface"].default_value = subsurface
    bsdf.inputs["Subsurface Radius"].default_value = radius
    bsdf.inputs["Subsurface Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Specular"].default_value = 0.0
    bsdf.inputs["Roughness"].default_value = 1.0
    if method is not None:
        bsdf.subsurface_method = method
    return mat


def build(spec: dict, mode: str, samples: int) -> dict:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.seed = 0
    scene.render.resolution_x, scene.render.resolution_y = RESOLUTION
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = HALF and "16" or "32"
    scene.render.image_settings.exr_codec = "ZIP"
    layer = scene.view_layers[0]
    layer.name = "ViewLayer"
    passes = ["use_pass_z", "use_pass_normal", "use_pass_diffuse_direct", "use_pass_diffuse_indirect",
              "use_pass_diffuse_color", "use_pass_object_index"]
    if PASSES == "minimal":  # what sss_jax and its tests read: the input's light, depth and ids, the truth's colour
        passes = (["use_pass_z", "use_pass_diffuse_direct", "use_pass_diffuse_indirect", "use_pass_object_index"]
                  if mode == "irradiance" else ["use_pass_object_index"])
    for p in passes:
        setattr(layer, p, True)

    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = WORLD
    scene.world = world

    cam_data = bpy.data.cameras.new("cam")
    cam_data.lens, cam_data.sensor_width, cam_data.sensor_fit = LENS_MM, SENSOR_MM, "HORIZONTAL"
    cam_data.clip_start, cam_data.clip_end = 0.1, 100.0
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    cam.location = spec["camera"]
    cam.rotation_euler = (Vector(spec["look_at"]) - Vector(spec["camera"])).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy, sun_data.angle = spec["sun_W_m2"], math.radians(0.5)
    sun = bpy.data.objects.new("sun", sun_data)
    scene.collection.objects.link(sun)
    sun.rotation_euler = (-Vector(spec["sun_from"])).to_track_quat("-Z", "Y").to_euler()
    if spec["back_point_W"] > 0:
        pt_data = bpy.data.lights.new("back_point", "POINT")
        pt_data.energy = spec["back_point_W"]
        pt = bpy.data.objects.new("back_point", pt_data)
        scene.collection.objects.link(pt)
        pt.location = BACK_POINT

    if mode == "irradiance":
        material = {"base_color": [1, 1, 1], "subsurface": 0.0, "specular": 0.0, "roughness": 1.0}
        sss = _principled("white", colour=(1.0, 1.0, 1.0), subsurface=0.0, radius=spec["radius"], method=None)
    else:
        radius_m = [r * spec["radius_scale"] for r in spec["radius"]]
        material = {"base_color": list(spec["colour"]), "subsurface_color": list(spec["colour"]),
                    "subsurface_radius": list(spec["radius"]),
                    "subsurface_weight_as_radius_scale": spec["radius_scale"], "radius_m": radius_m,
                    "method": "burley", "specular": 0.0, "roughness": 1.0}
        sss = _principled("sss", colour=spec["colour"], subsurface=spec["radius_scale"], radius=spec["radius"],
                          method="BURLEY")
    ground_mat = _principled("ground", colour=(GROUND_ALBEDO,) * 3, subsurface=0.0, radius=(1, 1, 1), method=None)

    bpy.ops.mesh.primitive_plane_add(size=40.0, location=(0.0, 0.0, 0.0))
    ground = bpy.context.active_object
    ground.pass_index = 0
    ground.data.materials.append(ground_mat)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=SPHERE["radius_m"], location=SPHERE["center"], segments=64,
                                         ring_count=32)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.pass_index = SPHERE["pass_index"]
    sphere.data.materials.append(sss)
    bpy.ops.mesh.primitive_monkey_add(size=SUZANNE["size"], location=SUZANNE["location"])
    monkey = bpy.context.active_object
    monkey.modifiers.new("subsurf", "SUBSURF").levels = SUZANNE["subsurf_levels"]
    monkey.modifiers["subsurf"].render_levels = SUZANNE["subsurf_levels"]
    bpy.ops.object.shade_smooth()
    monkey.pass_index = SUZANNE["pass_index"]
    monkey.data.materials.append(sss)

    focal_px = LENS_MM / SENSOR_MM * RESOLUTION[0]
    lights = {"sun": {"from": list(spec["sun_from"]), "energy_W_m2": spec["sun_W_m2"], "angle_deg": 0.5}}
    if spec["back_point_W"] > 0:
        lights["back_point"] = {"location": list(BACK_POINT), "power_W": spec["back_point_W"]}
    lights["world_strength"] = WORLD
    return {"blender_version": bpy.app.version_string, "mode": mode, "engine": "CYCLES", "samples": samples,
            "resolution": list(RESOLUTION),
            "camera": {"lens_mm": LENS_MM, "sensor_width_mm": SENSOR_MM, "sensor_fit": "HORIZONTAL",
                       "focal_px": focal_px,
                       "location": list(spec["camera"]), "look_at": list(spec["look_at"]), "clip": [0.1, 100.0]},
            "scene_unit_mm": 1000.0, "lights": lights,
            "objects": {"sphere": {k: (list(v) if isinstance(v, tuple) else v) for k, v in SPHERE.items()},
                        "suzanne": {k: (list(v) if isinstance(v, tuple) else v) for k, v in SUZANNE.items()},
                        "ground": {"pass_index": 0, "albedo": GROUND_ALBEDO}},
            "material": material}


def main() -> None:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", choices=sorted(SCENES), action="append")
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--modes", default="irradiance,burley")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("blender_frames"))
    ap.add_argument("--half", action="store_true", help="16-bit colour passes (smaller files)")
    ap.add_argument("--passes", choices=("all", "minimal"), default="all",
                    help="all: the reference's passes; minimal: only those sss_jax reads")
    args = ap.parse_args(argv)
    global HALF, PASSES
    HALF, PASSES = args.half, args.passes
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.scene or sorted(SCENES):
        for mode in args.modes.split(","):
            meta = build(SCENES[name], mode, args.samples)
            path = args.out / f"{mode}_{name}.exr"
            tmp = path.with_name(path.stem + ".partial.exr")
            bpy.context.scene.render.filepath = str(tmp)
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)
            meta["render_seconds"] = round(time.perf_counter() - t0, 2)
            tmp.replace(path)
            side = path.with_suffix(".json")
            side.with_suffix(".json.partial").write_text(json.dumps({"scene": name, **meta}, indent=1))
            side.with_suffix(".json.partial").replace(side)
            print(f"{path}: {meta['render_seconds']} s", flush=True)


if __name__ == "__main__":
    main()
