"""The registry of engines and the entry points every user of them goes through (``convert``, presets' engine
blocks, ``engine_profile_error``, the report): no caller tests an engine's name."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ._base import AbstractEngine, SssJax
from ._blender import Blender
from ._common import bins, burley_marginal_masses, material, relative_l2
from ._eevee import Eevee
from ._eevee_next import EeveeNext
from ._hdrp import Hdrp
from ._jimenez import Jimenez
from ._unreal import Unreal

REGISTRY: dict[str, AbstractEngine] = {e.name: e for e in (SssJax(), Blender(), Eevee(), EeveeNext(), Hdrp(),
                                                             Unreal(), Jimenez())}
ENGINES = tuple(REGISTRY)
# Which engines cannot hold an arbitrary sss_jax material exactly (A -> engine -> A differs), and why.
LOSSY = {name: e.lossy for name, e in REGISTRY.items()}
# The engines a preset carries a block for, and the kernels engine_profile_error compares (in this order).
BLOCK_ENGINES = tuple(name for name in ENGINES if name != "sss_jax")
KERNELS = tuple(e.kernel for e in REGISTRY.values() if e.kernel is not None)


def get_engine(name: str) -> AbstractEngine:
    """The registered engine ``name``; the error lists the valid names."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown engine {name!r}; valid engines: {', '.join(ENGINES)}") from None


def to_engine(engine: str, albedo, d_mm, **options) -> dict[str, Any]:
    """The engine's parameters (UI names) for the sss_jax material ``(albedo (3,), d_mm (3,) in mm)``."""
    return finite_block(engine, get_engine(engine).to_engine(albedo, d_mm, **options))


def finite_block(engine: str, block: dict[str, Any]) -> dict[str, Any]:
    """``block`` (an engine's parameters), or an error naming the first value that is not a finite number (a d of
    1e308 mm gave HDRP a "Max Radius (mm)" of inf, written to JSON as ``Infinity``, which JSON does not have)."""
    for key, value in block.items():
        values = np.asarray(value, dtype=object).ravel() if isinstance(value, (list, tuple, np.ndarray)) else [value]
        for v in values:
            if isinstance(v, (float, np.floating)) and not math.isfinite(v):
                raise ValueError(f"{engine}: {key} would be {v}: the material is beyond what the engine's "
                                 f"parameters hold")
    return block


def from_engine(engine: str, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) from an engine's parameters, given by the UI names ``to_engine`` writes."""
    return get_engine(engine).from_engine(_params(engine, params))


def _params(engine: str, params) -> dict[str, Any]:
    """An engine's parameters as a new dict (the engine may fill it in), or an error naming what was given."""
    if not isinstance(params, Mapping):
        raise TypeError(f"{engine} parameters must be a mapping of its parameter names to values (as to_engine "
                        f"writes them), got {type(params).__name__}")
    return dict(params)


def convert(source: str, target: str, params: dict[str, Any], **target_options) -> dict[str, Any]:
    """Convert a material from ``source``'s parameters to ``target``'s: ``{"from", "to", "albedo", "burley":
    {"d_mm"}, target: {...}, "lossy": reason or None, "unverified": reason or None, "sources": {engine: citation}}``
    (JSON-serialisable)."""
    src, dst = get_engine(source), get_engine(target)
    albedo, d = src.from_engine(_params(source, params))
    out = {"from": source, "to": target, "albedo": albedo.tolist(), "burley": {"d_mm": d.tolist()},
           target: finite_block(target, dst.to_engine(albedo, d, **target_options))}
    sides = {source: (src, params), target: (dst, out[target])}  # one entry when source == target
    for note in ("note", "lossy", "unverified"):
        reasons = [f"{name}: {e.notes(p)[note]}" for name, (e, p) in sides.items() if e.notes(p).get(note)]
        out[note] = "; ".join(reasons) if reasons else None
    engines = [e for e, _ in sides.values()]
    out["sources"] = {e.name: e.source for e in engines}
    return out


