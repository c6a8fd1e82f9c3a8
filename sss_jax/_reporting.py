"""The demo's own report sections (profiles and kernels, Monte Carlo, energy, presets, engines, transmission), handed
to the common report layout (``sss_jax._report.report``) as extra sections by ``write_demo_report``.

Simulations and timings are the caller's (``sss_jax._demo``): these functions only draw and tabulate.
"""

from __future__ import annotations

import html
import json
import pathlib

import numpy as np

from ._report import Page, new_figure, report
from ._techniques._registry import ENERGY_CONSERVING

__all__ = ["write_demo_report", "demo_sections"]

Report = Page  # the sections below take the page they add to


def _fig(w=6.0, h=3.6):
    return new_figure(w, h)


def write_demo_report(result, out_dir: pathlib.Path, *, trade=(), montecarlo=None) -> pathlib.Path:
    """The report of ``sss-jax demo``: the common layout (summary, renders, error and ΔE maps, per material, the
    time/error trade) of ``result`` and ``trade`` (``_demo.demo_trade``), plus the demo's sections; ``montecarlo``
    (``_demo.demo_montecarlo``) adds the Monte Carlo figure."""
    from ._demo import demo_report_data

    return report(demo_report_data(result, trade), out_dir, extra_sections=demo_sections(result, montecarlo))


def demo_sections(result, montecarlo=None) -> list[tuple[str, str, dict]]:
    """``(title, html_fragment, data)`` of the demo's own sections."""
    import jax.numpy as jnp

    from ._demo import DEMO_MATERIALS, demo_burley_material, demo_two_gaussian
    from ._kernels import separable_kernel_from_profile, two_gaussian_kernel
    from ._profiles import BurleyProfile, preintegrate

    rep = Page("demo sections")

    # profiles and kernels
    sec = rep.section("Profiles and kernels", "Left: r·R(r) of each demo material's Christensen–Burley profile per "
                      "channel. Right: the 1D separable kernel: Burley pre-integrated a_p(x) (solid) against the "
                      "two-Gaussian kernel fitted to it in profile space, used by separable_two_gaussian (dashed).")
    mat, tg = demo_burley_material(np.float64), demo_two_gaussian(np.float64)
    r = np.linspace(1e-3, 12.0, 400)
    colours = ("tab:red", "tab:green", "tab:blue")
    for i, name in enumerate(DEMO_MATERIALS):
        fig = _fig(8.0, 3.0)
        ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
        prof = BurleyProfile(jnp.asarray(mat.d_mm[i]), jnp.asarray(mat.albedo[i]))
        rr = np.asarray(prof.physical(jnp.asarray(r))) * r[:, None]
        x = np.linspace(0.02, 8.0, 300)
        ap = np.asarray(preintegrate(prof, jnp.asarray(x)))
        w, sn, sf = (np.asarray(a[i]) for a in (tg.w, tg.sigma_near_mm, tg.sigma_far_mm))
        g = lambda s: np.exp(-x[:, None] ** 2 / (2 * s**2)) / (np.sqrt(2 * np.pi) * s)
        am = w * g(sn) + (1 - w) * g(sf)
        for c in range(3):
            ax1.plot(r, rr[:, c], color=colours[c])
            ax2.plot(x, ap[:, c], color=colours[c])
            ax2.plot(x, am[:, c], color=colours[c], ls="--")
        ax1.set_xlabel("r (mm)"), ax1.set_ylabel("r R(r)"), ax1.set_title(f"{name}: Burley r·R(r)", fontsize=9)
        ax2.set_xlabel("x (mm)"), ax2.set_yscale("log"), ax2.set_title(f"{name}: 1D kernels", fontsize=9)
        fig.tight_layout()
        fmt = lambda a: ", ".join(f"{float(v):.3g}" for v in np.asarray(a))
        rep.figure(sec, fig, f"{name}: d = ({fmt(mat.d_mm[i])}) mm, A = ({fmt(mat.albedo[i])})")
    if montecarlo:
        rep.figure(sec, _mc_figure(montecarlo), "Monte Carlo random walk (dots, ±1 standard error) against "
                   "Christensen–Burley with the memo's searchlight s(A) (lines), index-matched semi-infinite medium, "
                   "normal pencil beam")
        rep.data["sections"]["Profiles and kernels"]["montecarlo_vs_burley"] = [
            {k: row[k] for k in ("albedo", "total_reflectance", "d_mfp", "rel_l2_rR")} for row in montecarlo]
    k = separable_kernel_from_profile(BurleyProfile(jnp.asarray(mat.d_mm[0])), taps=25)
    k2 = two_gaussian_kernel(*(jnp.asarray(a[0]) for a in (tg.w, tg.sigma_near_mm, tg.sigma_far_mm)), taps=25)
    fig = _fig(8.0, 3.0)
    for j, (kk, label) in enumerate(((k, "pre-integrated Burley"), (k2, "two-Gaussian"))):
        ax = fig.add_subplot(1, 2, j + 1)
        off, wt = np.asarray(kk.offsets_mm), np.asarray(kk.weights)
        order = np.argsort(off)
        for c in range(3):
            ax.plot(off[order], wt[order, c], "o-", ms=3, color=colours[c])
        ax.set_title(f"{label}: 25 taps", fontsize=9), ax.set_xlabel("offset (mm)")
    fig.tight_layout()
    rep.figure(sec, fig, "separable taps of the skin material (weights per channel; taps densest near the centre)")
    rep.data["sections"]["Profiles and kernels"]["skin_taps"] = {
        "offsets_mm": np.asarray(k.offsets_mm).tolist(), "weights": np.asarray(k.weights).tolist()}

    # energy
    sec = rep.section("Energy", "Output over input energy per channel over the SSS pixels (albedo divided out). "
                      "Separable and Burley redistribute light (1 up to image borders and depth edges); STA adds "
                      "light through thickness by design and does not conserve energy.")
    rep.table(sec, [dict(technique=n, R=float(e[0]), G=float(e[1]), B=float(e[2]),
                         conserves="yes" if (result.runs[n][2] if n in result.runs else ENERGY_CONSERVING.get(n, True))
                         else "no (adds light)")
                    for n, e in result.energy.items() if n != "local"], "energy ratio", key="energy")

    # Burley's sampling error: samples x frames, bias and noise over seeds (issue #18)
    from ._bench import sampling_section

    sampling_section(rep, result)

    # presets and what every engine renders for them
    from ._fit_presets import engine_rows, load_presets, preset_rows
    from ._presets import preset_home

    fits = preset_home()
    try:
        presets = load_presets(fits) if fits.is_dir() else []
        rows, eng = preset_rows(presets), engine_rows(presets)
    except (OSError, ValueError, KeyError, TypeError) as exc:  # a damaged preset must not cost the whole report
        presets, rows, eng = [], [], []
        problem = f" (fits/ could not be read: {html.escape(str(exc))})"
    else:
        problem = ""
    sec = rep.section("Presets", f"{len(presets)} fitted presets in fits/ (<code>sss-jax fit</code>), their parameters "
                      "and the error of each cheap model against the Burley profile and against Monte Carlo; "
                      f"fits/README.md has the metrics and a profile plot per preset.{problem}")
    rep.table(sec, rows, "presets", key="presets")
    _engines_section(rep, presets, eng)
    _transmission_section(rep, presets, fits)
    return rep.fragments()


