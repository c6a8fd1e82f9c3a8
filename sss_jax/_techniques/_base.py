"""The technique abstraction: one final equinox Module per technique, all answering the same questions.

A technique object carries its options as fields (static, so a new option value is a new compilation, except the
traced ones such as Burley's ``seed``), and answers for what it needs and does:

- ``name`` (the registry's), ``conserves_energy`` (SSSS, Burley and the reference redistribute light; STA adds it),
  ``material_type`` (the material class or classes it takes);
- ``technique(buffers, material, camera, *, origin=(0, 0), frame_shape=None)``: the image ``(H, W, 3)``; a tile
  passes its top-left pixel in the whole frame (``origin``) and the frame's ``(H, W)`` (``frame_shape``), so the
  rotation hash and the frame border follow the frame, not the tile;
- ``reach_px(buffers, material, camera)`` (host side): how many pixels away a pixel of the result reads, the halo a
  tile needs for its pixels to be the untiled frame's;
- ``check(buffers, material, camera)`` (host side): the sampling and window warnings a call would raise
  (``SamplingWarning``, ``ReferenceWindowWarning``), as warning objects, so a batch can report them per frame.

Options are declared with ``option(default, help, choices=...)``: the command line builds its flags from
``option_fields()``, and a value outside ``choices`` is an error at construction naming the option. Callers (batch,
report, match, bench, advise, the CLI) ask the object; none of them tests a technique's name. Models: diffrax's
``AbstractSolver``, optimistix's ``AbstractMinimiser``, this project's ``engines._base.AbstractEngine``.
"""

from __future__ import annotations

import abc
import collections
import dataclasses
import functools
import inspect
import threading
from collections.abc import Callable
from typing import Any, ClassVar

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from .._checks import is_bool
from .._errors import TilePlacementError
from .._scene import Buffers, Camera
from ._dispatch import check_tile


def option(default: Any, help: str, *, choices: tuple | None = None, static: bool = True) -> Any:
    """A technique option: a field with its default, its help (the CLI's) and, for a closed set, its ``choices``.

    ``static=False`` for an option that is traced (a new value does not recompile, e.g. a seed)."""
    metadata = {"help": help}
    if choices is not None:
        metadata["choices"] = tuple(choices)
    if static:  # a NumPy scalar (np.int64(8)) kept as the Python value it stands for: hashable, JSON, no warning
        return eqx.field(static=True, default=default, metadata=metadata, converter=_host_scalar)
    return eqx.field(static=False, default=default, metadata=metadata)


def _host_scalar(value: Any) -> Any:
    """``value``, a NumPy scalar or 0-d NumPy array as its Python scalar (``.item()``); anything else unchanged."""
    if isinstance(value, np.generic) or (type(value) is np.ndarray and value.ndim == 0):
        return value.item()
    return value


def default_of(function: Callable, name: str) -> Any:
    """The default of keyword ``name`` in ``function``'s signature: the technique function is the one owner of its
    defaults, so the class's option follows a change there."""
    parameter = inspect.signature(function).parameters.get(name)
    if parameter is None or parameter.default is inspect.Parameter.empty:
        raise TypeError(f"{function.__name__} has no keyword option {name!r} with a default")
    return parameter.default


