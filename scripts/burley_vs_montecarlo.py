"""How well does Christensen-Burley with the memo's s(A) reproduce brute-force Monte Carlo profiles?

    python scripts/burley_vs_montecarlo.py [--photons 100000] [--markdown docs/montecarlo_table.md]

For each single-scattering albedo: an index-matched, semi-infinite, isotropic medium under a normal pencil beam
(the memo's searchlight configuration). The surface albedo A is the MC total reflectance; Burley's d = mfp / s(A)
with the searchlight fit s = 1.85 - A + 7|A - 0.8|^3; errors of r R(r) over r in [0, 10] mean free paths.
"""

import argparse
import pathlib

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=100_000)
    ap.add_argument("--markdown", type=pathlib.Path)
    args = ap.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    import sss_jax as sj
    from sss_jax._montecarlo import simulate

    rows = []
    for alpha in (0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99):
        mc = simulate(alpha, photons=args.photons, seed=11, bins=100, r_max_mfp=10.0)
        r = mc.r_mfp
        A = mc.total_reflectance
        d = float(sj.d_from_mfp(A, 1.0, fit="searchlight"))
        burley = A * np.asarray(sj.burley_R(r, d))
        rr_mc, rr_b = r * mc.R, r * burley
        rel_l2 = np.linalg.norm(rr_b - rr_mc) / np.linalg.norm(rr_mc)
        # where the light is: the radius holding half of each profile's energy
        half_mc = r[np.searchsorted(np.cumsum(mc.R * 2 * np.pi * r * (r[1] - r[0])) / A, 0.5)]
        half_b = float(sj.burley_inverse_cdf(0.5, d))
        rows.append((alpha, A, mc.total_reflectance_stderr, d, rel_l2, half_mc, half_b))
    lines = ["| single-scattering albedo | MC total reflectance A | d = mfp/s(A) (mfp) | rel. L2 of rR(r), r<=10 mfp "
             "| median radius MC (mfp) | median radius Burley (mfp) |", "|---|---|---|---|---|---|"]
    for alpha, A, err, d, e, hm, hb in rows:
        lines.append(f"| {alpha:.2f} | {A:.4f} +- {err:.4f} | {d:.4f} | {e:.3f} | {hm:.3f} | {hb:.3f} |")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + f"\n\n({args.photons} photons per albedo, seed 11; "
                                 "`python scripts/burley_vs_montecarlo.py`)\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
