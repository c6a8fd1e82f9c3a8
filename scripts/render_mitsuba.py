"""Path-traced scenes of measured media (Mitsuba 3, CPU): the buffers sss_jax reads and the path-traced truth.

    nice -n 10 .venv/bin/python scripts/render_mitsuba.py [--spp 256] [--scene skin_closeup] [--out tests/data/mitsuba]

Mitsuba is not a dependency of sss_jax: ``pip install mitsuba`` (3.x, the ``scalar_rgb`` variant runs on any CPU).

Each scene is written as ``<scene>_buffers.exr`` (what a screen-space pass sees: ``R,G,B`` the irradiance -- the
same scene rendered with every object a white Lambertian surface, so a pixel is ``E / pi`` --, ``Z`` planar view
depth in mm (``inf`` where there is no surface), ``N.X/Y/Z`` camera-space normals, ``albedo.R/G/B`` the surface
albedo of the index-matched medium, ``id`` 1 on the medium and 0 elsewhere, ``thickness`` in mm where the scene has one),
``<scene>_truth.exr`` (``R,G,B``: Mitsuba's ``volpath`` through the measured medium, isotropic phase function with
the reduced coefficients of Jensen et al. 2001 Table 2, index-matched boundary: through a smooth dielectric
the directional light could not be reached by a scattered path's next-event estimate) and ``<scene>_buffers.json`` (camera ``focal_px``, ``scene_unit_mm``, lights, material, samples, seconds),
half float, ZIP. Camera space is sss_jax's (x right, y down, z forward): the Mitsuba camera sits at the origin and
looks along +z with up -y, so world and camera coordinates coincide. Geometry buffers are cast analytically
through pixel centres (NumPy), the renders are box-filtered over the pixel.

Scenes:
- ``skin_closeup``: a half-space of skin1 filling the frame (8 px/mm), lit by a directional light whose shadow edge,
  cast by a black blocker outside the view, crosses the frame: a close-up cut by the frame, with a hard shadow edge.
- ``marble_objects``: two marble spheres and a rotated marble cube against a black background, one directional light.
- ``skin_occlusion``: a skin2 sphere 25 mm in front of a skin2 wall, lit from the upper left: the sphere's silhouette
  against the lit wall and its shadow on the wall beside it (depth discontinuities between two surfaces of the medium).
- ``skin_backlit``: three slabs of skin1 (1, 2 and 4 mm thick) lit only from behind (17 degrees off the axis); the
  light they transmit is all the camera sees (the unscattered beam, a delta direction, never reaches it).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

W, H = 160, 120
ETA = 1.0


def _mitsuba():
    try:
        import mitsuba as mi
    except ImportError as exc:  # an optional tool, not a dependency
        raise SystemExit("render_mitsuba.py needs Mitsuba 3: pip install mitsuba") from exc
    mi.set_variant("scalar_rgb")
    return mi


def _medium(name: str) -> dict:
    """Reduced scattering and absorption (1/mm) of a measured material, from the package's copy of the table."""
    import csv
    from importlib import resources

    text = resources.files("sss_jax").joinpath("data/measured_materials.csv").read_text()
    rows = [r for r in csv.reader(line for line in text.splitlines() if not line.startswith("#"))]
    head, body = rows[0], rows[1:]
    for r in body:
        if r[0] == name:
            v = dict(zip(head, r))
            s = [float(v[f"sigma_s_prime_{c}"]) for c in "rgb"]
            a = [float(v[f"sigma_a_{c}"]) for c in "rgb"]
            return {"name": name, "sigma_s_prime_per_mm": s, "sigma_a_per_mm": a}
    raise SystemExit(f"no measured material {name!r}")


@functools.lru_cache(maxsize=None)
def _index_matched_material(name: str, *, photons: int = 100_000, slab_photons: int = 20_000) -> dict:
    """The Burley material and slab table of the index-matched medium the truth renders (the presets' A and d are
    those of eta 1.3): A the Monte Carlo total diffuse reflectance (pencil beam), d fitted to its profile as the
    presets fit theirs (``_fit_presets.fit_burley_d``), and ``medium_slab_table`` at eta 1 for
    ``translucency(model="slab")``."""
    from sss_jax._fit_presets._references import _r_max_mfp, fit_burley_d
    from sss_jax._montecarlo import simulate
    from sss_jax._profiles import scaling_searchlight
    from sss_jax._slab import medium_slab_table

    med = _medium(name)
    s = np.asarray(med["sigma_s_prime_per_mm"])
    a = np.asarray(med["sigma_a_per_mm"])
    albedo, d_mm, stderr = [], [], []
    for c in range(3):
        alpha, mfp = float(s[c] / (s[c] + a[c])), float(1.0 / (s[c] + a[c]))
        res = simulate(alpha, photons=photons, eta=1.0, seed=c, r_max_mfp=_r_max_mfp(alpha), bins=200)
        A = float(res.total_reflectance)
        fit = fit_burley_d(res, mfp, mfp / float(scaling_searchlight(A)))
        albedo.append(A)
        stderr.append(float(res.total_reflectance_stderr))
        d_mm.append(fit["d_mm"])
    slab = medium_slab_table(s, a, 1.0, photons=slab_photons)
    return {"albedo": albedo, "albedo_stderr": stderr, "d_mm": d_mm, "photons": photons,
            "derivation": "index-matched medium: A = Monte Carlo total diffuse reflectance, d = Burley d fitted to "
                          "the Monte Carlo profile (sss_jax._fit_presets.fit_burley_d)", "slab_table": slab}