def engine_blocks(albedo, d_mm, *, mm_per_unit: float | None = None,
                  options: dict[str, dict[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """One block per engine for a preset (``fits/<material>.json``): that engine's parameters for the material in
    its usual scene unit (Blender, EEVEE, HDRP, separable SSS 1 m; UE 1 cm) unless ``mm_per_unit`` is given, with
    per-engine ``options`` (e.g. ``{"hdrp": {"subsurface_mask": 0.5}, "unreal": {"opacity": 0.8}, "jimenez":
    {"alpha": 0.9}}``; every per-material multiplier defaults to 1 and is written into its block)."""
    albedo, d = material(albedo, d_mm)
    options = options or {}
    unknown = set(options) - set(BLOCK_ENGINES)
    if unknown:
        raise ValueError(f"options for unknown engines {sorted(unknown)}; valid: {', '.join(BLOCK_ENGINES)}")
    unit = {} if mm_per_unit is None else {"mm_per_unit": mm_per_unit}
    return {name: REGISTRY[name].block(albedo, d, **{**unit, **options.get(name, {})}) for name in BLOCK_ENGINES}


def engine_marginals(albedo, d_mm, *, blocks: dict[str, dict[str, Any]] | None = None,
                     rendered: bool = True) -> dict[str, Any]:
    """What each engine renders for the material, as 1D-marginal bin masses (3, 163) on the reference bins.

    ``edges`` (3, 162) in mm; ``reference``: the untruncated Burley marginal; then one entry per engine kernel
    (``KERNELS``: ``cycles``, ``eevee``, ``eevee-next``, ``hdrp``, ``unreal``, ``jimenez``), each the engine's own
    kernel as its class builds it (``AbstractEngine.marginal``), from ``blocks`` (a preset's engine blocks) where
    given, so a stored fit is not redone. Masses are normalised profiles; each engine's albedo factor is in
    ``albedo``. With ``rendered`` (default), also what each engine's own pass renders at its real budget
    (``AbstractEngine.rendered``: ``hdrp:low|medium|high``, ``eevee-next:taa256``, ``jimenez:comb``,
    ``jimenez:comb-refit``), each described in ``rendered`` (key -> what it is).
    """
    albedo, d = material(albedo, d_mm)
    if not np.all(d > 0):
        raise ValueError(f"engine_marginals needs d_mm > 0 in every channel, got {d.tolist()}")
    blocks = blocks or {}
    edges = bins(d)
    out: dict[str, Any] = {"edges": edges, "reference": burley_marginal_masses(d, edges)}
    albedos = {"reference": albedo}
    whats: dict[str, str] = {}
    for name, engine in REGISTRY.items():
        if engine.kernel is None:
            continue
        block = blocks.get(name)
        known = block if isinstance(block, dict) and "error" not in block else None
        result = engine.marginal(albedo, d, edges, known)
        if result is not None:
            out[engine.kernel], albedos[engine.kernel] = result
        if rendered:
            for key, (masses, a, what) in engine.rendered(albedo, d, edges, known).items():
                out[key], albedos[key], whats[key] = masses, a, what
    out["albedo"] = albedos
    out["rendered"] = whats
    return out


def engine_errors_against(marg: dict[str, Any], ref: np.ndarray, ref_albedo) -> dict[str, dict[str, Any]]:
    """Each engine's marginal masses of ``engine_marginals`` against reference masses ``ref (3, 163)`` on the same
    bins (Burley's, or a Monte Carlo profile's) with that reference's albedo (3,): relative L2 and energy lost."""
    a_ref = np.asarray(ref_albedo, np.float64)
    out = {}
    for kernel in (*KERNELS, *marg.get("rendered", {})):
        if kernel not in marg:
            continue
        m = marg[kernel]
        a = np.asarray(marg["albedo"][kernel])
        total = a * np.sum(m, axis=1)
        lost = np.where(a_ref > 0, 1.0 - total / np.where(a_ref > 0, a_ref * np.sum(ref, axis=1), 1.0), 0.0)
        what = marg.get("rendered", {}).get(kernel, "the engine's idealised kernel (its conversion's profile, "
                                                    "truncated or fitted as the engine builds it)")
        out[kernel] = {"error_relative_l2": relative_l2(m, ref).tolist(), "energy_lost": lost.tolist(), "what": what}
    return out


def engine_profile_error(albedo, d_mm, **options) -> dict[str, dict[str, Any]]:
    """Per engine kernel, how far it renders from the Burley reference of the material, per channel: each engine's
    idealised kernel (``hdrp``, ``eevee-next``, ``jimenez``, ...) and, beside it, what its own pass renders at its real
    budget (``hdrp:low``/``medium``/``high``, ``eevee-next:taa256``, ``jimenez:comb`` at 1 px/mm and
    ``jimenez:comb-refit``, the parameters fitted through that comb), each entry naming itself in ``what``.

    ``error_relative_l2``: ``||m_engine - m_ref|| / ||m_ref||`` over the 1D-marginal bin masses of
    ``engine_marginals`` (161 bins of width d/4 centred on 0 plus both tails); the 1D marginal is what one pass of a
    separable engine applies and what a radial engine's kernel projects to. ``energy_lost``: ``1 - A_engine
    sum(m_engine) / (A sum(m_ref))``, the fraction of the material's diffuse reflectance the engine does not return.
    ``cycles`` is Blender's Christensen–Burley (either version: the converted radius gives the same d); Cycles' random
    walks are measured against Monte Carlo in docs/engines.md instead.
    """
    marg = engine_marginals(albedo, d_mm, **options)
    return engine_errors_against(marg, marg["reference"], marg["albedo"]["reference"])
