"""The advisor: the cheapest technique and sample count whose measured error stays under a colour-difference budget.

Every candidate (local shading, ``separable`` at several tap counts, ``burley`` at several sample counts, or the
techniques the caller names, the engines' passes among them, with the options given) is run on the scene (the demo scene with every object made of the material, or the caller's buffers), timed on this machine
(median and interquartile range of repeated runs after a compile run) and compared with ``reference``: the error is
the mean CIEDE2000 over the SSS pixels (colour-science, on the host, linear sRGB at exposure 0). The choice is the
fastest candidate whose ΔE is within the budget; where the fastest one's interquartile range of times overlaps
another's within the budget, the two are within the noise of this machine: the advisor says so and takes the more
accurate of them.
Errors depend on the material's scattering distance against the scene's scale in pixels, so the scene scale
matters as much as the material: ``scene_scale`` multiplies the size of a scene unit in millimetres.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._checks import check_host_count
from ._timing import run_times
from ._materials import BurleyMaterial
from ._scene import Buffers, Camera, demo_scene
from ._sweep import changed_options, technique_runs
from ._techniques import AbstractTechnique, reference

__all__ = [
    "DEFAULT_CANDIDATES",
    "DEFAULT_COUNTS",
    "Advice",
    "Candidate",
    "advise",
    "choose",
    "known_materials",
    "candidate_runs",
    "measure_candidates",
    "resolve_material",
]

DEFAULT_CANDIDATES: tuple[tuple[str, int | None], ...] = (
    ("local", None), ("separable", 5), ("separable", 9), ("separable", 17), ("separable", 25),
    ("burley", 4), ("burley", 8), ("burley", 16), ("burley", 32), ("burley", 64),
)
# the counts a named technique is weighed at, by its count option (a technique without one is weighed once)
DEFAULT_COUNTS: dict[str, tuple[int, ...]] = {"taps": (5, 9, 17, 25), "samples": (4, 8, 16, 32, 64)}


@dataclasses.dataclass(frozen=True)
class Candidate:
    technique: str  # "local" (albedo * irradiance, no scattering) or a technique's registry name
    count: int | None  # taps or samples
    ms: float  # median time per frame on this machine
    delta_e: float  # mean CIEDE2000 against the reference over SSS pixels
    ms_low: float | None = None  # the timings' 25th percentile (None: one timing, no spread known)
    ms_high: float | None = None  # their 75th percentile
    options: dict = dataclasses.field(default_factory=dict, hash=False)  # its options that differ from the defaults

    @property
    def label(self) -> str:
        return " ".join([self.technique] + ([str(self.count)] if self.count is not None else [])
                        + [f"{k}={v}" for k, v in self.options.items()])

    @property
    def interval(self) -> tuple[float, float]:
        """The range of time per frame this machine's noise allows (ms): the interquartile range, or the median."""
        return (self.ms if self.ms_low is None else self.ms_low, self.ms if self.ms_high is None else self.ms_high)

    def within_noise_of(self, other: "Candidate") -> bool:
        """Whether the two cannot be told apart by time: their intervals overlap."""
        (lo, hi), (olo, ohi) = self.interval, other.interval
        return lo <= ohi and olo <= hi


