"""The built-in demo: the procedural scene rendered with every technique, timed and compared with the reference."""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax
import numpy as np

from ._materials import BurleyMaterial, STAParams, TwoGaussianMaterial
from ._scene import DemoScene, demo_scene
from ._techniques import ENERGY_CONSERVING, burley, reference, separable, translucency

__all__ = ["DEMO_MATERIALS", "DemoResult", "run_demo", "demo_two_gaussian"]

# Artist-style materials of the demo scene (surface albedo, Burley d in mm per channel), ids 1..3. The scattering
# distances are exaggerated for a scene of a few centimetres so the effect is visible at 256 px.
DEMO_MATERIALS = {
    "skin": dict(albedo=(0.80, 0.55, 0.45), d_mm=(3.0, 1.4, 0.8)),
    "marble": dict(albedo=(0.83, 0.79, 0.75), d_mm=(2.2, 1.9, 1.6)),
    "wax": dict(albedo=(0.85, 0.70, 0.45), d_mm=(3.5, 2.4, 1.4)),
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


def _timed(fn: Callable[[], jax.Array], repeats: int) -> tuple[np.ndarray, float, float]:
    t0 = time.perf_counter()
    out = fn().block_until_ready()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn().block_until_ready()
        times.append(time.perf_counter() - t0)
    best = float(np.median(times)) if times else first
    return np.asarray(out), best, max(first - best, 0.0)


def run_demo(*, height: int = 192, width: int = 256, samples: int = 32, taps: int = 25, repeats: int = 2,
             progress: Callable[[str], None] | None = None) -> DemoResult:
    """Render the demo scene with every technique; time each (median of ``repeats`` after a compile run)."""
    say = progress or (lambda msg: None)
    scene = demo_scene(height, width)
    b, cam = scene.buffers, scene.camera
    mat = demo_burley_material()
    tg = demo_two_gaussian()
    sta = STAParams(**DEMO_STA)
    runs: dict[str, Callable[[], jax.Array]] = {
        "reference": lambda: reference(b, mat, cam),
        f"burley_{samples}": lambda: burley(b, mat, cam, samples=samples),
        f"separable_preintegrated_{taps}": lambda: separable(b, mat, cam, taps=taps),
        f"separable_two_gaussian_{taps}": lambda: separable(b, tg, cam, taps=taps),
        "sta": lambda: translucency(b, sta, cam, scene.back_light),
    }
    mask = np.asarray(b.material_id) > 0
    albedo = np.asarray(b.albedo)
    irr = np.asarray(b.irradiance)
    local = albedo * irr
    images, seconds, compile_s = {}, {}, {}
    for name, fn in runs.items():
        say(f"rendering {name} ...")
        img, seconds[name], compile_s[name] = _timed(fn, 0 if name == "reference" else repeats)
        # the passes leave pixels without SSS untouched (irradiance); shade them locally for a finished picture
        images[name] = np.where(mask[..., None], img, local)
    images["irradiance"] = irr
    images["local"] = local
    ref = images["reference"]
    errors, energy = {}, {}
    for name, img in images.items():
        if name == "irradiance":
            continue
        errors[name] = float(np.linalg.norm((img - ref)[mask]) / np.linalg.norm(ref[mask]))
        scattered = img / np.where(albedo > 0, albedo, 1)
        energy[name] = scattered[mask].sum(0) / irr[mask].sum(0)
    return DemoResult(scene=scene, images=images, seconds=seconds, compile_seconds=compile_s, errors=errors,
                      energy=energy)


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