# ----------------------------------------------------------------------------------------------------------------
# scene descriptions: shapes as (kind, parameters) so that Mitsuba and the NumPy ray caster read the same geometry
# ----------------------------------------------------------------------------------------------------------------
def _rot_y(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], np.float64)


def scene_spec(name: str) -> dict:
    if name == "skin_closeup":
        # the surface at z = 60 mm, 8 px/mm there; the light comes from the left (travelling +x, +z)
        f = 8.0 * 60.0
        light = np.array([0.5, 0.2, 1.0])
        boxes = [{"center": [0.0, 0.0, 80.0], "half": [100.0, 100.0, 20.0], "rot_y": 0.0}]
        # blocker: x < -22 at z = 20 (outside the view: the frustum there is |x| < 3.4); shadow edge at
        # x = -22 + 0.5 * (60 - 20) = -2 mm on the surface, column 80 - 16 = 64
        blocker = {"x": [-222.0, -22.0], "y": [-100.0, 100.0], "z": 20.0}
        return {"focal_px": f, "medium": "skin1", "boxes": boxes, "spheres": [], "blocker": blocker,
                "lights": [{"direction_of_travel": light.tolist(), "irradiance": math.pi}]}
    if name == "marble_objects":
        f = 4.0 * 100.0  # 4 px/mm at z = 100 mm
        spheres = [{"center": [-8.0, 1.0, 100.0], "radius": 8.0}, {"center": [9.0, -6.0, 96.0], "radius": 4.5}]
        boxes = [{"center": [10.0, 6.5, 104.0], "half": [4.5, 4.5, 4.5], "rot_y": 30.0}]
        light = np.array([0.45, 0.55, 1.0])
        return {"focal_px": f, "medium": "marble", "boxes": boxes, "spheres": spheres, "blocker": None,
                "lights": [{"direction_of_travel": light.tolist(), "irradiance": math.pi}]}
    if name == "skin_backlit":
        f = 2.5 * 100.0  # 2.5 px/mm at the front faces (z = 100 mm)
        boxes = [{"center": [x, 0.0, 100.0 + t / 2], "half": [8.0, 18.0, t / 2], "rot_y": 0.0, "thickness": t}
                 for x, t in ((-20.0, 1.0), (0.0, 2.0), (20.0, 4.0))]
        light = np.array([0.3, 0.0, -1.0])  # from behind, travelling towards the camera, 17 degrees off the axis
        return {"focal_px": f, "medium": "skin1", "boxes": boxes, "spheres": [], "blocker": None,
                "lights": [{"direction_of_travel": light.tolist(), "irradiance": math.pi}]}
    if name == "skin_occlusion":
        # a skin2 sphere 25 mm in front of a skin2 wall, lit from the upper left and the front: its silhouette
        # occludes the lit wall, and its shadow falls on the wall beside it (what depth-aware passes must not bleed
        # across); 5.7 px/mm at the sphere's front (z = 70 mm), 3.8 px/mm on the wall (z = 105 mm)
        f = 400.0
        spheres = [{"center": [-2.0, -1.0, 80.0], "radius": 10.0}]
        boxes = [{"center": [0.0, 0.0, 115.0], "half": [100.0, 100.0, 10.0], "rot_y": 0.0}]
        light = np.array([0.5, 0.35, 1.0])
        return {"focal_px": f, "medium": "skin2", "boxes": boxes, "spheres": spheres, "blocker": None,
                "lights": [{"direction_of_travel": light.tolist(), "irradiance": math.pi}]}
    raise SystemExit(f"unknown scene {name!r}")


SCENES = ("skin_closeup", "skin_backlit", "marble_objects", "skin_occlusion")
# truth samples per pixel and channel (each channel is its own render): 1-2 CPU minutes per scene
SPP = {"skin_closeup": 64, "marble_objects": 128, "skin_backlit": 256, "skin_occlusion": 128}


