"""Where a preset's numbers come from: the measured table (Jensen et al. 2001) and the artist materials, the medium
behind each (Chandrasekhar's H-function inverted for artist albedos), and the constants of the pipeline."""

from __future__ import annotations

import csv
import math
import os
import pathlib
import re
from importlib import resources
from typing import Any

import numpy as np

from .._io import SSSInputError
from .._profiles import scaling_searchlight


# Artist materials: surface albedo A and Burley d (mm) per channel, the way artists set them (Blender's subsurface
# colour and radius, HDRP's scattering distance). Values chosen by look, not measured: skin after the red-dominant
# spread of measured skin (d_r about 4x d_b; cf. skin1/skin2 of Jensen et al. 2001); marble a bright, long, near-grey
# spread; jade green with its longest spread in green; wax warm and deep in red; milk bright with a blue-shifted
# short spread relative to the red. The artist marble is "marble_artist": "marble" is the measured one of the table.
ARTIST_MATERIALS: dict[str, dict[str, list[float]]] = {
    "skin": {"albedo": [0.85, 0.60, 0.48], "d_mm": [1.0, 0.45, 0.25]},
    "marble_artist": {"albedo": [0.90, 0.88, 0.85], "d_mm": [2.5, 2.2, 1.9]},
    "jade": {"albedo": [0.55, 0.80, 0.60], "d_mm": [3.0, 4.5, 3.2]},
    "wax": {"albedo": [0.90, 0.75, 0.50], "d_mm": [4.0, 2.8, 1.6]},
    "milk": {"albedo": [0.92, 0.90, 0.85], "d_mm": [1.8, 1.5, 1.1]},
}

# how the walk ends photons (part of the cache's provenance: runs before issue #18 dropped photons at the cap)
MC_TERMINATION = ("implicit capture and roulette for 100000 scatterings, analog absorption after; a non-absorbing "
                  "half-space's photon tallied as reflected at the cap")
MEASURED_ETA = 1.3  # Jensen et al. 2001, Table 2 caption: "index of refraction 1.3"
DEFAULT_PHOTONS = 100_000
SLAB_T_OVER_D = (0.25, 0.5, 1.0, 2.0, 4.0)  # slab thicknesses for the Monte Carlo transmission, in units of d
SLAB_PHOTONS_FRACTION = 5  # slab runs use photons / 5 each (five thicknesses per channel)
MEDIUM_SLAB_PHOTONS_FRACTION = 10  # the medium's transmittance table: photons / 10 per thickness
IMAGE_PX_PER_D = 2.0  # image-space errors: the widest channel's d spans 2 pixels (a face close-up at 1080p)


# ------------------------------------------------------------------------------------------------------------------
# sources
# ------------------------------------------------------------------------------------------------------------------


_PRESET_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
RESERVED_NAMES = ("schema",)  # files of a presets folder that are not presets (schema.json)


def check_preset_name(name: str) -> str:
    """``name`` if it can name a preset file ``<out_dir>/<name>.json``: letters, digits, ``_``, ``.`` and ``-``,
    starting with a letter or digit (no folder, no hidden file), and not a file the folder holds besides the
    presets (``schema``); else ``ValueError`` saying why."""
    if not isinstance(name, str) or not _PRESET_NAME.fullmatch(name) or ".." in name:
        raise ValueError(f"preset name {name!r}: use letters, digits, '_', '.' and '-', starting with a letter or "
                         "digit (it names the file <out>/<name>.json)")
    if name.lower() in RESERVED_NAMES:
        raise ValueError(f"preset name {name!r} is reserved: <out>/{name}.json is the presets' JSON schema")
    return name