def _engines_section(rep: Report, presets: list[dict], rows: list[dict]) -> None:
    """Every preset's kernel in every engine, as that engine's class builds it from the preset's own engine block
    (``engines.engine_marginals``), drawn beside the Burley reference; and the preset files' error table."""
    from .engines import KERNELS, engine_errors_against, engine_marginals

    sec = rep.section("Engines", "What each engine renders for every preset: its kernel as that engine builds it "
                      "(from the preset's engine block), as a 1D marginal (one separable pass; the projection of a "
                      "radial kernel) beside the Burley reference, for each preset's widest channel. Table cells, from the preset files: "
                      "relative L2 vs Burley / vs Monte Carlo / energy lost vs Monte Carlo (largest channel). Cycles' "
                      "random walks are measured against Monte Carlo in docs/engines.md.")
    rep.table(sec, rows, "engines", key="engines")
    errors, panels = {}, []
    for p in presets:
        try:
            marg = engine_marginals(p["albedo"], p["burley"]["d_mm"], blocks=p.get("engines"))
        except (KeyError, TypeError, ValueError):  # a damaged preset costs its panel, not the report
            continue
        err = engine_errors_against(marg, marg["reference"], marg["albedo"]["reference"])
        errors[p["name"]] = {k: v["error_relative_l2"] for k, v in err.items()}
        panels.append((p["name"], marg))
    if panels:
        cols = 4
        rows_n = -(-len(panels) // cols)
        fig = _fig(11.0, 2.3 * rows_n)
        for i, (name, marg) in enumerate(panels):
            ax = fig.add_subplot(rows_n, cols, i + 1)
            c = int(np.argmax(marg["edges"][:, -1]))  # the widest channel: where the engines differ most
            edges = marg["edges"][c]
            d_c = (edges[1] - edges[0]) * 4.0
            x, width = (edges[:-1] + edges[1:]) / (2 * d_c), np.diff(edges) / d_c
            ax.plot(x, marg["reference"][c, 1:-1] / width, color="k", lw=3, alpha=0.3, label="Burley")
            for kernel in KERNELS:
                if kernel in marg:
                    ax.plot(x, np.maximum(marg[kernel][c, 1:-1] / width, 1e-6), lw=0.8, label=kernel)
            ax.set_yscale("log"), ax.set_ylim(1e-4, 2.0), ax.set_xlim(-12, 12)
            ax.set_title(f"{name} ({'RGB'[c]}, d = {d_c:.3g} mm)", fontsize=7), ax.tick_params(labelsize=6)
        fig.axes[0].legend(fontsize=5)
        fig.subplots_adjust(left=0.05, right=0.99, bottom=0.04, top=0.96, hspace=0.45, wspace=0.25)
        rep.figure(sec, fig, "Each engine's 1D kernel (density per d, against x / d) beside the Burley reference, for "
                   "every preset's widest channel; the relative L2 of every channel is in report.json "
                   "(kernels_vs_burley)")
    rep.data["sections"]["Engines"]["kernels_vs_burley"] = errors


TRANSMISSION_FIGURE_PRESETS = ("skin", "marble", "ketchup")


def _transmission_section(rep: Report, presets: list[dict], fits: pathlib.Path) -> None:
    """Back-light through slabs: each preset's fitted STA, the profile's closed-form thin transmission and the
    tabulated slab model against the preset's cached Monte Carlo slabs (no new simulation)."""
    from ._fit_presets import transmission_curves

    sec = rep.section("Transmission", "Light through a slab of the preset's medium (normal incidence, normal view) "
                      "against the Monte Carlo slabs cached with the preset. <em>thin</em>: the profile's "
                      "closed form (e<sup>-t/d</sup> + 3 e<sup>-t/3d</sup>)/4 that HDRP and UE5 use; <em>slab</em>: "
                      "the total transmittance T of the Monte Carlo table of the index-matched medium behind (A, d) "
                      "(of which <code>translucency(model=\"slab\")</code> adds the scattered part, spread over "
                      "view directions as the slab lets it out); <em>STA</em>: the fitted STA term (an artist's model: it adds light and "
                      "is fitted to the thin model). Cells: relative L2 over the thicknesses t/d = 0.25 to 4, all "
                      "channels; presets measured with a dielectric boundary (eta 1.3) differ from the index-matched "
                      "slab table by construction.")
    rows, curves = [], {}
    for p in presets:
        try:
            c = transmission_curves(p, json.loads((fits / p["montecarlo"]["cache"]).read_text())["slab"])
        except (OSError, KeyError, TypeError, ValueError):  # an older preset without its slab block: skip it, say so
            rows.append({"preset": p.get("name", "?"), "STA vs MC": "-", "thin vs MC": "-", "slab vs MC": "-"})
            continue
        curves[p["name"]] = c
        rows.append({"preset": p["name"], "eta": p["montecarlo"]["eta"],
                     **{f"{m} vs MC": round(c["rel_l2"][m], 4) for m in ("sta", "thin", "slab")},
                     "closest": min(("sta", "thin", "slab"), key=lambda m: c["rel_l2"][m])})
    rep.table(sec, rows, "slab transmission against Monte Carlo", key="transmission")
    shown = [n for n in TRANSMISSION_FIGURE_PRESETS if n in curves]
    if not shown:
        return
    colours = ("tab:red", "tab:green", "tab:blue")
    fig = _fig(3.3 * len(shown), 3.4)
    for j, name in enumerate(shown):
        c = curves[name]
        ax = fig.add_subplot(1, len(shown), j + 1)
        for ch in range(3):
            t, col = np.asarray(c["t_over_d"][ch]), colours[ch]
            ax.errorbar(t, c["montecarlo"][ch], yerr=c["montecarlo_stderr"][ch], fmt="o", ms=3, color=col)
            fine = np.asarray(c["fine_t_over_d"])
            ax.plot(fine, c["fine"]["slab"][ch], "-", color=col, lw=1.2)
            ax.plot(fine, c["fine"]["thin"][ch], "--", color=col, lw=1.0)
            ax.plot(fine, c["fine"]["sta"][ch], ":", color=col, lw=1.4)
        ax.set_yscale("log"), ax.set_xlabel("t / d"), ax.set_title(name, fontsize=9)
        if j == 0:
            ax.set_ylabel("transmittance")
            ax.plot([], [], "ko", ms=3, label="Monte Carlo ±1 s.e."), ax.plot([], [], "k-", label="slab model")
            ax.plot([], [], "k--", label="thin (closed form)"), ax.plot([], [], "k:", label="fitted STA")
            ax.legend(fontsize=7)
    fig.tight_layout()
    rep.figure(sec, fig, "slab transmittance per channel (R, G, B) against thickness over d: Monte Carlo (dots), "
               "the tabulated slab model (solid), the closed-form thin transmission (dashed), fitted STA (dotted)")


def _mc_figure(montecarlo: list[dict]):
    """r R(r) of Monte Carlo against Burley for each albedo of ``_demo.demo_montecarlo``, as in the paper's Fig. 4."""
    fig = _fig(6.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    for row, c in zip(montecarlo, ("tab:blue", "tab:green", "tab:red", "tab:purple", "tab:brown")):
        ax.errorbar(row["r"], row["rR"], yerr=row["rR_stderr"], fmt="o", ms=2.5, color=c,
                    label=f"MC, albedo {row['albedo']}")
        ax.plot(row["r"], row["rR_burley"], color=c, lw=1.2)
    ax.set_xlabel("r (mean free paths)"), ax.set_ylabel("r R(r)"), ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
