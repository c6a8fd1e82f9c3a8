"""One self-contained HTML page: sections of text, tables and images (every image embedded as base64 PNG).

Host side only. Figures are matplotlib ``Figure`` objects drawn through ``FigureCanvasAgg``: no global figure state and no
backend switch, so building a page changes nothing in the caller's process.
"""

from __future__ import annotations

import base64
import html
import io
import time
from typing import Any

import numpy as np

__all__ = ["Page", "new_figure", "figure_png", "rgb_png"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1360px;margin:2em auto;padding:0 1em;
color:#222;line-height:1.45}
h1{font-size:1.7em;margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
h3{font-size:1.05em;margin:1.2em 0 .3em}
.meta{color:#666;font-size:.9em} nav ol{columns:3;font-size:.95em}
table{border-collapse:collapse;margin:1em 0;font-size:.85em;display:block;max-width:100%;overflow-x:auto} th,td{border:1px solid #ddd;padding:.25em .55em;
text-align:left} td.n{text-align:right;font-variant-numeric:tabular-nums} th{background:#f4f4f4} caption{text-align:left;
color:#555;font-size:.95em;padding:.2em 0} tr.best td{background:#eef7ee}
figure{display:inline-block;margin:.4em;vertical-align:top;text-align:center} figure img{max-width:100%;
border:1px solid #eee;image-rendering:pixelated} figcaption{font-size:.8em;color:#555;max-width:420px;margin:auto}
figure.plot img{image-rendering:auto}
.grid{display:flex;flex-wrap:wrap;align-items:flex-start}
.note{background:#fff8e1;border-left:4px solid #f0b400;padding:.5em 1em}
pre{background:#f6f6f6;padding:.6em;font-size:.8em;white-space:pre-wrap;max-height:24em;overflow-y:auto}
"""


def fmt(v: Any) -> str:
    """A table cell: 4 significant digits, '–' for None and NaN, lists joined by commas, text escaped."""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if v != v:
            return "–"
        return f"{v:.4g}" if abs(v) < 1e4 else (f"{v:.0f}" if abs(v) < 1e9 else f"{v:.3e}")
    if isinstance(v, (list, tuple)):
        return ", ".join(fmt(x) for x in v)
    if v is None:
        return "–"
    return html.escape(str(v))


def _cell(v: Any) -> str:
    """A table cell; numbers align right."""
    numeric = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
    return f"<td class=n>{fmt(v)}</td>" if numeric else f"<td>{fmt(v)}</td>"


def new_figure(width_in: float = 6.0, height_in: float = 3.6, dpi: int = 100):
    """A matplotlib ``Figure`` with an Agg canvas attached (no global state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig) -> bytes:
    """PNG bytes of a ``Figure`` through its Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    buf = io.BytesIO()
    canvas.print_png(buf)
    return buf.getvalue()


def rgb_png(rgb8: np.ndarray) -> bytes:
    """PNG bytes of an ``(H, W, 3)`` uint8 display-referred image, pixel for pixel."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb8, dtype=np.uint8), mode="RGB").save(buf, format="PNG", optimize=True)
    return buf.getvalue()


class Page:
    """Sections of text, tables and figures, in order. ``data`` collects each table's rows by section title (the
    caller decides which of it goes into a JSON file). ``html()`` renders the page; nothing is written here."""

    def __init__(self, title: str, *, subtitle: str = ""):
        self.title = title
        self.subtitle = subtitle
        self.sections: list[dict[str, Any]] = []
        self.data: dict[str, Any] = {"title": title, "date": time.strftime("%Y-%m-%d %H:%M"), "sections": {}}

    def section(self, title: str, text: str = "") -> dict[str, Any]:
        """A new section; ``text`` is an HTML fragment (callers escape what they did not write)."""
        sec = {"title": title, "parts": [f"<p>{text}</p>"] if text else []}
        self.sections.append(sec)
        self.data["sections"].setdefault(title, {})
        return sec

    def raw(self, sec: dict, fragment: str) -> None:
        sec["parts"].append(fragment)

    def table(self, sec: dict, rows: list[dict], caption: str = "", key: str | None = None,
              highlight: list[bool] | None = None) -> None:
        if not rows:
            sec["parts"].append("<p class=note>No rows.</p>")
            return
        cols = list(dict.fromkeys(c for r in rows for c in r))
        head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
        body = "".join(("<tr class=best>" if highlight and highlight[i] else "<tr>")
                       + "".join(_cell(r.get(c)) for c in cols) + "</tr>" for i, r in enumerate(rows))
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        sec["parts"].append(f"<table>{cap}<tr>{head}</tr>{body}</table>")
        self.data["sections"][sec["title"]][key or caption or f"table{len(sec['parts'])}"] = rows

    def png(self, sec: dict, data: bytes, caption: str, *, plot: bool = False) -> None:
        b64 = base64.b64encode(data).decode()
        cls = " class=plot" if plot else ""
        sec["parts"].append(f"<figure{cls}><img src='data:image/png;base64,{b64}' alt='{html.escape(caption)}'>"
                            f"<figcaption>{html.escape(caption)}</figcaption></figure>")

    def figure(self, sec: dict, fig, caption: str) -> None:
        self.png(sec, figure_png(fig), caption, plot=True)

    def image(self, sec: dict, linear_rgb: np.ndarray, caption: str, exposure: float = 0.0) -> None:
        """A linear scene-referred RGB image through the sRGB display transform (``exposure`` in stops)."""
        from .._io import display_transform

        disp = np.round(display_transform(linear_rgb, exposure=exposure) * 255).astype(np.uint8)
        self.png(sec, rgb_png(disp), caption)

    def fragments(self) -> list[tuple[str, str, dict]]:
        """The sections as ``(title, html_fragment, data)``: what ``report(extra_sections=...)`` takes."""
        return [(s["title"], "".join(s["parts"]), self.data["sections"].get(s["title"], {})) for s in self.sections]

    def html(self) -> str:
        toc = "".join(f"<li><a href='#s{i}'>{html.escape(s['title'])}</a></li>" for i, s in enumerate(self.sections))
        body = "".join(f"<h2 id='s{i}'>{html.escape(s['title'])}</h2>" + "".join(s["parts"])
                       for i, s in enumerate(self.sections))
        sub = f"{html.escape(self.subtitle)} · " if self.subtitle else ""
        return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(self.title)}</title>"
                f"<style>{_CSS}</style></head><body><h1>{html.escape(self.title)}</h1>"
                f"<p class=meta>{sub}sss_jax report, {self.data['date']}</p><nav><ol>{toc}</ol></nav>{body}"
                f"</body></html>")
