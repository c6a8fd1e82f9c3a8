"""One preset and all presets: sources -> Monte Carlo -> fits -> errors -> engine blocks and taps -> ``fits/*.json``."""

from __future__ import annotations

import json
import os
import pathlib
import sys
import time
from collections.abc import Callable, Iterable
from importlib import resources
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._version import __version__
from .._fitting import (
    RENDERED_PIXEL_PER_D,
    fit_sta,
    fit_two_gaussian_profile,
    fit_two_gaussian_to_burley,
)
from .._io import SSSInputError, check_output_folder, write_bytes_atomic
from .._kernels import _check_taps, two_gaussian_kernel
from .._montecarlo import to_tabulated_profile
from .._presets import preset_from_data
from .._profiles import scaling_searchlight
from ._errors import _burley_vs_mc, engine_errors, image_errors, kernel_errors, profile_errors, sta_errors
from ._files import plot_preset, write_presets_readme
from ._references import fit_burley_d, montecarlo_medium_slabs, montecarlo_profiles, montecarlo_slabs
from ._sources import (
    check_preset_name,
    ARTIST_MATERIALS,
    DEFAULT_PHOTONS,
    MEDIUM_SLAB_PHOTONS_FRACTION,
    SLAB_PHOTONS_FRACTION,
    material_source,
    measured_materials,
)

# ------------------------------------------------------------------------------------------------------------------
# engine export
# ------------------------------------------------------------------------------------------------------------------


def export_taps(name: str, tg: dict, *, taps: int = 25) -> dict[str, Any]:
    """The two-Gaussian kernel as Jimenez's ``float4(weight_r, weight_g, weight_b, offset)`` taps, centre first,
    offsets in mm (multiply by the pixels per mm at the surface, as ``sssWidth`` does in the reference shader)."""
    k = two_gaussian_kernel(jnp.asarray(tg["w"]), jnp.asarray(tg["sigma_near_mm"]), jnp.asarray(tg["sigma_far_mm"]),
                            taps=taps)
    off = np.asarray(k.offsets_mm, np.float64)
    wts = np.asarray(k.weights, np.float64)
    ident = "".join(ch if ch.isalnum() else "_" for ch in name)
    rows = [f"{wts[i, 0]:.8f}, {wts[i, 1]:.8f}, {wts[i, 2]:.8f}, {off[i]:.8f}" for i in range(taps)]
    hlsl = (f"// sss_jax {__version__}: {name}, two-Gaussian kernel, {taps} taps (rgb weights, offset mm), centre first\n"
            f"static const float4 kernel_{ident}[{taps}] = {{\n" + ",\n".join(f"    float4({r})" for r in rows) + "\n};")
    glsl = (f"// sss_jax {__version__}: {name}, two-Gaussian kernel, {taps} taps (rgb weights, offset mm), centre first\n"
            f"const vec4 kernel_{ident}[{taps}] = vec4[{taps}](\n" + ",\n".join(f"    vec4({r})" for r in rows) + "\n);")
    return {"taps": taps, "layout": "float4(weight_r, weight_g, weight_b, offset_mm), centre tap first",
            "offsets_mm": off.tolist(), "weights": wts.tolist(), "hlsl": hlsl, "glsl": glsl}


# ------------------------------------------------------------------------------------------------------------------
# one preset, all presets
# ------------------------------------------------------------------------------------------------------------------


def _strip(fit_block: dict) -> tuple[dict, dict]:
    params = {k: v for k, v in fit_block.items() if k != "fit"}
    return params, fit_block["fit"]


