"""The report's figures as matplotlib ``Figure`` objects (no global state): error maps and the time/error trade."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.ticker import FuncFormatter

from ._page import new_figure

__all__ = ["heatmap", "technique_colours", "trade_figure"]

# matplotlib's tab10 without its grey (kept for nothing) and tab20's darker halves after it: distinct hues for the
# techniques and their variants (separable and separable_two_gaussian are two techniques to the reader)
_PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
            "tab:cyan", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173")


def technique_colours(labels: Sequence[str]) -> dict[str, str]:
    """One colour per distinct label, in order of first appearance (the reference black); the palette repeats only
    past 14 techniques."""
    colours: dict[str, str] = {}
    for label in dict.fromkeys(labels):
        colours[label] = "black" if label == "reference" else _PALETTE[
            sum(1 for k in colours if k != "reference") % len(_PALETTE)]
    return colours


def heatmap(data: np.ndarray, title: str, vmax: float | None = None, cmap: str = "magma", *, width_px: int = 300):
    """A map of one value per pixel (``(H, W)``) from 0 to ``vmax`` with a colour bar; ``width_px`` sets the size."""
    h, w = data.shape
    fig = new_figure(width_px / 100, max(1.6, width_px / 100 * h / w * 0.88 + 0.35))
    ax = fig.add_subplot(1, 1, 1)
    top = vmax if vmax else max(float(np.max(data)), 1e-12)
    im = ax.imshow(data, cmap=cmap, vmin=0, vmax=top, interpolation="nearest")
    ax.set_title(title, fontsize=8)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).ax.tick_params(labelsize=7)
    fig.tight_layout(pad=0.3)
    return fig


def trade_figure(rows: Sequence[dict], panels: Sequence[tuple[str, str]]):
    """Time per frame (x, log) against error (y, log) for every run, one panel per ``(key, title)`` in ``panels``
    (``key`` names the metric block of a row: ``"vs_reference"`` or ``"vs_truth"``); each panel's Pareto front is
    dashed; each point is annotated with its count, or with what its label adds to the technique's name (the
    options telling two runs apart). ``rows``: the report's technique entries with ``pareto_<key>`` flags."""
    fig = new_figure(5.2 * len(panels), 3.9)
    for j, (key, title) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), j + 1)
        pts = [r for r in rows if r.get(key) and r["ms_per_frame"] is not None]
        colours = technique_colours([r["technique"] for r in rows])  # the same colours in every panel
        for tech in dict.fromkeys(r["technique"] for r in pts):
            mine = [r for r in pts if r["technique"] == tech]
            colour = colours[tech]
            ax.scatter([r["ms_per_frame"] for r in mine], [max(r[key]["rel_l2"], 1e-6) for r in mine], color=colour,
                       label=tech, s=22, zorder=3)
            for r in mine:
                # the count, and the options where two runs of one technique and count differ by them
                tag = r.get("label", "")[len(tech):].strip() if r.get("label", "").startswith(tech) else ""
                text = tag or ("" if r["count"] is None else str(r["count"]))
                if text:
                    ax.annotate(text, (r["ms_per_frame"], max(r[key]["rel_l2"], 1e-6)), fontsize=7,
                                xytext=(3, 3), textcoords="offset points")
        front = sorted((r for r in pts if r.get(f"pareto_{key}")), key=lambda r: r["ms_per_frame"])
        ax.plot([r["ms_per_frame"] for r in front], [max(r[key]["rel_l2"], 1e-6) for r in front], "k--", lw=1,
                label="Pareto front", zorder=2)
        ax.set_xscale("log"), ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):  # plain numbers at the decades and at a few steps between them
            axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))
        ax.set_xlabel("ms per frame"), ax.set_ylabel("relative L2"), ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
