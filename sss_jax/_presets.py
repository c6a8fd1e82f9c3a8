"""Reading material presets: ``fits/<name>.json`` files, or any file of the same format.

The fields read (the preset format of the fitting issue; anything else in the file is kept in ``raw``):

    {"name": "skin", "albedo": [r, g, b],
     "burley": {"d_mm": [r, g, b]},
     "separable": {"two_gaussian": {"w": [...], "sigma_near_mm": [...], "sigma_far_mm": [...]}},
     "sta": {"distortion": d, "power": p, "scale": [...], "ambient": [...], "thickness_mm": [...]}}

``albedo`` and ``burley`` are required; the two-Gaussian kernel, the STA parameters and the medium's slab
transmittance (``transmittance``: ``thickness_mm``, ``T``, ``resolved`` per channel, as ``_slab.medium_slab_table``
writes them; ``Preset.medium``, what ``translucency(model="slab")`` transmits) are optional. A name is looked
up in the directories of ``SSS_JAX_PRESETS`` (``os.pathsep``-separated) and then in the presets that ship with the
package (the repository's ``fits/``, installed as the package data ``sss_jax.fits``).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import os
import pathlib
from typing import Any

from ._io import SSSInputError
from ._materials import BurleyMaterial, STAParams, TwoGaussianMaterial
from ._slab import MediumMaterial

__all__ = ["Preset", "list_presets", "load_preset", "material_for", "preset_dirs", "preset_home"]


@dataclasses.dataclass(frozen=True)
class Preset:
    name: str
    path: str
    burley: BurleyMaterial
    two_gaussian: TwoGaussianMaterial | None
    sta: STAParams | None
    raw: dict[str, Any]
    medium: MediumMaterial | None = None


def preset_home() -> pathlib.Path:
    """The directory of the presets that ship with sss_jax (``fits/`` in the repository; package data in an install)."""
    return pathlib.Path(str(importlib.resources.files("sss_jax.fits")))


def preset_dirs() -> list[pathlib.Path]:
    """Where names are looked up, in order: the directories of ``SSS_JAX_PRESETS``, then ``preset_home()``."""
    dirs = [pathlib.Path(p) for p in os.environ.get("SSS_JAX_PRESETS", "").split(os.pathsep) if p]
    return dirs + [preset_home()]


def list_presets() -> list[str]:
    """The names ``load_preset`` accepts, sorted (a name in an earlier directory hides the same name later)."""
    return sorted({c.stem for d in preset_dirs() if d.is_dir() for c in d.glob("*.json") if c.stem != "schema"})


def _resolve(name_or_path: str | os.PathLike) -> pathlib.Path:
    """A preset file: a path (ending in ``.json``, naming a folder, or an existing file), else a name looked up in
    ``preset_dirs()`` (a folder or file of that name in the working directory does not hide the shipped preset)."""
    p = pathlib.Path(name_or_path)
    text = str(name_or_path)
    if p.suffix == ".json" or p.is_file() or os.sep in text or (os.altsep and os.altsep in text):
        if not p.exists():
            raise SSSInputError(f"{p}: preset file not found")
        return p
    for d in preset_dirs():
        candidate = d / f"{name_or_path}.json"
        if candidate.exists():
            return candidate
    raise SSSInputError(f"unknown preset {str(name_or_path)!r}; presets found: {', '.join(list_presets()) or 'none'} "
                        f"(looked in {', '.join(str(d) for d in preset_dirs())})")


def _triple(data: dict, path: list[str], source: pathlib.Path):
    node: Any = data
    for key in path:
        if not isinstance(node, dict) or key not in node:
            raise SSSInputError(f"{source}: preset is missing {'.'.join(path)}")
        node = node[key]
    if not (isinstance(node, list) and len(node) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in node)):  # true is not 1.0
        raise SSSInputError(f"{source}: {'.'.join(path)} must be a list of 3 numbers (R, G, B), got {node!r}")
    return node


def _numeric(value) -> bool:
    """Whether ``value`` (from JSON) is a number or a (nested) list of numbers, not a string or a bool."""
    if isinstance(value, list):
        return bool(value) and all(_numeric(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def load_preset(name_or_path: str | os.PathLike) -> Preset:
    """Read and validate a preset by name (``list_presets()``) or path; every error names the file and the field.

    The ``Preset`` holds the Burley material (albedo, d in mm), the fitted two-Gaussian kernel and STA parameters
    where the file has them, and the whole file as ``raw`` (fit records, errors, engine blocks)."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"load_preset: give a preset's name or a path to its JSON, got {name_or_path!r}")
    path = _resolve(name_or_path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise SSSInputError(f"{path}: cannot read preset ({exc.strerror})") from None
    except ValueError as exc:
        raise SSSInputError(f"{path}: preset is not valid JSON ({exc})") from None
    return preset_from_data(data, path)


def preset_from_data(data: Any, path: pathlib.Path) -> Preset:
    """``load_preset`` of the JSON ``data`` of the file ``path`` (errors name it): what a fit checks its preset
    with before writing it."""
    if not isinstance(data, dict):
        raise SSSInputError(f"{path}: a preset must be a JSON object")
    albedo = _triple(data, ["albedo"], path)
    try:
        burley = BurleyMaterial(albedo, _triple(data, ["burley", "d_mm"], path))
        tg = None
        if isinstance(data.get("separable"), dict) and "two_gaussian" in data["separable"]:
            fields = [_triple(data, ["separable", "two_gaussian", f], path)
                      for f in ("w", "sigma_near_mm", "sigma_far_mm")]
            tg = TwoGaussianMaterial(albedo, *fields)
        sta = None
        s = data.get("sta", sta)
        if s is not None:
            if not isinstance(s, dict):
                raise SSSInputError(f"{path}: sta must be an object of STA parameters")
            allowed = ("distortion", "power", "scale", "ambient", "thickness_mm")
            unknown = sorted(set(s) - set(allowed))
            if unknown:  # a misspelt name ("distorsion") would leave its parameter at the default without a word
                raise SSSInputError(f"{path}: sta has no parameter(s) {', '.join(unknown)}; its parameters: "
                                    f"{', '.join(allowed)}")
            for k in allowed:
                if k in s and not _numeric(s[k]):
                    raise SSSInputError(f"{path}: sta.{k} must be a number or a list of numbers, got {s[k]!r}")
            sta = STAParams(**{k: v for k, v in s.items() if k in allowed})
        medium = None
        if "transmittance" in data:
            tr = data["transmittance"]
            if not isinstance(tr, dict) or not all(k in tr for k in ("thickness_mm", "T", "resolved")):
                raise SSSInputError(f"{path}: transmittance must be an object with thickness_mm, T and resolved")
            # the medium's single-scattering albedo (its exit distribution's, _slab.slab_exit) from the source
            src = data.get("source") if isinstance(data.get("source"), dict) else {}
            alb = src.get("medium", {}).get("single_scattering_albedo") if isinstance(src.get("medium"), dict) \
                else None
            table = tr if alb is None or "albedo" in tr else {**tr, "albedo": alb}
            try:
                medium = MediumMaterial.from_tables(burley, [table])
            except ValueError as exc:  # the table's own message, the field named
                raise SSSInputError(f"{path}: transmittance: {exc}") from None
            except (TypeError, IndexError, KeyError) as exc:  # "tuple index out of range" named no field before
                raise SSSInputError(f"{path}: transmittance (thickness_mm, T and resolved: a list per channel) "
                                    f"is not a table of numbers ({type(exc).__name__}: {exc})") from None
    except SSSInputError:
        raise
    except (ValueError, TypeError, IndexError, KeyError) as exc:
        raise SSSInputError(f"{path}: invalid preset: {exc!s}") from None
    return Preset(name=str(data.get("name", path.stem)), path=str(path), burley=burley, two_gaussian=tg, sta=sta,
                  raw=data, medium=medium)


def material_for(technique, preset: Preset, *, albedo=None):
    """The material ``technique`` (a technique object, or its registry name: its default options) takes from a
    preset: the first of the preset's STA parameters, two-Gaussian kernel, measured medium and Burley material that
    the technique accepts (so the separable prefers the fitted two-Gaussian kernel to the pre-integrated profile).
    ``albedo`` (3,) overrides the preset's Burley or two-Gaussian albedo; the STA parameters and a measured medium
    are taken whole (an ``albedo`` given for them is an error, not dropped)."""
    from ._techniques import AbstractTechnique, get_technique

    if isinstance(technique, AbstractTechnique):
        name, accepts = technique.name, technique.takes
    else:
        cls = get_technique(technique)
        name, accepts = cls.name, cls.accepts
    for material in (preset.sta, preset.two_gaussian, preset.medium, preset.burley):
        if material is not None and accepts(material):
            break
    else:
        raise SSSInputError(f"{preset.path}: preset has no {name} parameters")
    if albedo is None:
        return material
    if isinstance(material, TwoGaussianMaterial):
        return TwoGaussianMaterial(albedo, material.w, material.sigma_near_mm, material.sigma_far_mm)
    if isinstance(material, BurleyMaterial):
        return BurleyMaterial(albedo, material.d_mm)
    kind = "STA parameters" if isinstance(material, STAParams) else "measured medium"
    raise ValueError(f"{preset.path}: an albedo does not apply to the preset's {kind}, which {name} takes whole")
