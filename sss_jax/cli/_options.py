"""What the sub-commands share: the technique flags built from the technique classes' fields, and the printer that
brings a run's warnings to the user."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import sys
import typing
from collections.abc import Iterable
from typing import Any


class WarningPrinter:
    """Within ``with``: every ``UserWarning`` a run raises (the techniques' ``SamplingWarning`` and
    ``ReferenceWindowWarning``, a frame without SSS pixels, a clamp) printed on stderr once per distinct message, as
    ``<command>: warning: <message>``; other warnings (libraries' deprecations) stay with Python's filters."""

    def __init__(self, command: str):
        self.command = command
        self.messages: list[str] = []
        self._catcher = None

    def __contains__(self, text: str) -> bool:
        return text in self.messages

    def __enter__(self):
        import warnings

        self._catcher = warnings.catch_warnings()
        self._catcher.__enter__()
        warnings.simplefilter("always", UserWarning)  # repeats are dropped below, by message, not by code line
        previous = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, UserWarning):
                return previous(message, category, filename, lineno, file, line)
            text = str(message)
            if text not in self.messages:
                self.messages.append(text)
                print(f"{self.command}: warning: {text}", file=sys.stderr, flush=True)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc):
        return self._catcher.__exit__(*exc)


# ------------------------------------------------------------------------------------------------------------------
# technique flags: one builder for every command, from the technique classes' option fields
# ------------------------------------------------------------------------------------------------------------------

_UNSET = type("_Unset", (), {"__repr__": lambda self: "(the technique's default)"})()


@dataclasses.dataclass(frozen=True)
class OptionSpec:
    """One technique option as a technique declares it: its default, its help and, for a closed set, its choices."""

    technique: str
    name: str
    default: Any
    help: str
    choices: tuple | None = None
    kind: type | None = None  # the type a value parses to: the default's, else the field's annotation (int | None)



def add_camera_flags(group) -> None:
    """--focal-px, --mm-per-unit, --depth-kind and --channel-map, one definition for every command that reads a
    frame's buffers as ``sss-jax apply`` does (apply, fit --render, report, advise --frame): how the frame's camera
    and channels are found. ``group``: the parser or argument group they belong to."""
    group.add_argument("--focal-px", type=float, help="focal length in pixels")
    group.add_argument("--mm-per-unit", type=float, help="millimetres per scene unit of the depth buffer (default: "
                       "the EXR header's or the sidecar's; else 1, or 1000 for a Blender file)")
    group.add_argument("--depth-kind", choices=("planar", "distance"), default="planar",
                       help="Z is planar view depth (default) or distance to the camera")
    group.add_argument("--channel-map", help="JSON/TOML file mapping buffers (irradiance, depth, albedo, normal, "
                       "thickness, id) to channels, or naming the Blender view layer to read ({\"layer\": \"ViewLayer\"})")


def comma_separated_counts(text: str) -> tuple[int, ...]:
    """``--taps 9,25`` and the like: comma-separated positive integers (argparse's ``type=``)."""
    try:  # an empty item ("9,,17") is a typo, not nothing
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    return values


def comma_separated_names(text: str, allowed: tuple[str, ...]) -> tuple[tuple[str, ...], list[str]]:
    """``--technique a,b``: the names given and those of them not in ``allowed`` (the caller says why they are
    refused); no name at all counts as one bad name."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in allowed]
    return names, bad if names else ["(none)"]


def add_counts(args, options: dict, running, what: str) -> None:
    """``--taps``/``--samples`` (lists of counts) into ``options[name]`` of every technique of ``running`` that has
    that option; an error naming ``what`` (the candidates, the techniques run) where none has it: the flag would do
    nothing."""
    import dataclasses

    from .._techniques import TECHNIQUES

    for name in ("taps", "samples"):
        values = getattr(args, name)
        if values is None:
            continue
        takers = [t for t in running if name in {f.name for f in dataclasses.fields(TECHNIQUES[t])}]
        if not takers:
            raise ValueError(f"--{name}: none of {what} ({', '.join(running)}) has {name}")
        for t in takers:
            options.setdefault(t, {})[name] = values

def technique_option_specs(names: Iterable[str] | None = None) -> dict[str, list[OptionSpec]]:
    """``{option name: [its spec in each technique that has it]}`` for the registered techniques (or ``names``).

    A technique class's options are its fields declared with ``option`` (``option_fields()``: default, help and
    choices in the field's metadata). A registry entry that is still a function gives its keyword-only parameters
    with defaults (help: the function's name and the default)."""
    from .._techniques import TECHNIQUES

    specs: dict[str, list[OptionSpec]] = {}
    for tech in (TECHNIQUES if names is None else names):
        entry = TECHNIQUES[tech]
        if isinstance(entry, type) and hasattr(entry, "option_fields"):
            hints = typing.get_type_hints(entry)
            for field in entry.option_fields():
                default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
                choices = field.metadata.get("choices")
                specs.setdefault(field.name, []).append(OptionSpec(tech, field.name, default, field.metadata["help"],
                                                                   None if choices is None else tuple(choices),
                                                                   _kind(default, hints.get(field.name))))
        else:
            for p in inspect.signature(entry).parameters.values():
                if p.kind == p.KEYWORD_ONLY and p.default is not p.empty:
                    specs.setdefault(p.name, []).append(
                        OptionSpec(tech, p.name, p.default, f"sss_jax.{entry.__name__}'s {p.name} option",
                                   kind=_kind(p.default, p.annotation)))
    return specs


def _kind(default: Any, hint: Any) -> type | None:
    """The type an option's value parses to: its default's, else (a default of None) its annotation's one plain type
    (``budget: int | None`` -> int; a union of several, e.g. an array-like, -> None: a number or numbers)."""
    if default is not None:
        return type(default)
    plain = [a for a in typing.get_args(hint) if a is not type(None)]
    return plain[0] if len(plain) == 1 and plain[0] in (bool, int, float, str) else None


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _dest(name: str) -> str:
    return f"technique_option_{name}"


def _show(value: Any) -> str:
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def _parse_value(text: str, specs: list[OptionSpec]) -> Any:
    """The value of ``text`` for an option: one of its choices (by spelling, case-insensitive, so ``none``/``true``
    reach None/True), else the type of its default (int, float, bool, str), else a number or a list of numbers."""
    word = text.strip()
    for spec in specs:
        for choice in spec.choices or ():
            if _show(choice).lower() == word.lower():
                return choice
    if any(spec.choices for spec in specs):
        valid = sorted({_show(c) for s in specs for c in (s.choices or ())})
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(valid)}, got {text!r}")
    kinds = {s.kind for s in specs if s.kind is not None}
    if kinds & {bool}:
        if word.lower() in ("1", "true", "yes", "on"):
            return True
        if word.lower() in ("0", "false", "no", "off"):
            return False
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    if word.lower() == "none" and any(s.default is None for s in specs):
        return None
    try:
        if kinds & {int}:
            try:
                return int(word)  # exactly (through a float, 99999999999999999999 read as 1e20)
            except ValueError:
                value = float(word)  # 1e3
            if value != int(value):
                raise ValueError
            return int(value)
        if kinds & {float}:  # one number (R,G,B reached the option as a tuple, refused deep inside by float())
            return float(word)
        if not kinds:
            values = tuple(float(v) for v in word.split(","))
            return values[0] if len(values) == 1 else values
    except (ValueError, OverflowError):
        what = "an integer" if kinds & {int} else "a number" if kinds & {float} else "a number (or R,G,B)"
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    return word


def _help(specs: list[OptionSpec]) -> str:
    """The techniques' help, then the default and choices: once where the techniques agree, per technique where not."""
    def one(s: OptionSpec) -> str:
        extra = f"default {_show(s.default)}"
        if s.choices:
            extra += f"; one of {', '.join(_show(c) for c in s.choices)}"
        return extra

    who = ", ".join(s.technique for s in specs)
    helps = list(dict.fromkeys(s.help for s in specs))
    text = helps[0] if len(helps) == 1 else "; ".join(f"{s.technique}: {s.help}" for s in specs)
    extras = list(dict.fromkeys(one(s) for s in specs))
    tail = extras[0] if len(extras) == 1 else "; ".join(f"{s.technique}: {one(s)}" for s in specs)
    return f"[{who}] {text} ({tail})".replace("%", "%%")


def _metavar(name: str, specs: list[OptionSpec]) -> str:
    choices = list(dict.fromkeys(_show(c) for s in specs for c in (s.choices or ())))
    return "{" + ",".join(choices) + "}" if choices else name.upper()


def add_technique_flags(parser: argparse.ArgumentParser, *, techniques: Iterable[str] | None = None,
                        exclude: Iterable[str] = (), rename: dict[str, str] | None = None,
                        title: str = "technique options") -> list[str]:
    """Add one ``--<option>`` flag per technique option (of ``techniques``, default every registered one), built from
    the techniques' own declarations: its help, default and choices in the help, its values parsed to the option's
    type. Options the command sets through flags of its own are ``exclude``d; ``rename`` gives an option another flag
    where the command's own flag has its name (``{"seed": "burley-seed"}``). A flag left out keeps the technique's
    default. Returns the option names added."""
    specs = technique_option_specs(techniques)
    group = parser.add_argument_group(title, "the techniques' own options; a flag left out keeps the technique's "
                                      "default")
    added = []
    for name, per_technique in specs.items():
        if name in set(exclude):
            continue
        group.add_argument(_flag((rename or {}).get(name, name)), dest=_dest(name), default=_UNSET, metavar=_metavar(name, per_technique),
                           type=lambda text, s=per_technique: _parse_value(text, s), help=_help(per_technique))
        added.append(name)
    parser.set_defaults(technique_flags=tuple(added), technique_flag_names=dict(rename or {}))
    return added


def given_technique_options(args: argparse.Namespace) -> dict[str, Any]:
    """The technique options the user gave on the command line (flags from ``add_technique_flags``)."""
    return {n: getattr(args, _dest(n)) for n in getattr(args, "technique_flags", ())
            if getattr(args, _dest(n), _UNSET) is not _UNSET}


def check_option_taken(flag: str, name: str, running: Iterable[str], specs: dict | None = None) -> None:
    """An error naming the techniques that have option ``name`` (given as ``flag``) where none of ``running`` (the
    command's techniques) takes it: a flag that would do nothing is refused, not dropped."""
    specs = technique_option_specs() if specs is None else specs
    owners = sorted({s.technique for s in specs.get(name, ())})
    if not set(running) & set(owners):
        raise ValueError(f"{flag} is an option of {', '.join(owners)}, not of {', '.join(sorted(running))}")


def technique_options(args: argparse.Namespace, technique: str, *, others: Iterable[str] = ()) -> dict[str, Any]:
    """The options given on the command line that ``technique`` takes, checked against its choices. A given option
    that neither ``technique`` nor any of ``others`` (the command's other techniques) takes is an error naming the
    flag and the techniques that have it."""
    specs = technique_option_specs()
    given = given_technique_options(args)
    mine = {s.name: s for ss in specs.values() for s in ss if s.technique == technique}
    running = {technique, *others}
    names = getattr(args, "technique_flag_names", {})
    _flag = lambda n: "--" + names.get(n, n).replace("_", "-")  # noqa: E731 - the flag as this command spells it
    for name, value in given.items():
        check_option_taken(_flag(name), name, running, specs)
        spec = mine.get(name)
        if spec is not None and spec.choices is not None and value not in spec.choices:
            raise ValueError(f"{_flag(name)} {_show(value)}: {technique} takes one of "
                             f"{', '.join(_show(c) for c in spec.choices)}")
    return {n: v for n, v in given.items() if n in mine}


# STA's back light through thickness t is exp(-t / thickness_mm) per channel: below this on every SSS pixel and
# channel it adds nothing visible (an 8-bit display step is 1/255), above 1 - this the thickness changes nothing
# the STA flags: (name, type, default), their defaults None in the parsers so that a given value can be told from one
# left out (a given one overrides a preset's field; given where no STA runs, it is an error, not silently dropped)
STA_FLAGS = (("distortion", float, 0.2), ("power", float, 4.0), ("scale", "rgb", (1.0, 1.0, 1.0)),
             ("ambient", "rgb", (0.0, 0.0, 0.0)), ("thickness_mm", "rgb", (1.0, 1.0, 1.0)))
_STA_HELP = {"thickness_mm": "thickness falloff per channel, mm: t = exp(-thickness / this)"}


def add_sta_flags(group, rgb_type) -> None:
    """``--sta-distortion``, ``--sta-power``, ``--sta-scale``, ``--sta-ambient``, ``--sta-thickness-mm``."""
    for name, kind, default in STA_FLAGS:
        shown = ",".join(f"{v:g}" for v in default) if isinstance(default, tuple) else f"{default:g}"
        what = _STA_HELP.get(name, f"STA {name}")
        group.add_argument(f"--sta-{name.replace('_', '-')}", type=rgb_type if kind == "rgb" else kind, default=None,
                           help=f"{what} (default {shown}, or the preset's)")


def given_sta_flags(args: argparse.Namespace) -> dict[str, Any]:
    """The STA fields given on the command line (``STAParams`` field -> value)."""
    return {name: getattr(args, f"sta_{name}") for name, _, _ in STA_FLAGS if getattr(args, f"sta_{name}", None)
            is not None}


def given_sta_flag_names(args: argparse.Namespace) -> list[str]:
    """The STA flags given on the command line, as typed (``--sta-power``), for a message."""
    return [f"--sta-{name.replace('_', '-')}" for name in given_sta_flags(args)]


def sta_params(args: argparse.Namespace, preset_sta=None):
    """``STAParams`` from the flags given, over the preset's (where one is given) or the flags' defaults."""
    from .._materials import STAParams

    base = {name: (default if preset_sta is None else getattr(preset_sta, name)) for name, _, default in STA_FLAGS}
    return STAParams(**{**base, **given_sta_flags(args)})


_STA_FAINT = 1e-3


def sta_thickness_warning(frame, params, thickness: float | None) -> str | None:
    """What to tell the user when the frame's thickness (its thickness channel, else ``--thickness``, in scene units,
    times the scene unit in mm) is far outside the STA material's falloff ``thickness_mm``: the back light it lets
    through (``exp(-t / thickness_mm)``) is nil on every pixel, or is 1 on every pixel (the thickness makes no
    difference). None where it is in range."""
    import numpy as np

    mm_per_unit = frame.scene_unit_mm
    falloff = np.asarray(params.thickness_mm, np.float64).reshape(-1)
    mask = np.isfinite(frame.depth) & ((frame.material_id > 0) if frame.material_id is not None else True)
    if frame.thickness is not None:
        units = np.asarray(frame.thickness, np.float64)[mask]
        source = "the thickness channel"
    elif thickness is not None:
        units = np.full(1, float(thickness))
        source = f"--thickness {thickness:g}"
    else:
        return None  # paper-thin by design: exp(0) = 1
    units = units[np.isfinite(units)]
    if units.size == 0:
        return None
    thin_mm, thick_mm = float(units.min()) * mm_per_unit, float(units.max()) * mm_per_unit
    most = float(np.exp(-thin_mm / falloff.max()))
    least = float(np.exp(-thick_mm / falloff.min()))
    unit = f"scene units of {mm_per_unit:g} mm"
    falloffs = ",".join(f"{v:g}" for v in falloff)
    if most < _STA_FAINT:
        hint = thin_mm / falloff.max() / 3  # a thickness the falloff passes ~exp(-3) = 5% of
        return (f"STA: {source} ({unit}) is {thin_mm:g} mm or more against a falloff of {falloffs} mm: the back "
                f"light passes exp(-{thin_mm / falloff.max():.3g}) = {most:.2g} of itself at most, so STA adds "
                f"nothing (the output is local shading); thickness is in scene units (e.g. --thickness "
                f"{float(units.min()) / hint:.3g} for {thin_mm / hint:.3g} mm), or raise --sta-thickness-mm")
    if least > 1 - _STA_FAINT and thick_mm > 0:
        return (f"STA: {source} ({unit}) is at most {thick_mm:g} mm against a falloff of {falloffs} mm: the back "
                f"light passes {least:.4f} of itself everywhere, so the thickness makes no difference (as paper-thin)")
    return None


def option_arguments(function, options: dict[str, dict[str, Any]], command: str) -> dict[str, Any]:
    """The technique options (``{technique: {option: value}}``, only the given ones) as ``function`` takes them:
    ``technique_options=`` where it has that parameter, Burley's as ``burley_options=`` where it has that one; an
    option it cannot take is an error naming the flags (a caller that does not pass them on would drop them)."""
    accepted = inspect.signature(function).parameters
    given = {t: o for t, o in options.items() if o}
    if "technique_options" in accepted:
        return {"technique_options": given}
    passed = {"burley_options": given["burley"]} if "burley" in given and "burley_options" in accepted else {}
    left = {t: o for t, o in given.items() if not (t == "burley" and passed)}
    if left:
        flags = sorted({"--" + k.replace("_", "-") for o in left.values() for k in o})
        raise ValueError(f"{', '.join(flags)}: this version's {command} cannot pass options to "
                         f"{', '.join(left)} yet")
    return passed


def technique_entries(text: str, valid: Iterable[str], *, flag: str = "--techniques") -> list[tuple[str, dict]]:
    """``name[:option=value[:option=value...]],...`` as ``[(name, {option: value})]``: the techniques of a command
    that runs several, each with options of its own (``hdrp:quality=low,hdrp:quality=high``), values parsed as the
    option's flag parses them. Errors name ``flag``, the entry and what is wrong (an unknown technique or option, a
    value outside the option's choices)."""
    valid = tuple(valid)
    out = []
    for entry in (e.strip() for e in text.split(",")):
        if not entry:
            continue
        name, *pairs = (part.strip() for part in entry.split(":"))
        if name not in valid:
            raise ValueError(f"{flag}: unknown technique {name!r} in {entry!r}; valid: {', '.join(valid)}")
        specs = technique_option_specs([name])
        options: dict[str, Any] = {}
        for pair in pairs:
            key, sep, value = pair.partition("=")
            key = key.strip().replace("-", "_")
            if not sep or not key:
                raise ValueError(f"{flag}: {entry!r}: expected {name}:option=value, got {pair!r}")
            if key not in specs:
                raise ValueError(f"{flag}: {entry!r}: {name} has no option {key!r}; its options: "
                                 f"{', '.join(sorted(specs))}")
            try:
                options[key] = _parse_value(value, specs[key])
            except argparse.ArgumentTypeError as exc:
                raise ValueError(f"{flag}: {entry!r}: {key}: {exc}") from None
        out.append((name, options))
    if not out:
        raise ValueError(f"{flag}: give at least one technique; valid: {', '.join(valid)}")
    return out
