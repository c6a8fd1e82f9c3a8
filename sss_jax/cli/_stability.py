"""``sss-jax stability``: the sweep over extreme inputs."""

from __future__ import annotations

import argparse
import pathlib
import sys

EPILOG = """examples:
  sss-jax stability --json stability.json           # the full sweep (~11,000 cases)
  sss-jax stability --quick --json quick.json       # the reduced sweep the tests run
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "stability",
        help="sweep the techniques, profiles and kernels over extreme inputs",
        description="Run the techniques (STA, separable with either kernel, Burley, the reference, HDRP's and EEVEE "
        "Next's passes; jimenez, whose shader parameters are fitted on the host, in the tests), the profiles and "
        "the kernels over the cross product of extreme parameters and buffers (d from 0 to 1e6 mm, albedo 0..1, "
        "sigma 0..1e4, depth 0/inf/NaN/1e-8/1e8, irradiance 0/subnormal/1e-30/1e30, float16/32/64, 1x1 and 1xN "
        "images; --quick: one dtype per technique at 4x4, every 7th case) and count non-finite outputs and "
        "gradients.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", type=pathlib.Path, required=True, help="where to write the summary and every case")
    p.add_argument("--quick", action="store_true", help="the reduced sweep")
    p.set_defaults(func=run)


def run(args) -> int:
    from .._io import SSSInputError, check_writable, write_json_atomic
    from .._stability import run_sweep

    try:  # before the sweep (minutes): a folder, a missing or read-only directory
        check_writable(args.json, create_dirs=False)
    except SSSInputError as exc:
        print(f"sss-jax stability: --json {exc}", file=sys.stderr)
        return 2
    summary = run_sweep(quick=args.quick, progress=True)
    write_json_atomic(args.json, summary)
    for key, label in _ROWS:
        print(f"{label + ':':<22}{summary.get(key, 0)}")
    failed = [c for c in summary.get("case_list", []) if c["outcome"] not in ("ok", "handled_error")]
    for c in failed[:10]:  # the cases that failed, by name: the exit status is 1 because of them
        print(f"  {c['outcome']}: {c['component']} {c['params']}: {c['message'][:160]}")
    if len(failed) > 10:
        print(f"  ... and {len(failed) - 10} more in {args.json}")
    bad = summary["cases"] - summary["ok"] - summary["handled_errors"]
    return 0 if bad == 0 else 1


# every outcome the sweep counts, in the order printed (a count left out here would fail the run unseen)
_ROWS = (("cases", "cases tried"), ("ok", "ok"), ("handled_errors", "handled errors"),
         ("nonfinite_outputs", "non-finite outputs"), ("nonfinite_gradients", "non-finite gradients"),
         ("energy_unbounded", "energy unbounded"), ("limit_violations", "limits violated"),
         ("unexpected_errors", "unexpected errors"))
