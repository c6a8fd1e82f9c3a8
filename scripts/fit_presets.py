"""Fit every preset into fits/ (measured materials of Jensen et al. 2001 and the artist materials).

    python scripts/fit_presets.py                 # all materials, 100000 photons per channel, into fits/
    python scripts/fit_presets.py --material skin --out /tmp/fits

The same as ``sss-jax fit``; every option of that command applies. Re-running it reproduces the files (all but the
``seconds`` fields), reusing the Monte Carlo runs cached in fits/montecarlo/ when their provenance matches.
"""

import pathlib
import sys

from sss_jax.cli import main

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--out" not in args:
        args += ["--out", str(pathlib.Path(__file__).resolve().parents[1] / "fits")]
    sys.exit(main(["fit", *args]))