class AbstractTechnique(eqx.Module):
    """A screen-space SSS technique. Concrete techniques are final; ``technique(name, **options)`` builds one."""

    name: eqx.AbstractClassVar[str]  # the registry's name
    conserves_energy: eqx.AbstractClassVar[bool]  # redistributes light (True) or adds it (False)
    material_type: eqx.AbstractClassVar[type | tuple[type, ...]]  # the material class(es) it takes
    # the option whose value is the technique's sample count, which a report sweeps ("samples", "taps"; None: none)
    count_option: ClassVar[str | None] = None
    # an eager call computes only the SSS pixels (compacted on the host): its work follows their share of the frame
    # (a batch's work estimate scales with it)
    sss_pixels_only: ClassVar[bool] = False

    def __check_init__(self):
        for name, choices in _choices_of(type(self)):
            value = getattr(self, name)
            if not _is_choice(value, choices):
                raise ValueError(f"{self.name}: {name}={value!r} is not one of {choices}")

    @abc.abstractmethod
    def __call__(self, buffers: Buffers, material: Any, camera: Camera, *, origin: tuple[int, int] = (0, 0),
                 frame_shape: tuple[int, int] | None = None) -> Float[Array, "H W 3"]:
        """The technique applied to ``buffers`` (one image) with ``material`` seen by ``camera``."""

    @abc.abstractmethod
    def reach_px(self, buffers: Buffers, material: Any, camera: Camera) -> int:
        """Host side: the farthest (in px, along a row or a column) a pixel of the result reads from: a tile with
        this halo on every side computes its inner pixels as the untiled frame does."""

    def check(self, buffers: Buffers, material: Any, camera: Camera) -> list[Warning]:
        """Host side: the warnings (``SamplingWarning``, ``ReferenceWindowWarning``) a call with these inputs
        raises; none by default."""
        return []

    def pieces(self, count: int) -> tuple[tuple["AbstractTechnique", float], ...] | None:
        """This technique's work as about ``count`` calls, ``(technique, weight)`` pairs whose results, weighted and
        summed, are this technique's pixels (to rounding): a long frame runs in pieces, each short enough for
        progress and Ctrl-C. ``None`` (the default): its work does not split (tiles are then the only pieces)."""
        return None

    def spread(self, count: int) -> "AbstractTechnique":
        """The technique with its work laid out so that ``pieces`` can split it into about ``count`` calls, the same
        count per pixel (Burley: samples moved into frames of their own rotation), for a frame too long for one
        call; itself (the default) where there is nothing to spread. Not the same pixels: the batch records the
        technique that ran."""
        return self

    @classmethod
    def option_fields(cls) -> tuple[dataclasses.Field, ...]:
        """The technique's options (the fields declared with ``option``), in declaration order."""
        return tuple(f for f in dataclasses.fields(cls) if "help" in f.metadata)

    @classmethod
    def option_fields_names(cls) -> tuple[str, ...]:
        return _option_names(cls)

    def options(self) -> dict[str, Any]:
        """The options' values by name (what a report or a manifest records)."""
        return {name: getattr(self, name) for name in _option_names(type(self))}

    def replace(self, **changes: Any) -> "AbstractTechnique":
        """This technique with some options changed (``t.replace(samples=64)``)."""
        check_option_names(type(self), changes)
        return dataclasses.replace(self, **changes)

    @classmethod
    def accepts(cls, material: Any, **options: Any) -> bool:
        """Whether the technique with ``options`` (its defaults elsewhere) takes ``material``; host side, without
        building the technique."""
        return isinstance(material, cls.material_type)

    def takes(self, material: Any) -> bool:
        """Whether ``material`` is one this technique (with its options) takes (``accepts`` with its options: a
        technique whose material depends on an option overrides both)."""
        return isinstance(material, self.material_type)

    def traces_camera(self, material: Any) -> bool:
        """Whether a call with ``material`` can run with the camera traced (a batch on several devices vmaps its
        frames, cameras and all); not where the technique reads the camera on the host."""
        return True

    def check_material(self, material: Any) -> None:
        """A ``TypeError`` naming the technique and the material classes it takes, unless it takes ``material``."""
        if not type(self).takes(self, material):
            kinds = self.material_type if isinstance(self.material_type, tuple) else (self.material_type,)
            raise TypeError(f"{self.name} needs a {' or '.join(k.__name__ for k in kinds)}, "
                            f"got {type(material).__name__}")


@functools.lru_cache(maxsize=None)
def _option_names(cls: type) -> tuple[str, ...]:
    """The option fields' names of a technique class (cached: asked on every call)."""
    return tuple(f.name for f in dataclasses.fields(cls) if "help" in f.metadata)


def _is_choice(value, choices: tuple) -> bool:
    """Whether ``value`` is one of ``choices``, a bool only as a bool (``1 == True`` in Python: a switch given 1
    would pass for True and a count given True for 1)."""
    flag = is_bool(value)
    return any(isinstance(c, (bool, np.bool_)) == flag and value == c for c in choices)


@functools.lru_cache(maxsize=None)
def _choices_of(cls: type) -> tuple[tuple[str, tuple], ...]:
    """(name, choices) of a technique class's options with a closed set of values (cached)."""
    return tuple((f.name, f.metadata["choices"]) for f in dataclasses.fields(cls) if "choices" in f.metadata)


_BUILT: collections.OrderedDict = collections.OrderedDict()  # (class, field ids, options) -> (fields, technique)
_BUILT_LOCK = threading.Lock()
_BUILT_KEPT = 256


def check_option_names(cls: type, options: dict[str, Any]) -> None:
    """An option the technique does not have is an error that lists the ones it has (the registry's ``technique``
    and the function wrappers, ``sj.burley(..., sample=3)``, say the same)."""
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(options) - fields)
    if unknown:
        raise TypeError(f"technique {cls.name!r} has no option(s) {', '.join(unknown)}; its options: "
                        f"{', '.join(sorted(fields))}")


def missing_fields(cls: type, given) -> list[dataclasses.Field]:
    """The fields of technique class ``cls`` without a default that ``given`` (names) leaves out (STA's ``light``)."""
    return [f for f in dataclasses.fields(cls) if f.name not in given
            and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]


