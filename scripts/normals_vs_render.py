"""Normals derived from depth (``sss_jax.normals_from_depth``) against a render's own normal pass.

For each frame that carries normals: the angle (degrees) between the derived and the rendered normal on the SSS
pixels, median / mean / 90th / 99th percentile / max, for the library's rule and for one-sided differences on the
side whose depth changes least everywhere (the rule before 2026-12-07), both in float64.

    python scripts/normals_vs_render.py                       # ../shared/reference/blender and tests/data/mitsuba
    python scripts/normals_vs_render.py frame.exr [...]
"""

from __future__ import annotations

import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

from sss_jax import normals_from_depth
from sss_jax._io import read_frame
from sss_jax._scene import _positions, surface_mask

ROOT = pathlib.Path(__file__).resolve().parent.parent
DEFAULT = [ROOT.parent / "shared/reference/blender/irradiance_backlit.exr",
           *sorted((ROOT / "tests/data/mitsuba").glob("*_buffers.exr"))]


def one_sided(depth: np.ndarray, camera) -> np.ndarray:
    """The rule before: on each axis the side whose depth changes least, wherever a side has a surface."""
    p = np.asarray(_positions(jnp.asarray(depth), camera))
    valid = np.asarray(surface_mask(jnp.asarray(depth)))

    def diff(axis):
        fwd = np.roll(p, -1, axis=axis) - p
        bwd = p - np.roll(p, 1, axis=axis)
        n = depth.shape[axis]
        idx = np.arange(n).reshape([n if i == axis else 1 for i in range(2)])
        v_f = valid & np.roll(valid, -1, axis=axis) & (idx < n - 1)
        v_b = valid & np.roll(valid, 1, axis=axis) & (idx > 0)
        use_f = v_f & (~v_b | (np.abs(fwd[..., 2]) <= np.abs(bwd[..., 2])))
        use_b = v_b & ~use_f
        return np.where(use_f[..., None], fwd, np.where(use_b[..., None], bwd, 0.0))

    n = np.cross(diff(0), diff(1))
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(norm > 0, n / np.where(norm > 0, norm, 1.0), np.array([0.0, 0.0, -1.0]))


def main(paths: list[str]) -> int:
    for path in paths or DEFAULT:
        frame = read_frame(path)
        if frame.normal is None:
            print(f"{path}: no normal pass")
            continue
        buffers, camera = frame.to_buffers(), frame.camera()
        depth = np.asarray(buffers.depth, np.float64)
        truth = np.asarray(buffers.normal, np.float64)
        sss = (np.asarray(buffers.material_id) > 0) & np.isfinite(depth)
        print(f"{path} ({sss.sum()} SSS pixels): angle to the rendered normal, degrees")
        for name, n in (("library", np.asarray(normals_from_depth(jnp.asarray(depth), camera), np.float64)),
                        ("one-sided (before)", one_sided(depth, camera))):
            a = np.degrees(np.arccos(np.clip(np.sum(n * truth, axis=-1), -1.0, 1.0)))[sss]
            print(f"  {name:20s} median {np.median(a):6.3f}  mean {a.mean():6.3f}  p90 {np.percentile(a, 90):6.3f}  "
                  f"p99 {np.percentile(a, 99):6.2f}  max {a.max():6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
