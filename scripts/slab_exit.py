"""The back-lit slab, checked by an independent Monte Carlo walk that keeps the exit direction.

    nice -n 10 .venv/bin/python scripts/slab_exit.py [--photons 400000]

For each slab of tests/data/mitsuba/skin_backlit (skin1 of Jensen et al. 2001, Table 2: isotropic phase function
with the reduced coefficients, index-matched faces, 1, 2 and 4 mm thick, lit from behind 17 degrees off the
normal), a NumPy random walk (this file; shares no code with sss_jax._montecarlo) gives:
- T_d, the diffusely transmitted fraction of the light crossing the back face, and T_1 its single-scattered part;
- the radiance leaving the front face towards the camera (the view cosines of the slab's interior pixels), as a
  ratio P_MC to a Lambertian exit of the same flux;
and prints them beside the path-traced truth (the Mitsuba render: mean over the slab's interior pixels), the model
(``translucency(model="slab")`` with the scene's medium table), the model's exit factor ``slab_exit`` and the
thick-slab diffusion exit ``diffuse_exit`` it replaced.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = ROOT / "tests" / "data" / "mitsuba"


def _fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance inside a medium of relative index eta meeting its face at cos_i (Born & Wolf);
    1 beyond the critical angle."""
    sin_t2 = eta * eta * (1.0 - cos_i * cos_i)
    cos_t = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (eta * cos_t - cos_i) / (eta * cos_t + cos_i)
    return np.where(sin_t2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def walk(albedo: float, tau: float, mu0: float, photons: int, mu_edges: np.ndarray, seed: int = 0,
         eta: float = 1.0) -> dict:
    """Photons enter the back face (depth 0) travelling at ``mu0`` (outside; refracted in by Snell's law) towards the
    front face (depth ``tau``, optical units), isotropic scattering of albedo ``albedo``; at a face of relative index
    ``eta`` a photon is reflected with the Fresnel probability, else leaves refracted. Returns the transmitted weight
    (scattered at least once) per bin of the exit cosine outside, its single-scattered part, and the unscattered
    fraction (per photon that entered)."""
    rng = np.random.default_rng(seed)
    z = np.zeros(photons)
    mu = np.full(photons, math.sqrt(1.0 - (1.0 - mu0 * mu0) / (eta * eta)))
    w = np.ones(photons)
    scattered = np.zeros(photons, np.int64)
    hist = np.zeros(mu_edges.size - 1)
    hist1 = np.zeros(mu_edges.size - 1)
    hist_sq = np.zeros(mu_edges.size - 1)
    unscattered = 0.0
    alive = np.ones(photons, bool)
    while alive.any():
        idx = np.flatnonzero(alive)
        step = -np.log(1.0 - rng.random(idx.size))
        znew = z[idx] + mu[idx] * step
        out_front = znew >= tau
        out_back = znew <= 0
        if eta != 1.0:  # the face reflects: the photon stays, mirrored at the face (its remaining path is redrawn)
            hit = out_front | out_back
            back = rng.random(idx.size) < _fresnel(np.abs(mu[idx]), eta)
            stay = hit & back
            znew = np.where(stay, np.where(out_front, tau, 0.0), znew)
            mu[idx[stay]] = -mu[idx[stay]]
            out_front, out_back = out_front & ~stay, out_back & ~stay
        # leaving the front face: tally by exit cosine
        f = idx[out_front]
        if f.size:
            mu_out = np.sqrt(np.clip(1.0 - eta * eta * (1.0 - mu[f] ** 2), 0.0, 1.0))
            b = np.clip(np.searchsorted(mu_edges, mu_out, side="right") - 1, 0, hist.size - 1)
            first = scattered[f] == 0
            unscattered += float(np.sum(w[f][first]))
            s = f[~first]
            bs = b[~first]
            np.add.at(hist, bs, w[s])
            np.add.at(hist_sq, bs, w[s] ** 2)
            one = scattered[s] == 1
            np.add.at(hist1, bs[one], w[s][one])
        alive[f] = False
        alive[idx[out_back]] = False
        moved = ~(out_front | out_back)
        z[idx[moved]] = znew[moved]
        # a photon mirrored at a face has not scattered: it flies on from the face (memoryless path length)
        at_face = moved & ((znew == tau) | (znew == 0.0)) if eta != 1.0 else np.zeros_like(moved)
        inside = idx[moved & ~at_face]
        w[inside] *= albedo
        scattered[inside] += 1
        mu[inside] = 2.0 * rng.random(inside.size) - 1.0  # isotropic
        # Russian roulette on small weights keeps the walk unbiased
        low = inside[w[inside] < 1e-3]
        survive = rng.random(low.size) < 0.1
        w[low[survive]] *= 10.0
        alive[low[~survive]] = False
    return {"hist": hist / photons, "hist1": hist1 / photons, "hist_stderr": np.sqrt(hist_sq) / photons,
            "unscattered": unscattered / photons}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photons", type=int, default=400_000)
    ap.add_argument("--json", type=pathlib.Path)
    ap.add_argument("--preset-eta", action="store_true", help="instead: the skin1 preset's medium behind faces of eta "
                    "1.3, the walk with Fresnel faces against slab_exit and the preset's T_d")
    args = ap.parse_args(argv)
    if args.preset_eta:
        return preset_check(args.photons)

    import jax.numpy as jnp

    import sss_jax as sj
    from sss_jax._slab import diffuse_exit, slab_exit

    sys.path.insert(0, str(ROOT / "tests"))
    from test_real_frames import _mitsuba, _slab_interiors

    b, cam, mat, truth, mask, meta = _mitsuba("skin_backlit")
    med = meta["medium"]
    s, a = np.asarray(med["sigma_s_prime_per_mm"]), np.asarray(med["sigma_a_per_mm"])
    medium = sj.MediumMaterial.from_tables(mat, [meta["material"]["slab_table"]])
    lt = meta["lights"][0]
    light = sj.DirectionalLight(jnp.asarray(lt["direction_to_light"], jnp.float32), lt["colour"])
    model = np.asarray(sj.translucency(b, medium, cam, light, model="slab"), np.float64)
    mu0 = float(lt["direction_to_light"][2])  # the beam's cosine to the slab's normal (index-matched: no refraction)
    # the view cosines of the pixels: -z . (pixel direction) on a face of normal (0, 0, -1)
    h, w = mask.shape
    xs = (np.arange(w) + 0.5 - w / 2) / cam.focal_px
    ys = (np.arange(h) + 0.5 - h / 2) / cam.focal_px
    mu_view = 1.0 / np.sqrt(1.0 + xs[None, :] ** 2 + ys[:, None] ** 2)
    edges = np.concatenate([np.linspace(0.0, 0.9, 10), [0.95, 0.97, 1.0]])
    rows = []
    for t, inner in _slab_interiors(b, mask).items():
        mv = float(np.mean(mu_view[inner]))
        for c in range(3):
            sigma_t = s[c] + a[c]
            tau = t * sigma_t
            r = walk(float(s[c] / sigma_t), tau, mu0, args.photons, edges, seed=17 * c + int(t))
            T_d = float(r["hist"].sum())
            # radiance over a Lambertian exit of the same flux: (dF / dmu) / (2 mu F), in the bin of the view cosine
            k = int(np.searchsorted(edges, mv, side="right") - 1)
            width = edges[k + 1] - edges[k]
            mid = 0.5 * (edges[k + 1] ** 2 - edges[k] ** 2) / width  # the mean of mu over the bin, weight dmu
            p_mc = float(r["hist"][k] / width / (2 * mid * T_d))
            # the pixel value the walk predicts (light irradiance pi <-> colour 1: a Lambertian exit of flux F is F)
            pred = mu0 * T_d * p_mc
            got = float(model[inner, c].mean())
            want = float(truth[inner, c].mean())
            alpha = float(s[c] / sigma_t)
            p_model = float(slab_exit(mv, tau, alpha, mu0, 1.0))
            p_thick = float(diffuse_exit(jnp.asarray(mv), jnp.asarray(1.0)))  # the exit before: thick-slab diffusion
            row = {"t_mm": t, "channel": "RGB"[c], "tau": tau, "mu_view": mv, "T_d_mc": T_d,
                   "T_d_model": float(medium.diffuse_transmittance(jnp.asarray(t))[c]),
                   "single_share": float(r["hist1"].sum() / T_d), "P_mc": p_mc, "P_model": p_model,
                   "P_diffusion_exit": p_thick,
                   "mc_pred": pred, "mc_pred_stderr": float(mu0 * r["hist_stderr"][k] / width / (2 * mid)),
                   "truth": want, "model": got}
            rows.append(row)
            print(f"t {t:.0f} mm {'RGB'[c]} tau {tau:.2f}: T_d MC {T_d:.4f} table {row['T_d_model']:.4f} "
                  f"(single {row['single_share']:.2f}); P at mu {mv:.3f}: MC {p_mc:.3f} model {p_model:.3f} "
                  f"(diffusion exit {p_thick:.3f}); "
                  f"pixel: truth {want:.4f} MC {pred:.4f} model {got:.4f} (model/truth {got / want:.3f}, "
                  f"MC/truth {pred / want:.3f})", flush=True)
    if args.json:
        from sss_jax._io import write_json_atomic

        write_json_atomic(args.json, rows)


def preset_check(photons: int) -> None:
    """skin1 behind faces of eta 1.3 (the preset's medium), lit at 0.958 from behind, seen near the normal."""
    import jax.numpy as jnp

    import sss_jax as sj
    from sss_jax._slab import slab_exit

    medium = sj.load_preset("skin1").medium
    s, a = np.array([0.74, 0.88, 1.01]), np.array([0.032, 0.17, 0.48])  # Jensen et al. 2001, Table 2
    edges = np.array([0.0, 0.5, 0.9, 0.95, 1.0])
    for t in (1.0, 2.0, 4.0):
        for c in range(3):
            sigma_t = s[c] + a[c]
            alpha = float(s[c] / sigma_t)
            r = walk(alpha, t * sigma_t, 0.958, photons, edges, seed=31 * c + int(t), eta=1.3)
            T_d = float(r["hist"].sum())
            width = edges[-1] - edges[-2]
            mid = 0.5 * (edges[-1] ** 2 - edges[-2] ** 2) / width
            p_mc = float(r["hist"][-1] / width / (2 * mid * T_d))
            p_model = float(slab_exit(0.975, t * sigma_t, alpha, 0.958, 1.3))
            T_model = float(medium.diffuse_transmittance(jnp.asarray(t))[c])
            print(f"eta 1.3, t {t:.0f} mm {'RGB'[c]}: T_d walk {T_d:.4f} (per photon entering) preset "
                  f"{T_model:.4f} (per photon arriving); P near the normal: walk {p_mc:.3f} slab_exit {p_model:.3f} "
                  f"({p_model / p_mc:.3f})", flush=True)


if __name__ == "__main__":
    main()
