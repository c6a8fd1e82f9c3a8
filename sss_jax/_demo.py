"""The built-in demo: the procedural scene rendered with every technique, timed and compared with the reference."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ._materials import BurleyMaterial, STAParams, TwoGaussianMaterial
from ._metrics import rel_l2
from ._scene import DemoScene, demo_scene
from ._techniques import ENERGY_CONSERVING, AbstractTechnique, Burley, Reference, Separable, Translucency
from ._timing import time_call

__all__ = ["DEMO_MATERIALS", "DemoResult", "run_demo", "demo_two_gaussian", "demo_trade", "demo_montecarlo",
           "demo_report_data"]

# Artist-style materials of the demo scene (surface albedo, Burley d in mm per channel), ids 1..3. The scattering
# distances are exaggerated for a scene of a few centimetres so the effect is visible at 256 px. Their names are their
# own ("demo_skin" is not the preset "skin"): one name, one material, in every command.
DEMO_MATERIALS = {
    "demo_skin": dict(albedo=(0.80, 0.55, 0.45), d_mm=(3.0, 1.4, 0.8)),
    "demo_marble": dict(albedo=(0.83, 0.79, 0.75), d_mm=(2.2, 1.9, 1.6)),
    "demo_wax": dict(albedo=(0.85, 0.70, 0.45), d_mm=(3.5, 2.4, 1.4)),
}

# STA parameters for the demo's back light (Barré-Brisebois & Bouchard's defaults are of this order)
DEMO_STA = dict(distortion=0.2, power=4.0, scale=(1.0, 0.8, 0.6), ambient=(0.05, 0.04, 0.03),
                thickness_mm=(6.0, 3.5, 2.0))


def demo_burley_material(dtype=np.float32) -> BurleyMaterial:
    rows = list(DEMO_MATERIALS.values())
    return BurleyMaterial(albedo=np.asarray([r["albedo"] for r in rows], dtype),
                          d_mm=np.asarray([r["d_mm"] for r in rows], dtype))


def demo_two_gaussian(dtype=np.float32) -> TwoGaussianMaterial:
    """Two-Gaussian kernels for the demo materials, fitted to each Burley profile in profile space
    (``_fitting.fit_two_gaussian_to_burley``; Burley profiles share one shape, so one fit per material)."""
    from ._fitting import fit_two_gaussian_to_burley

    mat = demo_burley_material(np.float64)
    fits = [fit_two_gaussian_to_burley(np.asarray(mat.d_mm[i])) for i in range(mat.count)]
    return TwoGaussianMaterial(
        albedo=np.asarray(mat.albedo, dtype),
        w=np.asarray([f["w"] for f in fits], dtype),
        sigma_near_mm=np.asarray([f["sigma_near_mm"] for f in fits], dtype),
        sigma_far_mm=np.asarray([f["sigma_far_mm"] for f in fits], dtype),
    )


@dataclasses.dataclass
class DemoResult:
    scene: DemoScene
    images: dict[str, np.ndarray]
    seconds: dict[str, float]
    compile_seconds: dict[str, float]
    errors: dict[str, float]  # relative L2 against the reference over SSS pixels
    energy: dict[str, np.ndarray]  # output / input energy per channel over SSS pixels (albedo divided out)
    # the images that are technique runs (the reference aside): image name -> (the report's label of the run, count
    # or None, whether the technique conserves energy)
    runs: dict[str, tuple[str, int | None, bool]] = dataclasses.field(default_factory=dict)


def run_demo(*, height: int = 192, width: int = 256, samples: int = 32, taps: int = 25, repeats: int = 2,
             progress: Callable[[str], None] | None = None) -> DemoResult:
    """Render the demo scene with every technique; time each (median of ``repeats`` after a compile run)."""
    say = progress or (lambda msg: None)
    scene = demo_scene(height, width)
    b, cam = scene.buffers, scene.camera
    mat = demo_burley_material()
    tg = demo_two_gaussian()
    sta = STAParams(**DEMO_STA)
    # image name -> (technique, its material, the report's label of the run); the reference first, timed once (it
    # is slow by design). The two-Gaussian separable keeps a label of its own beside the pre-integrated one.
    runs: dict[str, tuple[AbstractTechnique, object, str]] = {
        f"burley_{samples}": (Burley(samples=samples), mat, "burley"),
        f"separable_preintegrated_{taps}": (Separable(taps=taps), mat, "separable"),
        f"separable_two_gaussian_{taps}": (Separable(taps=taps), tg, "separable_two_gaussian"),
        "sta": (Translucency(scene.back_light), sta, "sta"),
    }
    mask = np.asarray(b.material_id) > 0
    albedo = np.asarray(b.albedo)
    irr = np.asarray(b.irradiance)
    local = albedo * irr
    images, seconds, compile_s = {}, {}, {}
    timed = [("reference", Reference(), mat, 0)] + [(name, t, m, repeats) for name, (t, m, _) in runs.items()]
    for name, technique, material, reps in timed:
        say(f"rendering {name} ...")
        img, seconds[name], compile_s[name] = time_call(lambda: technique(b, material, cam), reps)
        # the passes leave pixels without SSS untouched (irradiance); shade them locally for a finished picture
        images[name] = np.where(mask[..., None], img, local)
    images["irradiance"] = irr
    images["local"] = local
    ref = images["reference"]
    errors, energy = {}, {}
    for name, img in images.items():
        if name == "irradiance":
            continue
        errors[name] = rel_l2(img, ref, mask=mask)
        scattered = img / np.where(albedo > 0, albedo, 1)
        energy[name] = scattered[mask].sum(0) / irr[mask].sum(0)
    counts = {name: (label, None if t.count_option is None else int(getattr(t, t.count_option)), t.conserves_energy)
              for name, (t, _, label) in runs.items()}
    return DemoResult(scene=scene, images=images, seconds=seconds, compile_seconds=compile_s, errors=errors,
                      energy=energy, runs=counts)


def summary_rows(result: DemoResult) -> list[dict]:
    rows = []
    for name in result.images:
        if name in ("irradiance",):
            continue
        family = name.split("_")[0]
        rows.append(dict(
            technique=name,
            ms_per_frame=round(1e3 * result.seconds[name], 2) if name in result.seconds else None,
            compile_s=round(result.compile_seconds[name], 2) if name in result.compile_seconds else None,
            rel_l2_vs_reference=round(result.errors[name], 5),
            energy_ratio_rgb=[round(float(x), 4) for x in result.energy[name]],
            conserves_energy=ENERGY_CONSERVING.get(family, None) if family != "local" else True,
        ))
    return rows


def demo_trade(result: DemoResult, *, taps=(9, 17, 25), samples=(8, 16, 32, 64), repeats: int = 2) -> list:
    """Time and images of STA and of a few tap and sample counts on the demo frame (the report's trade), as
    ``TechniqueRun``s; the separable runs use the pre-integrated Burley kernel."""
    from ._report import TechniqueRun

    scene = result.scene
    b, cam = scene.buffers, scene.camera
    mat = demo_burley_material()
    mask = np.asarray(b.material_id) > 0
    local = result.images["local"]
    configs = [(Translucency(scene.back_light), STAParams(**DEMO_STA), None)]
    configs += [(Separable(taps=n), mat, n) for n in taps]
    configs += [(Burley(samples=n), mat, n) for n in samples]
    runs = []
    for technique, material, n in configs:
        img, seconds, _ = time_call(lambda: technique(b, material, cam), repeats)
        runs.append(TechniqueRun(technique.name, n, 1e3 * seconds, (np.where(mask[..., None], img, local),),
                                 conserves_energy=technique.conserves_energy))
    return runs


def demo_montecarlo(photons: int = 20_000, albedos=(0.5, 0.9, 0.99)) -> list[dict]:
    """Monte Carlo random walks (index-matched semi-infinite medium, normal pencil beam) beside Christensen-Burley
    with the memo's searchlight s(A), per single-scattering albedo: ``r`` (mean free paths), ``rR`` and its standard
    error, Burley's ``rR``, total reflectance, Burley's d (mean free paths) and the relative L2 between the curves."""
    from ._montecarlo import simulate
    from ._profiles import burley_R, d_from_mfp

    rows = []
    for alpha in albedos:
        mc = simulate(alpha, photons=photons, seed=5, bins=60, r_max_mfp=6.0)
        r = np.asarray(mc.r_mfp)
        d = float(d_from_mfp(mc.total_reflectance, 1.0, fit="searchlight"))
        rr_b = r * mc.total_reflectance * np.asarray(burley_R(r, d))
        rows.append(dict(albedo=alpha, total_reflectance=round(float(mc.total_reflectance), 4), d_mfp=round(d, 4),
                         rel_l2_rR=round(rel_l2(rr_b, r * mc.R), 4), r=r, rR=r * np.asarray(mc.R),
                         rR_stderr=r * np.asarray(mc.R_stderr), rR_burley=rr_b))
    return rows


def demo_report_data(result: DemoResult, trade=()):
    """The demo as ``ReportData``: the demo's own runs (reference, Burley, both separable kernels, STA) and the trade's
    runs (``demo_trade``), with the demo's inputs, materials and machine."""
    from ._machine import machine_info
    from ._report import FrameImages, ReportData, TechniqueRun

    b = result.scene.buffers
    h, w = np.asarray(b.depth).shape
    ms = lambda name: 1e3 * result.seconds[name]
    runs, seen = [], set()
    for name, (tech, count, conserves) in result.runs.items():
        runs.append(TechniqueRun(tech, count, ms(name), (result.images[name],), conserves_energy=conserves))
        seen.add((tech, count))
    runs += [r for r in trade if (r.technique, r.count) not in seen]
    runs.sort(key=lambda r: (r.technique, r.count or 0))
    frame = FrameImages(name="demo scene", shaded=result.images["local"], reference=result.images["reference"],
                        material_id=np.asarray(b.material_id),
                        mask=np.isfinite(np.asarray(b.depth)) & (np.asarray(b.material_id) > 0))
    cam = result.scene.camera
    material = {"names": list(DEMO_MATERIALS), **{k: [m[k] for m in DEMO_MATERIALS.values()] for k in ("albedo", "d_mm")},
                "separable_kernel": "pre-integrated Burley (separable), two-Gaussian fit (separable_two_gaussian)",
                "sta": DEMO_STA}
    inputs = [{"name": "procedural demo scene", "width": w, "height": h, "focal_px": float(cam.focal_px),
               "mm_per_unit": float(cam.mm_per_unit), "sss_pixels": int(frame.mask.sum())}]
    return ReportData(frames=(frame,), runs=tuple(runs), inputs=inputs, material=material, machine=machine_info(),
                      title="sss_jax demo: techniques against the reference",
                      reference_run=TechniqueRun("reference", None, ms("reference"), (result.images["reference"],)))