def _mitsuba_scene(mi, spec: dict, *, truth: bool, spp: int, seed: int, channel: int = 0):
    T = mi.ScalarTransform4f
    med = _medium(spec["medium"])
    s = np.asarray(med["sigma_s_prime_per_mm"])
    a = np.asarray(med["sigma_a_per_mm"])
    sigma_t = s + a
    if truth:
        # index-matched: a null boundary, so that next-event estimation reaches the directional light from inside
        # the medium (through a smooth dielectric a delta light is never reached by a scattered path)
        bsdf = {"type": "null"}
        # one channel's medium, grey: with an RGB medium volpath samples distances by one channel and weights the
        # others by ratios of transmittances, which for skin1 (sigma_t 0.77 vs 1.49 /mm) leaves fireflies of 1e3
        interior = {"type": "homogeneous", "sigma_t": 1.0, "albedo": float(s[channel] / sigma_t[channel]),
                    "scale": float(sigma_t[channel]),
                    "phase": {"type": "isotropic"}}
        integrator = {"type": "volpath", "max_depth": 100000, "rr_depth": 100000}
    else:
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
        interior = None
        integrator = {"type": "path", "max_depth": 16}
    d: dict = {"type": "scene", "integrator": integrator,
               "sensor": {"type": "perspective", "fov": math.degrees(2 * math.atan(W / 2 / spec["focal_px"])),
                          "fov_axis": "x", "near_clip": 1.0, "far_clip": 1000.0,
                          "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, -1, 0]),
                          "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                                   "pixel_format": "rgb"},
                          "sampler": {"type": "independent", "sample_count": spp, "seed": seed}}}

    def obj(shape: dict) -> dict:
        shape["bsdf"] = bsdf
        if interior is not None:
            shape["interior"] = interior
        return shape

    for i, sp in enumerate(spec["spheres"]):
        d[f"sphere{i}"] = obj({"type": "sphere", "center": sp["center"], "radius": sp["radius"]})
    for i, bx in enumerate(spec["boxes"]):
        m = T().translate(bx["center"]) @ T().rotate(axis=[0, 1, 0], angle=bx["rot_y"]) @ T().scale(bx["half"])
        d[f"box{i}"] = obj({"type": "cube", "to_world": m})
    if spec["blocker"] is not None:
        b = spec["blocker"]
        cx, cy = sum(b["x"]) / 2, sum(b["y"]) / 2
        hx, hy = (b["x"][1] - b["x"][0]) / 2, (b["y"][1] - b["y"][0]) / 2
        d["blocker"] = {"type": "rectangle", "flip_normals": False,
                        "to_world": T().translate([cx, cy, b["z"]]) @ T().scale([hx, hy, 1.0]),
                        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}
    for i, li in enumerate(spec["lights"]):
        d[f"light{i}"] = {"type": "directional", "direction": li["direction_of_travel"],
                          "irradiance": {"type": "rgb", "value": [li["irradiance"]] * 3}}
    return mi.load_dict(d)


def cast(spec: dict) -> dict[str, np.ndarray]:
    """Planar depth, camera-space normal, object id and thickness at each pixel centre (analytic ray casting)."""
    f = spec["focal_px"]
    xs = (np.arange(W) + 0.5 - W / 2) / f
    ys = (np.arange(H) + 0.5 - H / 2) / f
    dirs = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], np.ones((H, 1))), -1)  # z = 1: t is planar depth
    best = np.full((H, W), np.inf)
    normal = np.zeros((H, W, 3))
    normal[..., 2] = -1.0
    thickness = np.zeros((H, W))
    for sp in spec["spheres"]:
        c, r = np.asarray(sp["center"]), sp["radius"]
        b = dirs @ c
        a = np.sum(dirs * dirs, -1)
        disc = b * b - a * (c @ c - r * r)
        t = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
        hit = (t > 0) & (t < best)
        p = dirs * t[..., None]
        n = (p - c) / r
        best = np.where(hit, t, best)
        normal = np.where(hit[..., None], n, normal)
    for bx in spec["boxes"]:
        R = _rot_y(bx["rot_y"])
        c, half = np.asarray(bx["center"]), np.asarray(bx["half"])
        o_l = R.T @ (-c)  # ray origin (the camera, at 0) in the box frame
        d_l = dirs @ R  # R.T applied to each direction
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - o_l) / d_l
            t2 = (half - o_l) / d_l
        tmin = np.minimum(t1, t2)
        tnear = tmin.max(-1)
        tfar = np.maximum(t1, t2).min(-1)
        hit = (tnear <= tfar) & (tnear > 0) & (tnear < best)
        axis = tmin.argmax(-1)
        n_l = np.zeros((H, W, 3))
        np.put_along_axis(n_l, axis[..., None], -np.sign(np.take_along_axis(d_l, axis[..., None], -1)), -1)
        best = np.where(hit, tnear, best)
        normal = np.where(hit[..., None], n_l @ R.T, normal)
        if "thickness" in bx:
            thickness = np.where(hit, bx["thickness"], thickness)
    ids = np.isfinite(best).astype(np.float64)
    normal = np.where(ids[..., None] > 0, normal, np.array([0.0, 0.0, -1.0]))
    return {"depth": best, "normal": normal, "id": ids, "thickness": thickness}


