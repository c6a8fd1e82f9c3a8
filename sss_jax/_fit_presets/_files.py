"""What the presets look like to people: a profile plot per preset, the tables of fits/README.md and the report."""

from __future__ import annotations

import json
import os
import pathlib
from typing import Any

import numpy as np

from .._io import write_bytes_atomic
from .._profiles import burley_R
from ._errors import _radial_two_gaussian

# ------------------------------------------------------------------------------------------------------------------
# pictures and the table
# ------------------------------------------------------------------------------------------------------------------


def plot_preset(preset: dict, out_dir: pathlib.Path) -> pathlib.Path:
    """``plots/<name>.png``: r R(r) per channel of Monte Carlo (with its standard error), Burley and the two
    fitted two-Gaussian kernels, in the manner of the paper's Fig. 4."""
    from matplotlib.figure import Figure

    name = preset["name"]
    cache = json.loads((out_dir / preset["montecarlo"]["cache"]).read_text())
    # the preset's own mean free path: the cached profiles are per mean free path and serve every material of
    # that albedo, so the cache's length is the run's that simulated them, not necessarily this preset's
    mfp = np.asarray(preset["burley"].get("mean_free_path_mm", cache["mean_free_path_mm"]))
    d = np.asarray(preset["burley"]["d_mm"])
    fig = Figure(figsize=(12, 3.6), layout="constrained")  # a Figure of its own: no global matplotlib state
    axes = fig.subplots(1, 3)
    for c, ax in enumerate(axes):
        prof = cache["profiles"][c]
        r = np.asarray(prof["profile"]["r_mfp"]) * mfp[c]
        A = prof["total_reflectance"]
        # r R(r) in 1/mm of a unit-energy profile: rR in the cache is per mean free path
        rR = np.asarray(prof["profile"]["rR"]) / mfp[c] / A
        err = np.asarray(prof["profile"]["rR_stderr"]) / mfp[c] / A
        ax.errorbar(r, rR, yerr=err, fmt=".", ms=2, color="0.3", elinewidth=0.6, label="Monte Carlo (±1 s.e.)")
        ax.plot(r, r * np.asarray(burley_R(r, float(d[c]))), color="C3", label=f"Burley d={d[c]:.3g} mm")
        ax.plot(r, r * _radial_two_gaussian(preset["separable"]["two_gaussian"], r)[:, c], color="C0",
                label="two-Gaussian (fit to Burley)")
        ax.plot(r, r * _radial_two_gaussian(preset["separable"]["two_gaussian_montecarlo"], r)[:, c], "--",
                color="C2", label="two-Gaussian (fit to MC)")
        ax.set_xlim(0, float(min(r[-1], 12 * d[c])))
        ax.set_title(f"{name}: {'RGB'[c]}  A={preset['albedo'][c]:.3f}")
        ax.set_xlabel("r (mm)")
        ax.set_ylabel("r R(r) (1/mm)")
    axes[0].legend(fontsize=7)
    path = out_dir / "plots" / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, metadata={"Software": None})
    write_bytes_atomic(path, buf.getvalue())
    return path


def _triple_str(v, fmt="{:.3g}") -> str:
    return ", ".join(fmt.format(x) for x in v)


ENGINE_ORDER = ("cycles", "eevee", "hdrp", "unreal", "jimenez")


def load_presets(out_dir: str | os.PathLike, skipped: list[str] | None = None) -> list[dict]:
    """Every preset file in ``out_dir`` (not the schema), by name. With a ``skipped`` list, a file ``load_preset``
    refuses (one written before a fit checked what it writes, or edited by hand) is left out and its reason appended
    there instead of raising."""
    from .._presets import preset_from_data

    out = []
    for path in sorted(pathlib.Path(out_dir).glob("*.json")):
        if path.stem == "schema":
            continue
        if skipped is None:
            out.append(json.loads(path.read_text()))
            continue
        try:
            data = json.loads(path.read_text())
            preset_from_data(data, path)
        except ValueError as exc:  # (SSSInputError and JSON's errors are ValueErrors)
            skipped.append(f"{path.name}: {exc}")
            continue
        out.append(data)
    return out


