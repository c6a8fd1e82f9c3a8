"""Which technique objects a measurement runs: registry names built with the options given for them, once per count
where a count is given or swept; the label a run is known by. Shared by the bench and the advisor (the report's
runs are built by its command line)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["as_counts", "changed_options", "run_label", "technique_runs"]


def as_counts(value) -> tuple[int, ...]:
    """A count given as an option: one integer or several."""
    values = tuple(value) if isinstance(value, (tuple, list)) else (value,)
    return tuple(int(v) for v in values)


def technique_runs(techniques: Sequence[Any], technique_options: Mapping[str, Mapping[str, Any]] | None = None,
                   counts: Mapping[str, Sequence[int]] | None = None, **context: Any) -> list[Any]:
    """The technique objects for ``techniques`` (registry names or objects): an object runs as it is; a name is built
    from the registry with ``technique_options[name]`` and what ``context`` gives that it has fields for (the STA's
    ``light``). A count option given there (``taps``/``samples``, one value or several; jimenez's ``taps`` too)
    runs once per value; else the technique's own count option runs once per value of ``counts[that option]``
    (the caller's sweep); a technique with neither runs once. Errors (an unknown name, a value outside an option's
    choices) name the technique and the option."""
    from ._techniques import AbstractTechnique, get_technique

    given = technique_options or {}
    sweeps = dict(counts or {})
    objects = []
    for t in techniques:
        if isinstance(t, AbstractTechnique):
            objects.append(t)
            continue
        cls = get_technique(t)
        options = dict(given.get(cls.name, {}))
        fields = {f.name for f in dataclasses.fields(cls)}
        options.update({k: v for k, v in context.items() if k in fields and k not in options and v is not None})
        sweep, values = None, None
        for name in ("taps", "samples"):
            if name in options and name in fields:
                sweep, values = name, as_counts(options.pop(name))
        if sweep is None and cls.count_option in sweeps:
            sweep, values = cls.count_option, as_counts(sweeps[cls.count_option])
        if sweep is None:
            objects.append(cls(**options))
        else:
            objects += [cls(**options, **{sweep: n}) for n in values]
    return objects


def changed_options(t) -> dict[str, Any]:
    """The options of ``t`` that differ from its class's defaults (its count aside): what a run records."""
    defaults = {f.name: f.default for f in dataclasses.fields(t)}
    return {k: v for k, v in t.options().items()
            if k != t.count_option and isinstance(v, (str, int, float, bool, type(None))) and v != defaults.get(k)}


def run_label(t) -> str:
    """A run's label: the technique's name, its count and the options that differ from the defaults
    (``"burley 8"``, ``"hdrp quality=high"``)."""
    count = None if t.count_option is None else getattr(t, t.count_option)
    return " ".join([t.name] + ([str(count)] if count is not None else [])
                    + [f"{k}={v}" for k, v in changed_options(t).items()])