@dataclasses.dataclass(frozen=True)
class Advice:
    material: str
    max_delta_e: float
    choice: Candidate | None
    candidates: list[Candidate]
    reason: str
    against: str = "reference"  # what delta_e is measured against: "reference" or "truth"

    @property
    def worse_than_local(self) -> list[Candidate]:
        """The candidates whose error is above local shading's (no SSS at all) on this scene: the floor."""
        return worse_than_local(self.candidates)

    def table(self) -> str:
        width = max([14] + [len(c.label) for c in self.candidates])
        lines = [f"{'candidate':{width}s} {'ms/frame':>10s} {'(25-75%)':>15s} {'mean dE2000':>12s}  within budget"]
        worse = self.worse_than_local
        for c in sorted(self.candidates, key=lambda c: c.ms):
            mark = "yes" if c.delta_e <= self.max_delta_e else "no"
            pick = "  <- choice" if c == self.choice else ""
            flag = "  (worse than local shading)" if c in worse else ""
            lo, hi = c.interval
            lines.append(f"{c.label:{width}s} {c.ms:10.2f} {f'{lo:.2f}-{hi:.2f}':>15s} {c.delta_e:12.3f}  "
                         f"{mark}{pick}{flag}")
        tail = [self.reason]
        if worse:
            tail.append(f"worse than local shading against the {self.against}: "
                        + ", ".join(c.label for c in worse))
        return "\n".join(lines + tail)

    def to_json(self) -> dict:
        as_dict = lambda c: None if c is None else {"technique": c.technique, "count": c.count, "ms": c.ms,
                                                        "ms_low": c.interval[0], "ms_high": c.interval[1],
                                                        "delta_e": c.delta_e, "options": dict(c.options),
                                                        "label": c.label}
        return {"material": self.material, "max_delta_e": self.max_delta_e, "choice": as_dict(self.choice),
                "candidates": [as_dict(c) for c in self.candidates], "reason": self.reason, "against": self.against,
                "worse_than_local_shading": [c.label for c in self.worse_than_local]}


def known_materials() -> list[str]:
    """The demo's materials and the presets found (``fits/`` and ``$SSS_JAX_PRESETS``)."""
    from ._demo import DEMO_MATERIALS
    from ._presets import preset_dirs

    presets = {c.stem for d in preset_dirs() if d.is_dir() for c in d.glob("*.json") if c.stem != "schema"}
    return sorted(set(DEMO_MATERIALS) | presets)


def resolve_material(material: str | BurleyMaterial) -> tuple[str, BurleyMaterial]:
    """A name (a demo material, else a preset by name or file) or a ``BurleyMaterial`` -> (name, material)."""
    if isinstance(material, BurleyMaterial):
        return "custom", material
    from ._demo import DEMO_MATERIALS

    if material in DEMO_MATERIALS:
        m = DEMO_MATERIALS[material]
        return material, BurleyMaterial(np.asarray(m["albedo"], np.float32), np.asarray(m["d_mm"], np.float32))
    from ._io import SSSInputError
    from ._presets import load_preset

    try:
        preset = load_preset(material)
    except SSSInputError as exc:
        if os.path.isfile(material):  # a preset file given: what is wrong with it, not "unknown material"
            raise ValueError(str(exc)) from None
        raise ValueError(f"unknown material {material!r}; known materials: {', '.join(known_materials())} "
                         f"({exc})") from None
    b = preset.burley
    return preset.name, BurleyMaterial(np.asarray(b.albedo, np.float32), np.asarray(b.d_mm, np.float32))


def time_ms(fn: Callable[[], jax.Array], repeats: int) -> list[float]:
    """``repeats`` timings of ``fn`` (ms, each until its result is ready), after one run that compiles it."""
    fn().block_until_ready()  # compile
    return [1e3 * t for t in run_times(fn, repeats)]


def _scene(size: tuple[int, int], scene_scale: float) -> tuple[Buffers, Camera]:
    scene = demo_scene(*size)
    b = scene.buffers
    ids = (np.asarray(b.material_id) > 0).astype(np.int32)  # every object made of the one material
    buffers = Buffers(irradiance=b.irradiance, depth=b.depth, material_id=jnp.asarray(ids))
    cam = Camera(float(scene.camera.focal_px), float(scene.camera.mm_per_unit) * scene_scale)
    return buffers, cam