def fit_preset(name: str, *, photons: int = DEFAULT_PHOTONS, seed: int = 0, solver: str = "optimistix",
               taps: int = 25, cache_dir: str | os.PathLike | None = None, measured_csv=None,
               artist: dict | None = None, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Everything a preset holds, for a measured material, a built-in artist material, or ``artist`` =
    ``{"albedo": (3,), "d_mm": (3,)}`` under a new ``name``. Fits and errors run in float64."""
    with jax.enable_x64(True):
        return _fit_preset(name, photons=photons, seed=seed, solver=solver, taps=taps, cache_dir=cache_dir,
                           measured_csv=measured_csv, artist=artist, log=log)


def _fit_preset(name, *, photons, seed, solver, taps, cache_dir, measured_csv, artist, log) -> dict[str, Any]:
    from ..engines import engine_blocks

    log = log or (lambda s: None)
    t_start = time.perf_counter()
    source = material_source(name, measured_csv=measured_csv, artist=artist)
    medium = source["medium"]
    mfp = np.asarray(medium["mean_free_path_mm"])

    cache = pathlib.Path(cache_dir) if cache_dir is not None else None
    profiles, prov = montecarlo_profiles(name, medium, photons=photons, seed=seed, cache_dir=cache, log=log)
    A_mc = np.asarray([p.total_reflectance for p in profiles])
    d_searchlight = mfp / np.asarray(scaling_searchlight(A_mc))
    burley_fit = None
    if source["kind"] == "artist":
        albedo, d = np.asarray(source["albedo"]), np.asarray(source["d_mm"])
    else:
        # the searchlight s(A) was fitted to index-matched media; with the eta 1.3 boundary internal reflection
        # widens the profile, so the d that best matches the transport is fitted to it, from mfp / s(A)
        albedo = A_mc
        fits = [fit_burley_d(p, float(m), float(d0), solver=solver) for p, m, d0 in zip(profiles, mfp, d_searchlight)]
        d = np.asarray([f["d_mm"] for f in fits])
        burley_fit = {"solver": solver, "objective": "1D radial ||r (R_burley(d) - R_mc)|| / ||r R_mc||, unit-energy "
                      "profiles, from d = mfp / s_searchlight(A)",
                      "outcome": "successful" if all(f["outcome"] == "successful" for f in fits) else
                      ";".join(f["outcome"] for f in fits),
                      "iterations": [f["iterations"] for f in fits],
                      "seconds": round(sum(f["seconds"] for f in fits), 3),
                      "error_relative_l2": [f["error_relative_l2"] for f in fits],
                      "error_relative_l2_searchlight": [_burley_vs_mc(p, float(m), float(d0))
                                                        for p, m, d0 in zip(profiles, mfp, d_searchlight)]}
    slab = montecarlo_slabs(name, medium, d, photons=photons, seed=seed, cache_dir=cache, log=log)
    medium_slab = montecarlo_medium_slabs(name, medium, photons=photons, seed=seed, cache_dir=cache, log=log)
    mc = {"profiles": profiles, "slab": slab, "provenance": {**prov, "slab": slab["provenance"]}}
    mc_profile = to_tabulated_profile(profiles, mfp.tolist())

    log(f"  fitting {name}: two-Gaussian to Burley and to Monte Carlo, STA to slab transmission ({solver})")
    tg_b, fit_tg_b = _strip(fit_two_gaussian_to_burley(d, solver=solver))
    tg_m, fit_tg_m = _strip(fit_two_gaussian_profile(mc_profile, pixel_mm=RENDERED_PIXEL_PER_D * d, solver=solver))
    sta, fit_sta_rec = _strip(fit_sta(d, solver=solver))

    errors = {
        "profile": {"metric": "1D radial ||r (R_model - R_ref)|| / ||r R_ref|| on the Monte Carlo bins, profiles of "
                              "unit energy; two-Gaussian as the azimuthal average of a_m(x) a_m(y)", "per_channel": True,
                    **profile_errors(d, mc["profiles"], mfp, tg_b, tg_m),
                    "two_gaussian_fit_objective": fit_tg_b["error_relative_l2"]},
        "kernel": kernel_errors(d, mc_profile, tg_b, tg_m),
        "image": image_errors(albedo, d, mc_profile, tg_b, tg_m, taps=taps),
        "sta": {**sta_errors(sta, d, mc["slab"]), "fit_objective": fit_sta_rec["error_relative_l2"]},
        "engines": engine_errors(albedo, d, mc_profile, A_mc),
        "albedo": {"metric": "Monte Carlo total diffuse reflectance (pencil beam) against the preset's albedo A",
                   "montecarlo": A_mc.tolist(),
                   "montecarlo_stderr": [p.total_reflectance_stderr for p in mc["profiles"]],
                   "capped_weight": [p.capped_weight for p in mc["profiles"]]},
    }
    preset = {
        "name": name,
        "source": source,
        "albedo": albedo.tolist(),
        "burley": {"d_mm": d.tolist(), "d_searchlight_mm": d_searchlight.tolist(), "mean_free_path_mm": mfp.tolist(),
                   "d_rule": "artist's d" if burley_fit is None else
                   "fitted to the Monte Carlo profile (r R(r) least squares) from mfp / s_searchlight(A)"},
        "separable": {"two_gaussian": tg_b, "two_gaussian_montecarlo": tg_m, "export": export_taps(name, tg_b, taps=taps)},
        "sta": sta,
        "transmittance": {
            "model": "total transmittance (unscattered + scattered) of a slab of the preset's medium (source.medium: "
                     "isotropic with the reduced coefficients, its eta on both faces) under a normal back light, by "
                     "the Monte Carlo walk; thickness_mm per channel (tau_nodes mean free paths, and 0); "
                     "translucency(model='slab') interpolates log T linearly in t",
            **{k: medium_slab[k] for k in ("eta", "tau_nodes", "thickness_mm", "T", "T_stderr", "resolved")},
            "photons": medium_slab["provenance"]["photons"]},
        "errors": errors,
        "fit": {**({"burley": burley_fit} if burley_fit else {}), "two_gaussian": fit_tg_b, "two_gaussian_montecarlo": fit_tg_m, "sta": fit_sta_rec,
                "solver": solver, "seconds": round(time.perf_counter() - t_start, 3)},
        "montecarlo": {**mc["provenance"], "cache": f"montecarlo/{name}.json"},
        "engines": engine_blocks(albedo, d),
        "version": __version__,
    }
    return preset


def _json_bytes(data: Any) -> bytes:
    return (json.dumps(data, indent=2) + "\n").encode()


# the fewest photons a preset's fit takes: its slab and medium runs get a fifth and a tenth of them each, and a Monte
# Carlo run needs two (its standard error)
LEAST_PHOTONS = 2 * max(SLAB_PHOTONS_FRACTION, MEDIUM_SLAB_PHOTONS_FRACTION)


def fit_presets(names: Iterable[str] | None = None, *, out_dir: str | os.PathLike = "fits",
                photons: int = DEFAULT_PHOTONS, seed: int = 0, solver: str = "optimistix", taps: int = 25,
                plots: bool = True, readme: bool = True, measured_csv=None,
                artist: dict[str, dict] | None = None, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Fit and write ``out_dir/<name>.json`` for each material (default: all measured and artist materials) and the
    schema, plots and README; a material whose fit fails is reported and the others go on. Returns
    ``{"written": [paths], "failed": {name: message}}``. What the caller gave wrong (an unknown name, a material's
    values, an output folder that cannot be one) is an ``SSSInputError`` before any work, and nothing is written."""
    log = log or (lambda s: print(s, file=sys.stderr, flush=True))
    artist = dict(artist or {})
    for name in artist:  # before any work: the name is a file of out_dir (and of its Monte Carlo cache)
        check_preset_name(name)
    if not isinstance(photons, (int, np.integer)) or photons < LEAST_PHOTONS:
        raise ValueError(f"photons must be an integer >= {LEAST_PHOTONS} (the medium's slabs run photons / "
                         f"{MEDIUM_SLAB_PHOTONS_FRACTION} each, and a Monte Carlo run needs 2), got {photons!r}")
    _check_taps(taps)  # the exported kernel has a centre tap
    out = pathlib.Path(out_dir)
    check_output_folder(out, "out_dir")
    todo = list(names) if names is not None else (sorted(measured_materials(measured_csv)) + sorted(ARTIST_MATERIALS))
    todo += [n for n in artist if n not in todo]
    known = set(measured_materials(measured_csv)) | set(ARTIST_MATERIALS) | set(artist)
    unknown = [name for name in todo if name not in known]
    if unknown:
        raise SSSInputError(f"unknown material(s) {', '.join(map(repr, unknown))}; known: {', '.join(sorted(known))}")
    for name in todo:  # the materials' own values: their errors are the input's, found before any fit
        try:
            material_source(name, measured_csv=measured_csv, artist=artist.get(name))
        except ValueError as exc:  # (its message names the material)
            raise SSSInputError(str(exc)) from None
    out.mkdir(parents=True, exist_ok=True)
    written, failed = [], {}
    for i, name in enumerate(todo, 1):
        log(f"[{i}/{len(todo)}] {name}")
        try:
            preset = fit_preset(name, photons=photons, seed=seed, solver=solver, taps=taps,
                                cache_dir=out / "montecarlo", measured_csv=measured_csv, artist=artist.get(name),
                                log=log)
            # what it writes must load: a fit that gives a preset load_preset refuses fails (a Monte Carlo of too
            # few photons leaves the medium's transmission unresolved) instead of replacing a good one
            path = out / f"{name}.json"
            data = _json_bytes(preset)
            preset_from_data(json.loads(data), path)
        except (SSSInputError, ValueError, ArithmeticError, RuntimeError) as exc:
            failed[name] = f"{type(exc).__name__}: {exc}"
            if photons < DEFAULT_PHOTONS:
                failed[name] += f" (with {photons} photons; the default is {DEFAULT_PHOTONS})"
            log(f"  failed: {failed[name]}")
            continue
        write_bytes_atomic(path, data)
        written.append(str(path))
        log(f"  wrote {path} ({preset['fit']['seconds']:.1f} s)")
        if plots:
            plot_preset(preset, out)
    schema = resources.files("sss_jax").joinpath("data/preset.schema.json").read_bytes()
    write_bytes_atomic(out / "schema.json", schema)
    if readme:
        write_presets_readme(out)
    return {"written": written, "failed": failed}
