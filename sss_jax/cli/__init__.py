"""The ``sss-jax`` command. Each ``_<name>.py`` module in this package adds one sub-command via ``register``."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys


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



def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
        return 130


if __name__ == "__main__":
    sys.exit(main())