def _cached_material(sidecar: pathlib.Path, medium: str) -> dict | None:
    """The material of an earlier run of the same medium (the Monte Carlo is seeded: the same numbers again)."""
    try:
        meta = json.loads(sidecar.read_text())
    except (OSError, ValueError):
        return None
    same = meta.get("medium", {}).get("name") == medium and meta.get("medium", {}).get("eta") == ETA
    return meta["material"] if same and "slab_table" in meta.get("material", {}) else None


def render(name: str, out: pathlib.Path, spp: int, spp_irradiance: int, seed: int = 0) -> None:
    from sss_jax._io import write_exr, write_json_atomic

    mi = _mitsuba()
    spec = scene_spec(name)
    geo = cast(spec)
    t0 = time.perf_counter()
    irr = np.asarray(mi.render(_mitsuba_scene(mi, spec, truth=False, spp=spp_irradiance, seed=seed)), np.float64)
    t1 = time.perf_counter()
    truth = np.stack([np.asarray(mi.render(_mitsuba_scene(mi, spec, truth=True, spp=spp, seed=seed + 1 + c,
                                                          channel=c)), np.float64)[..., c] for c in range(3)], -1)
    t2 = time.perf_counter()
    mat = _cached_material(out / f"{name}_buffers.json", spec["medium"]) or _index_matched_material(spec["medium"])
    sss = geo["id"] > 0
    albedo = np.where(sss[..., None], np.asarray(mat["albedo"]), 0.0)
    chans = {"R": irr[..., 0], "G": irr[..., 1], "B": irr[..., 2], "Z": geo["depth"],
             "N.X": geo["normal"][..., 0], "N.Y": geo["normal"][..., 1], "N.Z": geo["normal"][..., 2],
             "albedo.R": albedo[..., 0], "albedo.G": albedo[..., 1], "albedo.B": albedo[..., 2], "id": geo["id"]}
    if any("thickness" in b for b in spec["boxes"]):
        chans["thickness"] = geo["thickness"]
    out.mkdir(parents=True, exist_ok=True)
    attrs = {"sss_jax:focal_px": spec["focal_px"], "sss_jax:mm_per_unit": 1.0}
    write_exr(out / f"{name}_buffers.exr", chans, half=True, attributes=attrs)
    write_exr(out / f"{name}_truth.exr", truth.astype(np.float32), half=True, attributes=attrs)
    # lights in camera space as sss_jax states them: the direction towards the light, irradiance as E / pi (the
    # radiance of a white Lambertian surface facing it)
    lights = [{"direction_to_light": (-np.asarray(li["direction_of_travel"]) /
                                      np.linalg.norm(li["direction_of_travel"])).tolist(),
               "colour": [li["irradiance"] / math.pi] * 3} for li in spec["lights"]]
    med = _medium(spec["medium"])
    meta = {"renderer": f"Mitsuba {mi.__version__} scalar_rgb", "scene": name, "resolution": [W, H],
            "camera": {"focal_px": spec["focal_px"], "location": [0, 0, 0], "forward": [0, 0, 1], "down": [0, 1, 0]},
            "scene_unit_mm": 1.0, "lights": lights,
            "medium": {**med, "eta": ETA, "phase": "isotropic (reduced coefficients)"},
            "material": mat, "geometry": {k: spec[k] for k in ("spheres", "boxes", "blocker")},
            "truth": {"integrator": "volpath, one grey render per channel", "spp_per_channel": spp, "seconds": round(t2 - t1, 1)},
            "irradiance": {"integrator": "path, white diffuse (reflectance 1)", "max_depth": 16,
                           "spp": spp_irradiance, "seconds": round(t1 - t0, 1)}}
    write_json_atomic(out / f"{name}_buffers.json", meta)
    print(f"{name}: irradiance {t1 - t0:.1f} s, truth {t2 - t1:.1f} s ({spp} spp)", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", action="append", choices=SCENES, help="scene(s) to render (default: all)")
    ap.add_argument("--spp", type=int, default=None,
                    help="samples per pixel of the path-traced truth (default: each scene's own, SPP)")
    ap.add_argument("--spp-irradiance", type=int, default=64, help="samples per pixel of the white diffuse pass")
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "tests" / "data" / "mitsuba")
    args = ap.parse_args(argv)
    for name in args.scene or SCENES:
        render(name, args.out, args.spp or SPP[name], args.spp_irradiance)


if __name__ == "__main__":
    main()