def candidate_runs(*, techniques: Sequence[str | AbstractTechnique] | None = None,
                   technique_options: Mapping[str, Mapping[str, Any]] | None = None,
                   candidates: Sequence[tuple[str | AbstractTechnique, int | None]] | None = None
                   ) -> list[tuple[str, AbstractTechnique | None]]:
    """``(technique name, object)`` per candidate, local shading first (object None).

    ``candidates``: ``(name or object, count)`` pairs (``("local", None)`` is local shading); a name is built from
    the registry with ``technique_options[name]`` and the count as its count option. ``techniques``: names (or
    objects) instead, each weighed at ``DEFAULT_COUNTS`` of its count option, or at the counts given in its options
    (``{"burley": {"samples": (8, 32)}}``), or once; local shading is added. Default: ``DEFAULT_CANDIDATES``."""
    from ._techniques import get_technique

    options = technique_options or {}
    if techniques is not None:
        if candidates is not None:
            raise ValueError("give techniques or candidates, not both")
        return [("local", None)] + [(t.name, t) for t in technique_runs(techniques, options, DEFAULT_COUNTS)]
    out: list[tuple[str, AbstractTechnique | None]] = []
    for tech, n in (DEFAULT_CANDIDATES if candidates is None else candidates):
        if isinstance(tech, AbstractTechnique):
            t = tech if n is None or tech.count_option is None else tech.replace(**{tech.count_option: n})
            out.append((t.name, t))
            continue
        if tech == "local":
            out.append(("local", None))
            continue
        try:
            cls = get_technique(tech)
        except ValueError as exc:
            raise ValueError(f"unknown candidate technique {tech!r}; {exc}") from None
        count = {} if n is None or cls.count_option is None else {cls.count_option: n}
        out.append((cls.name, cls(**{**options.get(cls.name, {}), **count})))
    return out


def measure_candidates(material: BurleyMaterial, *, buffers: Buffers | None = None, camera: Camera | None = None,
                       size: tuple[int, int] = (72, 96), scene_scale: float = 1.0,
                       candidates: Sequence[tuple[str | AbstractTechnique, int | None]] | None = None,
                       repeats: int = 5, progress: Callable[[str], None] | None = None,
                       timer: Callable[[Callable[[], jax.Array], int], list[float]] = time_ms,
                       truth=None, techniques: Sequence[str | AbstractTechnique] | None = None,
                       technique_options: Mapping[str, Mapping[str, Any]] | None = None) -> list[Candidate]:
    """Time (median and interquartile range of ``repeats`` runs) and ΔE2000 (against ``reference``, or against
    ``truth``, an ``(H, W, 3)`` offline render of the given buffers' view, when given) of each candidate on the
    scene; host-side ΔE via colour-science. ``timer(fn, repeats)`` returns the timings in ms (``time_ms``; tests
    inject their own). The candidates: ``candidate_runs(techniques=, technique_options=, candidates=)``."""
    from ._metrics import delta_e_2000
    from ._techniques._common import _sss_mask

    say = progress or (lambda m: None)
    runs = candidate_runs(techniques=techniques, technique_options=technique_options, candidates=candidates)
    if (buffers is None) != (camera is None):
        raise ValueError("pass both buffers and camera, or neither (the demo scene)")
    if buffers is None:
        buffers, camera = _scene(size, scene_scale)
    if not scene_scale > 0:
        raise ValueError(f"scene_scale must be > 0, got {scene_scale!r}")
    for name, t in runs:
        if t is not None and not t.takes(material):
            raise ValueError(f"{name} takes no {type(material).__name__} (the advisor's material): leave it out")
    mask = np.asarray(_sss_mask(buffers))
    if not mask.any():
        raise ValueError("the scene has no SSS pixels to measure")
    if truth is not None:
        ref = np.asarray(truth, np.float64)
        if ref.shape != tuple(buffers.depth.shape) + (3,):
            raise ValueError(f"truth is {ref.shape}, the buffers {tuple(buffers.depth.shape)}: it must be the same "
                             "view, (H, W, 3)")
    else:
        say(f"reference ({buffers.depth.shape[1]}x{buffers.depth.shape[0]}) ...")
        ref = np.asarray(reference(buffers, material, camera, **dict((technique_options or {}).get("reference", {}))))
    albedo = np.asarray(buffers.albedo if buffers.albedo is not None else
                        np.broadcast_to(np.asarray(material.albedo).reshape(-1, 3)[0], ref.shape))
    local_fn = jax.jit(lambda e, m, a: jnp.where(m[..., None], a * e, e))
    out = []
    for i, (name, t) in enumerate(runs):
        count = None if t is None or t.count_option is None else int(getattr(t, t.count_option))
        options = {} if t is None else changed_options(t)
        say(f"[{i + 1}/{len(runs)}] {Candidate(name, count, 0.0, 0.0, options=options).label}")
        if t is None:
            fn = lambda: local_fn(buffers.irradiance, jnp.asarray(mask), jnp.asarray(albedo))  # noqa: E731
        else:
            fn = lambda t=t: t(buffers, material, camera)  # noqa: E731
        times = np.asarray(timer(fn, repeats), np.float64)
        de = delta_e_2000(np.asarray(fn()), ref, mask=mask)["mean"]
        low, median, high = (round(float(v), 3) for v in np.percentile(times, [25, 50, 75]))
        out.append(Candidate(name, count, median, round(float(de), 4), low, high, options=options))
    return out


