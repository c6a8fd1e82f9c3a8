"""The ``sss-jax`` command. Each ``_<name>.py`` module in this package adds one sub-command via ``register``."""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import re
import sys

_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|nan"
# a value that starts with a minus and is a number or a comma-separated list of numbers ("-0.25,0.3,0.9", "-1e-3")
_NEGATIVE_VALUE = re.compile(rf"^-(?:{_NUMBER})(?:\s*,\s*[-+]?(?:{_NUMBER}))*$", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """argparse with one change for every flag of every sub-command: a value that starts with a minus and reads as
    a number or a list of numbers (``--light-dir -0.25,0.3,0.9``, ``--d-mm -1,1,1``) is the flag's value, judged on
    its merits by the command, not taken for an unknown option. Stock argparse knows only ``-1`` and ``-.5``.
    Sub-command parsers are made of this class too (``add_subparsers`` uses the parent's class)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_VALUE


def rgb_triple(text: str) -> tuple[float, float, float]:
    """argparse type for R,G,B (one number stands for all three channels)."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers R,G,B, got {text!r}") from None
    if len(values) == 1:
        values = values * 3
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers R,G,B, got {text!r}")
    return values



def srgb_colour(text: str) -> tuple[float, float, float]:
    """argparse type for an sRGB colour as an inspector shows it: R,G,B in [0, 1] or the hex ``#RRGGBB``."""
    hex_digits = text.strip().removeprefix("#")
    if text.strip().startswith("#"):
        if len(hex_digits) != 6 or any(c not in "0123456789abcdefABCDEF" for c in hex_digits):
            raise argparse.ArgumentTypeError(f"expected a hex colour #RRGGBB or R,G,B, got {text!r}")
        return tuple(int(hex_digits[i:i + 2], 16) / 255 for i in (0, 2, 4))
    return rgb_triple(text)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="sss-jax",
        description="Real-time subsurface scattering in image space: apply, fit, measure.",
        epilog="Start with:  sss-jax demo --out demo_out",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_") and not info.name.startswith("__"):
            module = importlib.import_module(f"{__name__}.{info.name}")
            register = getattr(module, "register", None)
            if register is not None:
                register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("sss-jax: interrupted", file=sys.stderr)
        if argv is None:  # the command itself, ending: what it wrote is complete (atomic) or removed already
            # Python's shutdown beside an interrupted XLA computation crashed (exit 139, "Segmentation fault", in
            # 4 of 6 interrupted `report`s): the process ends here, without it
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        return 130


if __name__ == "__main__":
    sys.exit(main())