def preset_rows(presets: list[dict]) -> list[dict[str, Any]]:
    """One summary row per preset: parameters and the errors of each cheap model against Burley and Monte Carlo."""
    rows = []
    for p in presets:
        e = p["errors"]
        rows.append({
            "preset": p["name"], "source": p["source"]["kind"], "albedo A": _triple_str(p["albedo"]),
            "d (mm)": _triple_str(p["burley"]["d_mm"]),
            "2G w": _triple_str(p["separable"]["two_gaussian"]["w"], "{:.2f}"),
            "2G sigma near / far (mm)": " / ".join(_triple_str(p["separable"]["two_gaussian"][k])
                                                  for k in ("sigma_near_mm", "sigma_far_mm")),
            "Burley vs MC": _triple_str(e["profile"]["burley_vs_montecarlo"], "{:.3f}"),
            "2G rendered / radial mix vs Burley": "{:.3f} / {:.3f}".format(
                max(e["kernel"]["pixel_d"]["two_gaussian_vs_burley"]["rendered_product"]),
                max(e["kernel"]["pixel_d"]["two_gaussian_vs_burley"]["radial_mix"])),
            "2G(MC) rendered vs MC": "{:.3f}".format(
                max(e["kernel"]["pixel_d"]["two_gaussian_montecarlo_vs_montecarlo"]["rendered_product"])),
            "2G image vs Burley": f"{e['image']['two_gaussian_vs_burley']:.3f}",
            "2G image vs MC": f"{e['image']['two_gaussian_vs_montecarlo']:.3f}",
            "medium slab T at 1 / 2 / 4 mm (R, G, B)": _medium_T_cell(p),
            "STA vs Burley slab": f"{e['sta']['sta_vs_burley']:.3f}",
            "STA vs MC slab": f"{e['sta']['sta_vs_montecarlo']:.3f}",
            "Burley slab vs MC slab": f"{e['sta']['burley_vs_montecarlo']:.3f}",
        })
    return rows


def _medium_T_cell(preset: dict) -> str:
    """The preset's medium transmittance (its ``transmittance`` table, as ``sss-jax transmit`` reads it) at 1, 2, 4 mm."""
    if "transmittance" not in preset:
        return "-"
    from .._materials import BurleyMaterial
    from .._slab import MediumMaterial

    medium = MediumMaterial.from_tables(BurleyMaterial(preset["albedo"], preset["burley"]["d_mm"]),
                                        [preset["transmittance"]])
    T = np.asarray(medium.transmittance(np.asarray([1.0, 2.0, 4.0])), np.float64)
    return " / ".join(_triple_str(row, "{:.2g}") for row in T)


def engine_rows(presets: list[dict]) -> list[dict[str, Any]]:
    """The engine table: per preset, each engine's kernel error (largest channel) against Burley and against Monte
    Carlo, the largest energy it loses against Monte Carlo, and the engine closest to Monte Carlo."""
    rows = []
    for p in presets:
        eng = p["errors"]["engines"]
        row: dict[str, Any] = {"preset": p["name"]}
        for name in ENGINE_ORDER:
            b = max(eng["vs_burley"][name]["error_relative_l2"])
            m = max(eng["vs_montecarlo"][name]["error_relative_l2"])
            lost = max(eng["vs_montecarlo"][name]["energy_lost"], key=abs)
            row[name] = f"{b:.3f} / {m:.3f} / {lost:+.3f}"
        row["closest to MC"] = min(ENGINE_ORDER, key=lambda n: max(eng["vs_montecarlo"][n]["error_relative_l2"]))
        rows.append(row)
    return rows


def _markdown_table(rows: list[dict[str, Any]]) -> list[str]:
    cols = list(rows[0]) if rows else []
    return (["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
            + ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows])


