"""The error report: one self-contained HTML file (every image embedded) plus the JSON behind it."""

from __future__ import annotations

import base64
import html
import io
import json
import pathlib
import time
from typing import Any

import numpy as np

from ._io import display_transform, write_bytes_atomic, write_json_atomic

__all__ = ["Report", "write_demo_report"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
color:#222;line-height:1.45}
h1{font-size:1.7em;margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
.meta{color:#666;font-size:.9em} nav ol{columns:2;font-size:.95em}
table{border-collapse:collapse;margin:1em 0;font-size:.9em} th,td{border:1px solid #ddd;padding:.3em .6em;
text-align:right} th{background:#f4f4f4} td:first-child,th:first-child{text-align:left}
figure{display:inline-block;margin:.5em;vertical-align:top;text-align:center} figure img{max-width:100%;
border:1px solid #eee} figcaption{font-size:.85em;color:#555;max-width:520px;margin:auto}
.note{background:#fff8e1;border-left:4px solid #f0b400;padding:.5em 1em}
"""


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if v != v:
            return "–"
        return f"{v:.4g}" if abs(v) < 1e4 else f"{v:.3e}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    if v is None:
        return "–"
    return html.escape(str(v))


class Report:
    """Sections of text, tables and figures; ``write`` produces the HTML and the JSON atomically."""

    def __init__(self, title: str):
        self.title = title
        self.sections: list[dict[str, Any]] = []
        self.data: dict[str, Any] = {"title": title, "date": time.strftime("%Y-%m-%d %H:%M"), "sections": {}}

    def section(self, title: str, text: str = "") -> dict[str, Any]:
        sec = {"title": title, "parts": [f"<p>{text}</p>"] if text else []}
        self.sections.append(sec)
        self.data["sections"][title] = {}
        return sec

    def table(self, sec: dict, rows: list[dict], caption: str = "", key: str | None = None) -> None:
        if not rows:
            sec["parts"].append("<p class=note>No rows.</p>")
            return
        cols = list(rows[0])
        head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
        body = "".join("<tr>" + "".join(f"<td>{_fmt(r.get(c))}</td>" for c in cols) + "</tr>" for r in rows)
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        sec["parts"].append(f"<table>{cap}<tr>{head}</tr>{body}</table>")
        self.data["sections"][sec["title"]][key or caption or f"table{len(sec['parts'])}"] = rows

    def png(self, sec: dict, data: bytes, caption: str) -> None:
        b64 = base64.b64encode(data).decode()
        sec["parts"].append(f"<figure><img src='data:image/png;base64,{b64}' alt='{html.escape(caption)}'>"
                            f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    def figure(self, sec: dict, fig, caption: str) -> None:
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        self.png(sec, buf.getvalue(), caption)

    def image(self, sec: dict, linear_rgb: np.ndarray, caption: str, exposure: float = 0.0) -> None:
        disp = np.round(display_transform(linear_rgb, exposure=exposure) * 255).astype(np.uint8)
        self.png(sec, _png_bytes(disp), caption)

    def write(self, html_path: pathlib.Path, json_path: pathlib.Path) -> None:
        toc = "".join(f"<li><a href='#s{i}'>{html.escape(s['title'])}</a></li>" for i, s in enumerate(self.sections))
        body = "".join(f"<h2 id='s{i}'>{html.escape(s['title'])}</h2>" + "".join(s["parts"])
                       for i, s in enumerate(self.sections))
        page = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1>"
                f"<p class=meta>sss_jax report, {self.data['date']}</p><nav><ol>{toc}</ol></nav>{body}</body></html>")
        write_bytes_atomic(html_path, page.encode())
        write_json_atomic(json_path, self.data)


def _png_bytes(rgb8: np.ndarray) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    h, w = rgb8.shape[:2]
    fig = Figure(figsize=(w / 100, h / 100), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(rgb8, interpolation="nearest")
    ax.axis("off")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def _fig(w=6.0, h=3.6):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), dpi=100)


def _heatmap(data: np.ndarray, title: str, vmax: float | None = None, cmap: str = "magma"):
    fig = _fig(4.2, 3.2)
    ax = fig.add_subplot(1, 1, 1)
    im = ax.imshow(data, cmap=cmap, vmin=0, vmax=vmax if vmax else max(float(np.max(data)), 1e-12))
    ax.set_title(title, fontsize=9)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    fig.tight_layout()
    return fig


def write_demo_report(result, out_dir: pathlib.Path, *, pareto: bool = True) -> pathlib.Path:
    """The report for ``sss-jax demo``: renders, error and ΔE maps, profiles, kernels, energy, the trade."""
    import jax.numpy as jnp

    from ._demo import DEMO_MATERIALS, demo_burley_material, demo_two_gaussian, summary_rows
    from ._kernels import separable_kernel_from_profile, two_gaussian_kernel
    from ._metrics import delta_e_2000
    from ._profiles import BurleyProfile, preintegrate

    out_dir = pathlib.Path(out_dir)
    rep = Report("sss_jax demo: techniques against the reference")
    b = result.scene.buffers
    mask = np.asarray(b.material_id) > 0
    ref = result.images["reference"]
    names = [n for n in result.images if n not in ("irradiance",)]

    # 1. summary
    sec = rep.section("Summary", "Every technique on the procedural demo scene, against the dense pixel-integrated "
                      "reference, over the pixels with subsurface scattering. Times are medians on this machine "
                      "after compilation. CIEDE2000 at exposure 0 (linear sRGB white = L* 100).")
    rows = []
    for r in summary_rows(result):
        de = delta_e_2000(result.images[r["technique"]], ref, mask=mask)
        rows.append(dict(technique=r["technique"], ms_per_frame=r["ms_per_frame"], compile_s=r["compile_s"],
                         rel_l2=r["rel_l2_vs_reference"], delta_e_mean=round(de["mean"], 3),
                         delta_e_p95=round(de["p95"], 3), energy_rgb=r["energy_ratio_rgb"],
                         light={"sta": "adds", "local": "local only"}.get(r["technique"], "redistributes")))
    rep.table(sec, rows, "time, error and energy per technique", key="techniques")

    # 2. renders
    sec = rep.section("Renders", "Linear renders through the sRGB display transform. Ground pixels (no SSS) are "
                      "shaded locally in every image.")
    for n in ["irradiance", "local", "reference"] + [n for n in names if n not in ("local", "reference")]:
        rep.image(sec, result.images[n], n)

    # 3. difference and CIEDE2000 maps
    sec = rep.section("Difference maps", "Absolute difference to the reference (mean over RGB) and CIEDE2000 per "
                      "pixel, SSS pixels only. The scattering techniques share one scale so they compare at a "
                      "glance; STA, which adds light, has its own.")
    diffs = {n: np.abs(result.images[n] - ref).mean(-1) * mask for n in names if n != "reference"}
    des = {n: delta_e_2000(result.images[n], ref, mask=mask)["map"] for n in diffs}
    shared = [n for n in diffs if n != "sta"]
    scale = lambda maps, keys: max(float(np.percentile(maps[k][mask], 99.5)) for k in keys) or 1.0
    for n in diffs:
        keys = shared if n in shared else [n]
        rep.figure(sec, _heatmap(diffs[n], f"|{n} - reference|", scale(diffs, keys)), f"{n}: absolute difference")
        rep.figure(sec, _heatmap(des[n], f"ΔE2000 {n}", scale(des, keys), "viridis"), f"{n}: CIEDE2000")

    # 4. profiles and kernels
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
    rep.figure(sec, _mc_figure(rep), "Monte Carlo random walk (dots, ±1 standard error) against Christensen–Burley "
               "with the memo's searchlight s(A) (lines), index-matched semi-infinite medium, normal pencil beam")
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

    # 5. energy
    sec = rep.section("Energy", "Output over input energy per channel over the SSS pixels (albedo divided out). "
                      "Separable and Burley redistribute light (1 up to image borders and depth edges); STA adds "
                      "light through thickness by design and does not conserve energy.")
    rep.table(sec, [dict(technique=r["technique"], R=r["energy_rgb"][0], G=r["energy_rgb"][1], B=r["energy_rgb"][2],
                         conserves="no (adds light)" if r["technique"] == "sta" else "yes") for r in rows],
              "energy ratio", key="energy")

    # 6. the trade
    sec = rep.section("Speed against accuracy", "Time per frame against error for each sample and tap count on "
                      "this scene; the dashed line is the Pareto front. `sss-jax bench` measures the full grid with "
                      "peers.")
    if pareto:
        trade = _trade(result)
        rep.table(sec, trade, "time and error per configuration", key="trade")
        fig = _fig(6.0, 4.0)
        ax = fig.add_subplot(1, 1, 1)
        for tech, c in (("sta", "tab:orange"), ("separable", "tab:blue"), ("burley", "tab:green")):
            pts = [t for t in trade if t["technique"] == tech]
            ax.scatter([t["ms_per_frame"] for t in pts], [t["rel_l2"] for t in pts], color=c, label=tech)
            for t in pts:
                ax.annotate(str(t["count"] or ""), (t["ms_per_frame"], t["rel_l2"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        front = [t for t in trade if t["pareto"]]
        ax.plot([t["ms_per_frame"] for t in front], [t["rel_l2"] for t in front], "k--", lw=1, label="Pareto front")
        ax.set_xscale("log"), ax.set_yscale("log"), ax.set_xlabel("ms per frame"), ax.set_ylabel("relative L2")
        ax.legend(fontsize=8), ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        rep.figure(sec, fig, "Pareto plot on the demo scene")

    # Burley's sampling error: samples x frames, bias and noise over seeds (issue #18)
    from ._bench import sampling_section

    sampling_section(rep, result)

    # 7. presets and what every engine renders for them
    from ._fit_presets import engine_rows, load_presets, preset_rows

    fits = pathlib.Path(__file__).resolve().parents[1] / "fits"
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
    sec = rep.section("Engines", "What each engine renders for every preset: its kernel as that engine builds it, "
                      "as a 1D marginal against the Burley and Monte Carlo references. Cells: relative L2 vs Burley / "
                      "vs Monte Carlo / energy lost vs Monte Carlo (largest channel). STA and the closed-form thin "
                      "transmission against Monte Carlo slabs are in the presets table.")
    rep.table(sec, eng, "engines", key="engines")
    _transmission_section(rep, presets, fits)

    html_path = out_dir / "report.html"
    rep.write(html_path, out_dir / "report.json")
    return html_path


TRANSMISSION_FIGURE_PRESETS = ("skin", "marble", "ketchup")


def _transmission_section(rep: Report, presets: list[dict], fits: pathlib.Path) -> None:
    """Back-light through slabs: each preset's fitted STA, the profile's closed-form thin transmission and the
    tabulated slab model against the preset's cached Monte Carlo slabs (no new simulation)."""
    from ._fit_presets import transmission_curves

    sec = rep.section("Transmission", "Light through a slab of the preset's medium (normal incidence, normal view) "
                      "against the Monte Carlo slabs cached with the preset. <em>thin</em>: the profile's "
                      "closed form (e<sup>-t/d</sup> + 3 e<sup>-t/3d</sup>)/4 that HDRP and UE5 use; <em>slab</em>: "
                      "<code>translucency(model=\"slab\")</code>, the Monte Carlo table of the index-matched medium "
                      "behind (A, d); <em>STA</em>: the fitted STA term (an artist's model: it adds light and "
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


def _mc_figure(rep: Report, photons: int = 20_000):
    """r R(r) of Monte Carlo against Burley for three single-scattering albedos, in the manner of the paper's Fig. 4."""
    from ._montecarlo import simulate
    from ._profiles import burley_R, d_from_mfp

    fig = _fig(6.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    rows = []
    for alpha, c in ((0.5, "tab:blue"), (0.9, "tab:green"), (0.99, "tab:red")):
        mc = simulate(alpha, photons=photons, seed=5, bins=60, r_max_mfp=6.0)
        r = mc.r_mfp
        d = float(d_from_mfp(mc.total_reflectance, 1.0, fit="searchlight"))
        rr_b = r * mc.total_reflectance * np.asarray(burley_R(r, d))
        ax.errorbar(r, r * mc.R, yerr=r * mc.R_stderr, fmt="o", ms=2.5, color=c, label=f"MC, albedo {alpha}")
        ax.plot(r, rr_b, color=c, lw=1.2)
        rows.append(dict(albedo=alpha, total_reflectance=round(mc.total_reflectance, 4), d_mfp=round(d, 4),
                         rel_l2_rR=round(float(np.linalg.norm(rr_b - r * mc.R) / np.linalg.norm(r * mc.R)), 4)))
    ax.set_xlabel("r (mean free paths)"), ax.set_ylabel("r R(r)"), ax.legend(fontsize=8)
    fig.tight_layout()
    rep.data["sections"]["Profiles and kernels"]["montecarlo_vs_burley"] = rows
    return fig


def _trade(result) -> list[dict]:
    """Time and error of a few sample/tap counts on the demo scene (same frame as the report)."""
    from ._bench import _compile_and_time
    from ._demo import DEMO_STA, demo_burley_material
    from ._materials import STAParams
    from ._techniques import burley, separable, translucency

    scene = result.scene
    b, cam = scene.buffers, scene.camera
    mat = demo_burley_material()
    mask = np.asarray(b.material_id) > 0
    ref = result.images["reference"]
    local = np.asarray(b.albedo) * np.asarray(b.irradiance)
    configs = [("sta", None, lambda: translucency(b, STAParams(**DEMO_STA), cam, scene.back_light))]
    configs += [("separable", n, lambda n=n: separable(b, mat, cam, taps=n)) for n in (9, 17, 25)]
    configs += [("burley", n, lambda n=n: burley(b, mat, cam, samples=n)) for n in (8, 16, 32, 64)]
    rows = []
    for tech, n, fn in configs:
        _, t = _compile_and_time(fn, 2)
        img = np.where(mask[..., None], np.asarray(fn()), local)
        err = float(np.linalg.norm((img - ref)[mask]) / np.linalg.norm(ref[mask]))
        rows.append(dict(technique=tech, count=n, ms_per_frame=round(1e3 * t, 2), rel_l2=round(err, 5)))
    front, best = [], float("inf")
    for r in sorted(rows, key=lambda r: r["ms_per_frame"]):
        if r["rel_l2"] < best:
            best = r["rel_l2"]
            front.append(r)
    for r in rows:
        r["pareto"] = r in front
    return rows