def worse_than_local(candidates: Sequence[Candidate]) -> list[Candidate]:
    """The candidates less accurate than local shading (no SSS), where local shading is one of them."""
    local = [c for c in candidates if c.technique == "local"]
    if not local:
        return []
    return [c for c in candidates if c.technique != "local" and c.delta_e > local[0].delta_e]


def choose(candidates: Sequence[Candidate], max_delta_e: float) -> tuple[Candidate | None, str]:
    """The fastest candidate whose ΔE is within the budget, and why. Candidates within the budget whose timings
    cannot be told from the fastest one's (``Candidate.within_noise_of``: interquartile ranges overlap) tie with it,
    and the most accurate of the tie is the choice. A candidate less accurate than local shading (no SSS), when local
    shading is a candidate, is never the choice: local shading is the better and cheaper one."""
    worse = worse_than_local(candidates)
    within = [c for c in candidates if c.delta_e <= max_delta_e and c not in worse]
    if not within:
        best = min(candidates, key=lambda c: (c.delta_e, c.ms))
        return None, (f"no candidate stays within mean dE2000 {max_delta_e:g}; the most accurate is {best.label} "
                      f"(dE {best.delta_e:.3f}, {best.ms:.2f} ms): raise the budget or use the reference")
    fastest = min(within, key=lambda c: (c.ms, c.delta_e))
    tied = [c for c in within if c.within_noise_of(fastest)]
    pick = min(tied, key=lambda c: (c.delta_e, c.ms))
    slower_better = [c for c in within if c is not pick]
    if pick is fastest:
        why = (f"choice: {pick.label}, the fastest of the {len(within)} candidates within mean dE2000 "
               f"{max_delta_e:g} ({pick.ms:.2f} ms, dE {pick.delta_e:.3f})")
    else:
        lo, hi = fastest.interval
        why = (f"choice: {pick.label} ({pick.ms:.2f} ms, dE {pick.delta_e:.3f}): {fastest.label} has the lowest "
               f"median time ({fastest.ms:.2f} ms, {lo:.2f}-{hi:.2f}) but "
               f"{', '.join(c.label for c in tied if c is not fastest)} {'is' if len(tied) == 2 else 'are'} within "
               f"the timing noise of this machine "
               f"(overlapping interquartile ranges), and of those {pick.label} is the most accurate")
    others_tied = [c.label for c in tied if c is not pick and c is not fastest]
    if pick is fastest and len(tied) > 1:
        why += f"; within the timing noise of it: {', '.join(c.label for c in tied if c is not pick)}, less accurate"
    elif others_tied:
        why += f"; also within the noise: {', '.join(others_tied)}"
    if slower_better:
        runner = min(slower_better, key=lambda c: (c.ms, c.delta_e))
        why += f"; next: {runner.label} ({runner.ms:.2f} ms, dE {runner.delta_e:.3f})"
    cheaper = [c for c in candidates if c.ms < pick.ms and c.delta_e > max_delta_e]
    if cheaper:
        c = min(cheaper, key=lambda c: c.delta_e)
        why += f"; the best cheaper one, {c.label}, misses the budget (dE {c.delta_e:.3f})"
    if pick.technique == "local":
        why += "; local shading already meets the budget on this scene: subsurface scattering is not needed here"
    return pick, why