def check_required_fields(cls: type, options: dict[str, Any]) -> None:
    """A field without a default that ``options`` leaves out (``missing_fields``) is an error naming it and its
    type, not Python's "missing 1 required positional argument"."""
    missing = missing_fields(cls, options)
    if missing:
        needs = ", ".join(f"{f.name}=" + (f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "..."))
                          for f in missing)
        raise TypeError(f"technique {cls.name!r} needs {needs}")


def built(cls: type, options: dict[str, Any], fields: tuple = ()) -> AbstractTechnique:
    """``cls(*fields, **options)``, the same object again for the same hashable options (the wrappers build one per
    call; building an equinox Module costs ~0.01-0.3 ms). Types are part of the key: ``True`` is not ``1``.
    ``fields``: leading fields that are Modules of arrays (STA's light), which cannot be hashed: matched by identity
    (the last ``_BUILT_KEPT`` objects are kept with their fields, so an id is never reused while it is a key); fields
    holding a tracer (a call under ``jit``) are never kept. An unhashable option (an array seed, a tracer): built
    afresh, its errors raised as they are."""
    try:
        key = (cls, tuple(id(f) for f in fields), tuple((k, type(v), v) for k, v in sorted(options.items())))
        hash(key)
    except TypeError:
        check_option_names(cls, options)
        return cls(*fields, **options)
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(fields)):
        return cls(*fields, **options)
    with _BUILT_LOCK:
        hit = _BUILT.get(key)
        if hit is not None:
            _BUILT.move_to_end(key)
            return hit[1]
    check_option_names(cls, options)  # (a miss only: a kept object's options were checked when it was made)
    technique = cls(*fields, **options)
    with _BUILT_LOCK:
        _BUILT[key] = (fields, technique)
        while len(_BUILT) > _BUILT_KEPT:
            _BUILT.popitem(last=False)
    return technique


def call_options(technique: AbstractTechnique, material: Any) -> dict[str, Any]:
    """The per-call path of ``__call__``: ``material`` checked, the options by name. Through the class, not the
    instance: equinox builds a bound-method Module on each method access (~0.1 ms each on a loaded CPU)."""
    cls = type(technique)
    cls.check_material(technique, material)
    return {name: getattr(technique, name) for name in _option_names(cls)}


def frame_pieces(technique: "AbstractTechnique", count: int, seed_of_frame: Callable[[int, int], int]):
    """``pieces`` of a technique that averages ``frames`` frames, each frame's pattern a function of (seed, frame):
    about ``count`` groups of consecutive frames, each a call with fewer frames and the seed under which its first
    frame is the group's first (``seed_of_frame(seed, first)``), weighted by its share of the frames: the same
    pixels to rounding. ``None`` for one frame, one piece, or a seed that is not a concrete integer."""
    frames = int(technique.frames)
    try:  # a concrete integer seed (not a tracer)
        whole = np.ndim(technique.seed) == 0 and float(np.asarray(technique.seed)) == int(np.asarray(technique.seed))
    except (TypeError, ValueError, jax.errors.ConcretizationTypeError):
        whole = False
    if frames < 2 or count < 2 or not whole:
        return None
    seed = int(np.asarray(technique.seed))
    size = -(-frames // min(int(count), frames))  # groups of one size (the last one smaller): two programs at most
    return tuple((technique.replace(frames=min(size, frames - a), seed=seed_of_frame(seed, a)),
                  min(size, frames - a) / frames) for a in range(0, frames, size))


def tile_options(function: Callable, buffers: Buffers, origin: tuple[int, int],
                 frame_shape: tuple[int, int] | None) -> dict[str, Any]:
    """The keyword options that place ``buffers`` in the whole frame, for ``function``: none where the buffer is the
    whole frame; ``origin``/``frame_shape`` where the function takes them; else a ``TilePlacementError`` (it cannot
    place a tile)."""
    if not isinstance(buffers, Buffers):  # before the first read of it
        raise TypeError(f"{function.__name__}: buffers must be a Buffers, got {type(buffers).__name__}")
    shape = tuple(buffers.depth.shape[-2:])
    origin, frame_shape = check_tile(shape, origin, frame_shape)  # the one check of a tile's place
    if origin == (0, 0) and frame_shape == shape:
        return {}
    accepted = inspect.signature(function).parameters
    if "origin" not in accepted or "frame_shape" not in accepted:
        raise TilePlacementError(f"{function.__name__} cannot place a tile in a frame yet (no origin/frame_shape options): "
                         "pass the whole frame")
    return {"origin": origin, "frame_shape": frame_shape}