def write_presets_readme(out_dir: str | os.PathLike) -> pathlib.Path:
    """``README.md`` with a table of every preset in ``out_dir`` (its numbers read from the files)."""
    out = pathlib.Path(out_dir)
    skipped: list[str] = []
    presets = load_presets(out, skipped)  # a broken file is named in the README, not a failure of the whole fit
    lines = [
        "# Presets",
        "",
        "Written by `python scripts/fit_presets.py` (the same as `sss-jax fit --all`); re-running it reproduces every",
        "file here except the `seconds` fields. Each `<name>.json` validates against `schema.json`. Monte Carlo",
        "references are cached in `montecarlo/` with their provenance; `plots/<name>.png` shows r R(r) per channel",
        "(Monte Carlo with its standard error, Burley, and the two fitted two-Gaussian kernels), as in Fig. 4 of the",
        "paper.",
        "",
        "**Derivation.** Measured materials (Jensen et al. 2001, Table 2, eta 1.3): mean free path 1/(sigma_s' +",
        "sigma_a), single-scattering albedo sigma_s'/(sigma_s' + sigma_a), surface albedo A = Monte Carlo total diffuse",
        "reflectance (pencil beam, eta 1.3), d = mean free path / s(A) with the searchlight s(A) = 1.85 - A +",
        "7|A - 0.8|^3. Artist materials (A, d as an artist sets them): the index-matched isotropic medium whose",
        "reflectance is A (Chandrasekhar's 1 - H(1) sqrt(1 - alpha), inverted), mean free path d s(A).",
        "",
        "**Two-Gaussian kernels** are fitted as `separable` renders them: the product a(x) a(y) of the 1D kernel",
        "a(x) = w N(x; sigma_near) + (1 - w) N(x; sigma_far), integrated over pixels of side d (each channel's Burley",
        "d; the pixel spans +-d/2), against the target profile integrated over the same pixels, on 41x41 pixels",
        "(unweighted relative L2), once to Burley and once to the Monte Carlo profile.",
        "",
        "**Errors** (per channel, R/G/B). *Burley vs MC*: 1D radial relative L2 of r R(r), unit-energy profiles.",
        "*2G rendered / radial mix vs Burley*: the fitted kernel's product a(x) a(y) (what the pass renders) and its",
        "radial mix w G_near(r) + (1 - w) G_far(r), against Burley on pixels of side d (largest channel; errors",
        "on pixels of side d/2 are in the files). *2G(MC) rendered vs MC*: the kernel fitted to Monte Carlo, rendered.",
        "*2G image*: image-space relative L2 of the 25-tap two-Gaussian `separable` against `reference` over the five",
        "test patterns with the widest d spanning 2 px (vs the Burley profile / vs the Monte Carlo profile).",
        "*STA*: relative L2 of slab transmittance, STA (fitted to Burley's slab model) vs Monte Carlo slabs at",
        "t/d = 0.25 ... 4.",
        "",
        "**Medium slab T** (the `transmittance` block): the fraction of a normally incident back light that leaves",
        "the front face of a slab of the preset's own medium (its reduced coefficients; eta 1.3 on both faces for the",
        "measured materials, index-matched for the artist ones), unscattered and scattered light together, by the Monte",
        "Carlo walk at 0.1 ... 16 mean free paths per channel, interpolated (log T linear in t). All absorption is in",
        "it: `translucency(model=\"slab\")` adds light x T x cos with no albedo factor; `sss-jax transmit --preset NAME",
        "--thickness-mm 1,2,4` prints it. skin1 agrees with Prahl's adding-doubling (iadpython) within 2% at 1, 2, 4 mm",
        "in every channel above 0.01 (tests/test_slab_transmission.py; blue at 4 mm, 0.0086 against 0.0080, is 7% off).",
        "",
    ]
    lines += _markdown_table([dict(r, plot=f"[png](plots/{r['preset']}.png)") for r in preset_rows(presets)])
    lines += [
        "",
        "## What each engine renders",
        "",
        "Each preset's material converted to every engine (the `engines` block) and that engine's kernel as it builds",
        "it (Cycles: Burley truncated at 16 d; EEVEE legacy: its precomputed kernel; HDRP: Burley cut at its filter",
        "radius; UE5: Burley with its clamps; Jimenez: `calculateKernel` with the fitted strength/falloff/sssWidth),",
        "compared as 1D marginals (one separable pass, or the projection of a radial kernel), bins d/4 wide to 20 d.",
        "Cells: relative L2 against Burley / against Monte Carlo / energy lost against Monte Carlo (largest channel;",
        "renormalising engines lose none; a negative value is energy gained: an artist albedo differs from its Monte",
        "Carlo reflectance within that run's error, and UE's albedo clamp at 0.009 brightens very dark channels).",
        "",
    ]
    lines += _markdown_table(engine_rows(presets))
    lines.append("")
    if skipped:
        lines += ["## Files left out (not valid presets)", ""] + [f"- {reason}" for reason in skipped] + [""]
    path = out / "README.md"
    write_bytes_atomic(path, "\n".join(lines).encode())
    return path