def advise(material: str | BurleyMaterial, *, max_delta_e: float = 1.0, buffers: Buffers | None = None,
           camera: Camera | None = None, size: tuple[int, int] = (72, 96), scene_scale: float = 1.0,
           candidates: Sequence[tuple[str | AbstractTechnique, int | None]] | None = None, repeats: int = 5,
           progress: Callable[[str], None] | None = None,
           measure: Callable[..., list[Candidate]] | None = None, truth=None,
           techniques: Sequence[str | AbstractTechnique] | None = None,
           technique_options: Mapping[str, Mapping[str, Any]] | None = None) -> Advice:
    """Measure the candidates for ``material`` on the scene and pick the cheapest within ``max_delta_e``.

    ``material``: a demo material name (``sss_jax._demo.DEMO_MATERIALS``), a preset name or file, or a
    ``BurleyMaterial``. The scene is the demo scene at ``size`` (H, W) with every object made of the material and
    ``scene_scale`` times its size in mm, or the given ``buffers``/``camera``. ``measure`` replaces the measurement
    (same keywords as ``measure_candidates``; tests stub it). ``truth``: an offline render of ``buffers``' view,
    ``(H, W, 3)``: the errors are then against it, not the reference. Local shading is the floor: every candidate
    doing worse than it is flagged (``Advice.worse_than_local``, in the table and the JSON).
    ``techniques``: the techniques to weigh (registry names, the engines' passes among them, or technique objects)
    instead of the default candidates, each at ``DEFAULT_COUNTS`` of its count option (or the counts its options
    give), or once; ``technique_options``: ``{name: {option: value}}`` for the techniques built from names (the
    ``reference``'s too); ``candidates``: explicit ``(name or object, count)`` pairs (``candidate_runs``).
    """
    if not (max_delta_e >= 0):
        raise ValueError(f"max_delta_e must be >= 0, got {max_delta_e!r}")
    # what the command line checks, checked here for the library's callers too (min() of an empty sequence, an
    # IndexError, or a camera's message about its own mm_per_unit)
    check_host_count(repeats, "repeats")
    if not (float(scene_scale) > 0 and math.isfinite(float(scene_scale))):
        raise ValueError(f"scene_scale must be a finite positive number, got {scene_scale!r}")
    candidates = None if candidates is None else list(candidates)
    if candidates is not None and not candidates:
        raise ValueError("candidates: give at least one (name or technique, count) pair, or None for the defaults")
    name, mat = resolve_material(material)
    if truth is not None and buffers is None:
        raise ValueError("truth needs the buffers (and camera) of the view it renders")
    extra = {} if truth is None else {"truth": truth}
    if techniques is not None:
        extra["techniques"] = techniques
    if technique_options:
        extra["technique_options"] = technique_options
    cands = (measure or measure_candidates)(mat, buffers=buffers, camera=camera, size=size, scene_scale=scene_scale,
                                            candidates=candidates, repeats=repeats, progress=progress, **extra)
    choice, reason = choose(cands, max_delta_e)
    return Advice(material=name, max_delta_e=float(max_delta_e), choice=choice, candidates=list(cands), reason=reason,
                  against="reference" if truth is None else "truth")