def measured_materials(path: str | os.PathLike | None = None) -> dict[str, dict[str, list[float]]]:
    """The measured coefficients (``sigma_s_prime``, ``sigma_a`` in 1/mm, (3,) each) by name; default: the copy of
    Jensen et al. 2001, Table 2 shipped in ``sss_jax/data``. A file of one's own is read as spreadsheets write CSV
    (UTF-8 with or without Excel's byte-order mark; ``#`` lines are comments); its errors name the file and the line:
    a header without the columns (the columns it has), a value that is not a number, a row with more values than
    the header, a name that cannot name a preset file (``check_preset_name``: no folders), a name given twice or
    taken by an artist material."""
    if path is None:
        text = resources.files("sss_jax").joinpath("data/measured_materials.csv").read_text()
        where = "sss_jax/data/measured_materials.csv"
    else:
        try:
            text = pathlib.Path(path).read_text(encoding="utf-8-sig")
        except OSError as exc:
            raise SSSInputError(f"{path}: cannot read measured materials ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise SSSInputError(f"{path}: not UTF-8 text (byte {exc.start}): save the CSV as UTF-8") from None
        where = str(path)
    numbered = [(k, line) for k, line in enumerate(text.splitlines(), start=1)
                if line.strip() and not line.lstrip().startswith("#")]
    rows = csv.DictReader(line for _, line in numbered)
    need = [f"{k}_{c}" for k in ("sigma_s_prime", "sigma_a") for c in "rgb"]
    header = [h.strip() for h in (rows.fieldnames or [])]
    absent = [k for k in ["name", *need] if k not in header]
    if numbered and absent:
        raise SSSInputError(f"{where}: the header (line {numbered[0][0]}) lacks {', '.join(absent)}; it has "
                            f"{', '.join(map(repr, header)) or 'nothing'} (a comma-separated header: name, sigma_s_prime_r, ...)")
    rows.fieldnames = header
    out: dict[str, dict[str, list[float]]] = {}
    for row in rows:
        line = numbered[rows.line_num - 1][0]
        if None in row:
            raise SSSInputError(f"{where}: line {line} has {len(row[None])} value(s) more than the header's columns")
        missing = [k for k in ["name", *need] if not (row.get(k) or "").strip()]
        if missing:
            raise SSSInputError(f"{where}: line {line} lacks {', '.join(missing)}")
        name = row["name"].strip()
        try:
            check_preset_name(name)
        except ValueError as exc:
            raise SSSInputError(f"{where}: line {line}: {exc}") from None
        if name in out:
            raise SSSInputError(f"{where}: line {line}: material {name!r} is given twice")
        if name in ARTIST_MATERIALS:
            raise SSSInputError(f"{where}: line {line}: {name!r} is an artist material's name; give it another")
        try:
            vals = {k: float(row[k]) for k in need}
        except ValueError as exc:
            raise SSSInputError(f"{where}: line {line} ({name}): {exc}") from None
        s = [vals[f"sigma_s_prime_{c}"] for c in "rgb"]
        a = [vals[f"sigma_a_{c}"] for c in "rgb"]
        if not all(math.isfinite(v) and v >= 0 for v in s + a) or not all(x > 0 for x in s):
            raise SSSInputError(f"{where}: line {line} ({name}): coefficients must be finite and >= 0, with "
                                f"sigma_s' > 0 per channel (a medium that does not scatter has no diffusion "
                                f"profile to fit); got sigma_s'={s}, sigma_a={a}")
        out[name] = {"sigma_s_prime": s, "sigma_a": a}
    if not out:
        raise SSSInputError(f"{where}: no materials (a header and one row per material: name, sigma_s_prime_r/g/b, "
                            "sigma_a_r/g/b)")
    return out


def material_names() -> list[str]:
    names = sorted(measured_materials()) + sorted(ARTIST_MATERIALS)
    assert len(set(names)) == len(names), "a preset name is both measured and artist"
    return names


def chandrasekhar_h(alpha: float, mu, *, nodes: int = 96, tol: float = 1e-13) -> np.ndarray:
    """Chandrasekhar's H-function for isotropic scattering with single-scattering albedo ``alpha``, at ``mu``.

    Iterates (damped) the form ``1/H(mu) = sqrt(1 - alpha) + (alpha/2) int_0^1 mu' H(mu') / (mu + mu') dmu'`` (Chandrasekhar
    1960, Eq. V.(40)), which converges for alpha = 1 as well, on Gauss-Legendre nodes, then evaluates it at ``mu``."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = 0.5 * (x + 1), 0.5 * w
    root = math.sqrt(max(0.0, 1.0 - alpha))
    h = np.ones(nodes)
    for _ in range(100_000):
        # undamped, the iteration swings between two wrong curves near alpha = 1; averaged it settles
        new = 0.5 * h + 0.5 / (root + 0.5 * alpha * np.sum(w * x * h / (x[:, None] + x[None, :]), axis=1))
        if np.max(np.abs(new - h)) < tol:
            h = new
            break
        h = new
    mu = np.atleast_1d(np.asarray(mu, np.float64))
    return 1.0 / (root + 0.5 * alpha * np.sum(w * x * h / (mu[:, None] + x[None, :]), axis=1))


def albedo_from_surface_albedo(A: float) -> float:
    """Single-scattering albedo of the index-matched isotropic half-space whose pencil-beam total reflectance is
    ``A`` (bisection on ``A(alpha) = 1 - H(1) sqrt(1 - alpha)``, which rises monotonically from 0 to 1)."""
    if not (0.0 <= A < 1.0):
        raise ValueError(f"surface albedo must lie in [0, 1), got {A}")
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if 1.0 - chandrasekhar_h(mid, 1.0)[0] * math.sqrt(1.0 - mid) < A:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


MAX_D_MM = 1e4  # 10 m: the largest artist d a preset is fitted for


def material_source(name: str, *, measured_csv: str | os.PathLike | None = None,
                    artist: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``source`` block of a preset: where the material comes from, its parameters and units, and the medium
    (single-scattering albedo per channel, mean free path in mm, boundary eta) the Monte Carlo reference walks."""
    if artist is not None or name in ARTIST_MATERIALS:
        spec = artist if artist is not None else ARTIST_MATERIALS[name]
        A = np.asarray(spec["albedo"], np.float64)
        d = np.asarray(spec["d_mm"], np.float64)
        # an albedo of 0 reflects nothing (the Monte Carlo reference is black, every ratio to it infinite); a d
        # past 10 m is no material's (the reference's walks and the fits overflow)
        if A.shape != (3,) or not np.all((A > 0) & (A < 1)):
            raise SSSInputError(f"{name}: albedo must be 3 values in (0, 1), got {A.tolist()}")
        if d.shape != (3,) or not np.all(np.isfinite(d) & (d > 0) & (d <= MAX_D_MM)):
            raise SSSInputError(f"{name}: d_mm must be 3 values in (0, {MAX_D_MM:g}] mm, got {d.tolist()}")
        alpha = [albedo_from_surface_albedo(float(a)) for a in A]
        mfp = (d * np.asarray(scaling_searchlight(A))).tolist()
        return {"kind": "artist", "albedo": A.tolist(), "d_mm": d.tolist(), "units": {"albedo": "1", "d_mm": "mm"},
                "medium": {"single_scattering_albedo": alpha, "mean_free_path_mm": mfp, "eta": 1.0, "phase": "isotropic",
                           "derivation": "alpha from A = 1 - H(1) sqrt(1 - alpha) (Chandrasekhar, index-matched, "
                                         "isotropic); mean free path = d s(A), searchlight s(A) = 1.85 - A + 7|A - 0.8|^3"}}
    table = measured_materials(measured_csv)
    if name not in table:
        raise SSSInputError(f"unknown material {name!r}; measured: {', '.join(sorted(table))}; artist: "
                            f"{', '.join(sorted(ARTIST_MATERIALS))}")
    s = np.asarray(table[name]["sigma_s_prime"])
    a = np.asarray(table[name]["sigma_a"])
    st = s + a
    return {"kind": "measured", "reference": "Jensen, Marschner, Levoy, Hanrahan 2001, A Practical Model for "
            "Subsurface Light Transport, Table 2", "sigma_s_prime_per_mm": s.tolist(), "sigma_a_per_mm": a.tolist(),
            "units": {"sigma_s_prime_per_mm": "1/mm", "sigma_a_per_mm": "1/mm"},
            "medium": {"single_scattering_albedo": (s / st).tolist(), "mean_free_path_mm": (1 / st).tolist(),
                       "eta": MEASURED_ETA, "phase": "isotropic (reduced coefficients)",
                       "derivation": "alpha' = sigma_s'/(sigma_s' + sigma_a), mean free path = 1/(sigma_s' + sigma_a); "
                                     "A = Monte Carlo total diffuse reflectance (pencil beam, eta 1.3); "
                                     "d = mean free path / s(A), searchlight s(A) = 1.85 - A + 7|A - 0.8|^3"}}
