"""Monte Carlo reference profiles: a jitted random walk in a homogeneous medium.

Geometry: a semi-infinite half-space ``z >= 0`` or a slab ``0 <= z <= t``; light enters at the origin through the
top surface as a pencil beam at normal incidence or as diffuse (cosine-distributed) incidence. Phase function:
isotropic or Henyey–Greenstein with asymmetry ``g``. Boundaries: index-matched (``eta = 1``) or dielectric with
unpolarised Fresnel reflection on entry (the specular part is reported apart) and internal reflection, including
total internal reflection, at every exit attempt.

Lengths inside are in mean free paths (``sigma_t = 1``). Photons carry a weight: each scattering multiplies it by the
single-scattering albedo (implicit capture) and Russian roulette ends weak photons without bias; past an event cap
absorption turns analog (a photon dies with probability 1 - albedo at each scattering, its weight unchanged), and a
photon in a non-absorbing half-space is tallied as reflected (it is certain to leave), so no photon is dropped at
the cap. Because free paths are memoryless, a path that reaches a boundary stops there, the boundary decides (leave or
reflect), and a fresh free path starts: no partial steps to carry.

Streaming: each jitted call (a batch) runs ``lanes`` photons in parallel inside a ``lax.while_loop``. One iteration
advances every lane by ``unroll`` events; at its end the photons that left are tallied with one histogram scatter and
their lanes are refilled, until the batch's photon budget is spent, so dead photons cost (almost) nothing; the tail of a
batch, when no photons remain to launch, runs in 1/8 as many lanes. Memory is ``O(lanes + bins)`` per batch whatever
the photon count. Batches run on a few threads at once (one jitted call keeps one core busy; XLA releases the GIL),
with a progress bar; tallies (sums of weights and of squared weights per photon, for standard errors) accumulate on
the host in float64, in batch order, so a seed gives the same numbers whatever the number of threads.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import math
import time
from numbers import Real
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._checks import check_host_count, check_host_range
from ._machine import usable_cores

__all__ = ["MCResult", "simulate", "fresnel_unpolarised", "to_tabulated_profile"]

_ROULETTE_WEIGHT = 1e-3
_ROULETTE_SURVIVAL = 0.1
# lane widths of a batch: all lanes while photons are launched, then the survivors in 1/8 as many (a third stage
# gained another ~7% at albedo 0.99 and nothing at 0.9, for 1.2 s more compile time per configuration)
_STAGES = 2


def fresnel_unpolarised(cos_i, n1, n2):
    """Fresnel reflectance of unpolarised light going from index n1 to n2 at incidence cosine ``cos_i`` (>= 0);
    1 beyond the critical angle (total internal reflection)."""
    cos_i = jnp.clip(cos_i, 0.0, 1.0)
    sin_t = n1 / n2 * jnp.sqrt(jnp.maximum(1 - cos_i * cos_i, 0.0))
    tir = sin_t >= 1.0
    cos_t = jnp.sqrt(jnp.maximum(1 - sin_t * sin_t, 0.0))
    rs = (n1 * cos_i - n2 * cos_t) / jnp.maximum(n1 * cos_i + n2 * cos_t, 1e-30)
    rp = (n1 * cos_t - n2 * cos_i) / jnp.maximum(n1 * cos_t + n2 * cos_i, 1e-30)
    return jnp.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


_ONE_BITS = 0x3F800000  # the bits of float32 1.0: OR-ing 23 random mantissa bits into it gives [1, 2)


def _hg_cos(u, g):
    """Sample the Henyey–Greenstein cosine (isotropic when g = 0)."""
    safe_g = jnp.where(jnp.abs(g) < 1e-6, 1e-6, g)
    frac = (1 - safe_g * safe_g) / (1 - safe_g + 2 * safe_g * u)
    hg = (1 + safe_g * safe_g - frac * frac) / (2 * safe_g)
    return jnp.clip(jnp.where(jnp.abs(g) < 1e-6, 2 * u - 1, hg), -1.0, 1.0)


def _rotate(ux, uy, uz, cos_t, cos_phi, sin_phi):
    """New direction at polar angle acos(cos_t) and azimuth phi relative to (ux, uy, uz) (MCML's formulas)."""
    sin_t = jnp.sqrt(jnp.maximum(1 - cos_t * cos_t, 0.0))
    cp, sp = cos_phi, sin_phi
    near_pole = jnp.abs(uz) > 0.99999
    den = jnp.sqrt(jnp.maximum(1 - uz * uz, 1e-30))
    nx = sin_t * (ux * uz * cp - uy * sp) / den + ux * cos_t
    ny = sin_t * (uy * uz * cp + ux * sp) / den + uy * cos_t
    nz = -sin_t * cp * den + uz * cos_t
    px, py, pz = sin_t * cp, sin_t * sp, jnp.sign(uz) * cos_t
    return jnp.where(near_pole, px, nx), jnp.where(near_pole, py, ny), jnp.where(near_pole, pz, nz)


# --- random numbers ---------------------------------------------------------------------------------------------------
# Each lane owns four xoroshiro64* generators (Blackman & Vigna 2018: period 2^64 - 1, their recommendation for 32-bit
# floating-point numbers; only the upper bits, the strong ones, are used here), one per kind of draw, seeded per batch
# from the run's seed with jax.random (threefry). A draw is ~8 uint32 operations on two words that the event's loop
# carries. One generator per kind keeps every draw one step from the carried state: chained steps of one generator
# were fused by XLA into each consumer and recomputed there, and threefry through jax.random costs more than the whole
# rest of a scattering event.
_GENERATORS = 4  # step length, direction (or Fresnel decision), azimuth, roulette


def _xoroshiro_next(s0, s1):
    out = s0 * jnp.uint32(0x9E3779BB)
    s1 = s1 ^ s0
    return out, ((s0 << 26) | (s0 >> 6)) ^ s1 ^ (s1 << 9), (s1 << 13) | (s1 >> 19)


def _draw(rng, which):
    """One draw of generator ``which`` of every lane; returns the bits and the advanced states."""
    out, s0, s1 = _xoroshiro_next(rng[2 * which], rng[2 * which + 1])
    return out, rng[:2 * which] + (s0, s1) + rng[2 * which + 2:]


def _unit(bits):
    """Uniform in [0, 1) from the upper 23 bits of a uint32 (float32 resolution)."""
    return jax.lax.bitcast_convert_type((bits >> 9) | jnp.uint32(_ONE_BITS), jnp.float32) - 1.0


def _cos_sin_turn(bits):
    """(cos 2 pi u, sin 2 pi u) for the uniform u of a uint32: the top two bits pick the quadrant, 23 more the angle in
    it. Polynomials on [-pi/4, pi/4] (Taylor to degree 8 and 9: error < 3e-8, below float32 resolution) instead of
    general-argument cos/sin, which cost 3x a log here."""
    f = jax.lax.bitcast_convert_type(((bits >> 7) & jnp.uint32(0x7FFFFF)) | jnp.uint32(_ONE_BITS), jnp.float32) - 1.5
    b = f * (math.pi / 2)
    b2 = b * b
    cb = 1 + b2 * (-1 / 2 + b2 * (1 / 24 + b2 * (-1 / 720 + b2 * (1 / 40320))))
    sb = b * (1 + b2 * (-1 / 6 + b2 * (1 / 120 + b2 * (-1 / 5040 + b2 * (1 / 362880)))))
    half = math.sqrt(0.5)
    c, s = (cb - sb) * half, (cb + sb) * half  # angle b + pi/4 in [0, pi/2)
    odd = (bits >> 30) & jnp.uint32(1) == 1
    c, s = jnp.where(odd, -s, c), jnp.where(odd, c, s)  # + 90 degrees
    upper = (bits >> 31) == 1
    return jnp.where(upper, -c, c), jnp.where(upper, -s, s)  # + 180 degrees


def _kahan_add(total, compensation, x):
    """Compensated (Kahan) float32 summation: a batch's tallies do not drift however many photons they add; the host
    adds the batches in float64."""
    y = x - compensation
    t = total + y
    return t, (t - total) - y


_STATE = ("x", "y", "z", "ux", "uy", "uz", "w", "n", "events", "active")


def _make_kernel(lanes: int, bins: int, r_max: float, max_events: int, max_events_hard: int, slab: bool,
                 diffuse: bool, isotropic: bool, index_matched: bool, unroll: int):
    """The jitted batch runner for one static configuration.

    One iteration of the while loop advances every lane by ``unroll`` events (boundary hits or scatterings); a lane
    whose photon leaves, dies or is capped stops where it is until the end of the iteration, where all exits are
    tallied with one histogram scatter and freed lanes are refilled. Once the budget is launched and few photons are
    left, the survivors are compacted into 1/8 as many lanes, so the long tail of a batch runs narrow."""
    f32, i32, u32 = jnp.float32, jnp.int32, jnp.uint32
    n_cells = bins + 1  # the last bin collects r >= r_max
    inv_dr = bins / r_max
    widths = [lanes]
    while len(widths) < _STAGES and widths[-1] // 8 >= 64:
        widths.append(widths[-1] // 8)

    @jax.jit
    def run(key, budget, albedo, g, eta, thickness):
        r_sp = ((eta - 1) / (eta + 1)) ** 2

        def launch(rng, width):
            """Fresh photons in every lane (the caller keeps them where a lane is refilled); diffuse incidence draws
            from the step and azimuth generators."""
            zeros = jnp.zeros(width, f32)
            if diffuse:
                b1, rng = _draw(rng, 0)
                b2, rng = _draw(rng, 2)
                cos_out = jnp.sqrt(_unit(b1))  # cosine-weighted directions outside
                weight = 1 - fresnel_unpolarised(cos_out, 1.0, eta)
                sin_in = jnp.sqrt(jnp.maximum(1 - cos_out * cos_out, 0.0)) / eta
                cp, sp = _cos_sin_turn(b2)
                uz = jnp.sqrt(jnp.maximum(1 - sin_in * sin_in, 0.0))
                ux, uy = sin_in * cp, sin_in * sp
            else:
                weight = jnp.full(width, 1 - r_sp, f32)
                ux, uy, uz = zeros, zeros, jnp.ones(width, f32)
            fresh = dict(x=zeros, y=zeros, z=zeros, ux=ux, uy=uy, uz=uz, w=weight.astype(f32),
                         n=jnp.zeros(width, i32))
            return fresh, rng

        def event(st, rng, done):
            """One free path for every active lane: to the next scattering, or to the boundary and its decision."""
            x, y, z, ux, uy, uz, w, n, events, active = (st[s] for s in _STATE)
            b_step, rng = _draw(rng, 0)
            b_dir, rng = _draw(rng, 1)  # the scattering cosine, or the Fresnel decision at a boundary
            b_phi, rng = _draw(rng, 2)
            b_rr, rng = _draw(rng, 3)
            step = -jnp.log(1.0 - _unit(b_step))  # 1 - u lies in (0, 1]
            z_new = z + uz * step
            hits_top = z_new < 0
            hits_bottom = (z_new > thickness) if slab else jnp.zeros_like(hits_top)
            crosses = hits_top | hits_bottom
            boundary = active & crosses
            scatter = active & ~crosses
            # memoryless free paths: stop at the boundary crossed, decide there, restart
            t_b = jnp.where(hits_top, -z / jnp.where(uz < 0, uz, -1.0), (thickness - z) / jnp.where(uz > 0, uz, 1.0))
            t = jnp.where(boundary, t_b, jnp.where(scatter, step, 0.0))
            x, y = x + ux * t, y + uy * t
            if slab:
                z_b = jnp.where(hits_top, 0.0, thickness).astype(f32)
            else:
                z_b = jnp.zeros_like(z)
            z = jnp.where(boundary, z_b, jnp.where(scatter, z_new, z))
            u_dir = _unit(b_dir)
            if index_matched:
                leaves = boundary
            else:
                reflect = u_dir < fresnel_unpolarised(jnp.abs(uz), eta, 1.0)
                leaves = boundary & ~reflect
                uz = jnp.where(boundary & reflect, -uz, uz)
            cp, sp = _cos_sin_turn(b_phi)
            if isotropic:
                cos_t = 2 * u_dir - 1
                sin_t = jnp.sqrt(jnp.maximum(1 - cos_t * cos_t, 0.0))
                nx, ny, nz = sin_t * cp, sin_t * sp, cos_t
            else:
                nx, ny, nz = _rotate(ux, uy, uz, _hg_cos(u_dir, g), cp, sp)
            ux, uy, uz = (jnp.where(scatter, a, b) for a, b in ((nx, ux), (ny, uy), (nz, uz)))
            u_rr = _unit(b_rr)
            # up to max_events scatterings: implicit capture (the weight carries the albedo) with Russian roulette on
            # weak photons; beyond: analog absorption (the photon survives a scattering with probability albedo,
            # its weight unchanged), unbiased with weights that never grow, so nearly conservative media end too
            analog = n >= max_events
            w = jnp.where(scatter & ~analog, w * albedo, w)
            absorbed = scatter & analog & (u_rr >= albedo)
            n = n + scatter.astype(i32)
            events = events + scatter.astype(i32)
            weak = active & ~leaves & ~analog & (w < _ROULETTE_WEIGHT)
            survive = u_rr < _ROULETTE_SURVIVAL
            w = jnp.where(weak, jnp.where(survive, w / _ROULETTE_SURVIVAL, 0.0), w)
            died = (weak & ~survive) | absorbed
            alive = active & ~leaves & ~died
            if slab:
                escapes = jnp.zeros_like(alive)
            else:
                # without absorption a half-space keeps no photon: its walk in depth is recurrent, so it meets the
                # surface again and again until it leaves (probability 1). Its weight is tallied as reflected at
                # r >= r_max (after max_events steps it is ~sqrt(2 n / 3) mfp from the axis); waiting for it
                # would cost without bound, as the return time has an n^-1/2 tail
                escapes = alive & (n >= max_events) & (albedo >= 1)
            capped = alive & ~escapes & (n >= max_events_hard)
            exit_top, exit_bottom, was_capped, was_escaped = done
            done = (exit_top | (leaves & hits_top), exit_bottom | (leaves & hits_bottom), was_capped | capped,
                    was_escaped | escapes)
            active = alive & ~escapes & ~capped
            st = dict(x=x, y=y, z=z, ux=ux, uy=uy, uz=uz, w=w.astype(f32), n=n, events=events, active=active)
            return st, rng, done

        def tally(st, done, acc):
            """All exits of one iteration in one histogram scatter; rows R, R^2, T, T^2 per radial bin."""
            exit_top, exit_bottom, capped, escaped = done
            x, y, w, n = st["x"], st["y"], st["w"], st["n"]
            r = jnp.sqrt(x * x + y * y)
            cell = jnp.where(escaped, bins, jnp.minimum((r * inv_dr).astype(i32), bins))
            cell = cell + jnp.where(exit_bottom, n_cells, 0)
            exit_w = jnp.where(exit_top | exit_bottom | escaped, w, 0.0)
            h = jnp.zeros(2 * n_cells, f32).at[cell].add(exit_w, mode="promise_in_bounds")
            h2 = jnp.zeros(2 * n_cells, f32).at[cell].add(exit_w * exit_w, mode="promise_in_bounds")
            hist = jnp.stack([h[:n_cells], h2[:n_cells], h[n_cells:], h2[n_cells:]])
            single = jnp.where(exit_top & (n == 1), w, 0.0)
            sums = jnp.stack([jnp.sum(single), jnp.sum(single * single), jnp.sum(jnp.where(capped, w, 0.0))])
            hist_acc, hist_c, sums_acc, sums_c, n_capped = acc
            hist_acc, hist_c = _kahan_add(hist_acc, hist_c, hist)
            sums_acc, sums_c = _kahan_add(sums_acc, sums_c, sums)
            return hist_acc, hist_c, sums_acc, sums_c, n_capped + jnp.sum(capped, dtype=i32)

        def iterate(st, rng, acc):
            width = st["x"].shape[0]
            false = jnp.zeros(width, bool)
            done = (false, false, false, false)
            st, rng, done = jax.lax.fori_loop(0, unroll, lambda _, c: event(*c), (st, rng, done))
            return st, rng, tally(st, done, acc)

        def refill(st, rng, launched):
            free = ~st["active"]
            n_free = jnp.sum(free, dtype=i32)
            remaining = budget - launched

            def ranked():
                rank = jnp.cumsum(free, dtype=i32) - 1
                return free & (rank < remaining)

            # the rank of each free lane is needed only while the budget runs out, not in the bulk of the batch
            new = jax.lax.cond(n_free <= remaining, lambda: free,
                               lambda: jax.lax.cond(remaining > 0, ranked, lambda: jnp.zeros_like(free)))
            fresh, rng = launch(rng, free.shape[0])
            st = dict(st, **{s: jnp.where(new, fresh[s], st[s]) for s in fresh}, active=st["active"] | new)
            n_new = jnp.sum(new, dtype=i32)
            return st, rng, launched + n_new, free.shape[0] - n_free + n_new

        words = jax.random.bits(key, (2 * _GENERATORS, lanes), u32)
        rng = ()
        for s0, s1 in zip(words[0::2], words[1::2]):
            rng += (s0 | ((s0 | s1) == 0).astype(u32), s1)  # never the all-zero state
        st = {s: jnp.zeros(lanes, f32) for s in ("x", "y", "z", "ux", "uy", "uz", "w")}
        st.update(n=jnp.zeros(lanes, i32), events=jnp.zeros(lanes, i32), active=jnp.zeros(lanes, bool))
        st, rng, launched, n_active = refill(st, rng, jnp.int32(0))
        acc = (jnp.zeros((4, n_cells), f32), jnp.zeros((4, n_cells), f32), jnp.zeros(3, f32), jnp.zeros(3, f32),
               jnp.zeros((), i32))
        events = []
        for stage, width in enumerate(widths):
            last = stage == len(widths) - 1
            next_width = 0 if last else widths[stage + 1]
            if stage == 0:
                def cond(c, next_width=next_width):
                    return (c[3] < budget) | (c[4] > next_width)

                def body(c):
                    st, rng, acc, launched, _ = c
                    st, rng, acc = iterate(st, rng, acc)
                    st, rng, launched, n_active = refill(st, rng, launched)
                    return st, rng, acc, launched, n_active
            else:
                def cond(c, next_width=next_width):
                    return c[4] > next_width

                def body(c):
                    st, rng, acc, launched, _ = c
                    st, rng, acc = iterate(st, rng, acc)
                    return st, rng, acc, launched, jnp.sum(st["active"], dtype=i32)

            st, rng, acc, launched, n_active = jax.lax.while_loop(cond, body, (st, rng, acc, launched, n_active))
            events.append(st["events"])
            if not last:
                # the survivors (at most next_width of them) move to the first lanes of a narrower stage
                keep = jnp.nonzero(st["active"], size=next_width, fill_value=0)[0]
                st = {s: v[keep] for s, v in st.items()}
                st["active"] = jnp.arange(next_width, dtype=i32) < n_active
                st["events"] = jnp.zeros(next_width, i32)
                rng = tuple(v[keep] for v in rng)
        hist_acc, hist_c, sums_acc, sums_c, n_capped = acc
        hist, sums = hist_acc - hist_c, sums_acc - sums_c
        return dict(R=hist[0], R2=hist[1], T=hist[2], T2=hist[3], R1=sums[0], R1sq=sums[1], capped_w=sums[2],
                    capped=n_capped, events=jnp.concatenate(events))

    return run


@dataclasses.dataclass
class MCResult:
    """Tallies of one run (lengths in mean free paths). Reflectances are fractions of the incident power."""

    albedo: float
    g: float
    eta: float
    slab_mfp: float | None
    incidence: str
    photons: int
    seed: int
    bin_edges_mfp: np.ndarray
    total_reflectance: float
    total_reflectance_stderr: float
    total_transmittance: float
    total_transmittance_stderr: float
    specular_reflectance: float
    single_scatter_reflectance: float
    single_scatter_reflectance_stderr: float
    R: np.ndarray  # reflectance per unit area (1/mfp^2) per radial bin
    R_stderr: np.ndarray
    T: np.ndarray  # transmittance per unit area through a slab
    T_stderr: np.ndarray
    capped_photons: int
    capped_weight: float
    scattering_events: int
    seconds: float

    @property
    def r_mfp(self) -> np.ndarray:
        return 0.5 * (self.bin_edges_mfp[1:] + self.bin_edges_mfp[:-1])

    def to_json(self) -> dict[str, Any]:
        from ._version import __version__

        r = self.r_mfp
        out = {
            "albedo": self.albedo, "g": self.g, "eta": self.eta, "slab_mfp": self.slab_mfp,
            "incidence": self.incidence, "photons": self.photons, "seed": self.seed,
            "total_reflectance": self.total_reflectance, "total_reflectance_stderr": self.total_reflectance_stderr,
            # NaN where it is not defined (diffuse incidence): null, as JSON (RFC 8259) has no NaN
            "specular_reflectance": None if math.isnan(self.specular_reflectance) else self.specular_reflectance,
            "single_scatter_reflectance": self.single_scatter_reflectance,
            "capped_photons": self.capped_photons, "capped_weight": self.capped_weight,
            "scattering_events": self.scattering_events, "seconds": self.seconds, "version": __version__,
            "profile": {"r_mfp": r.tolist(), "rR": (r * self.R).tolist(), "rR_stderr": (r * self.R_stderr).tolist()},
        }
        if self.slab_mfp is not None:
            out["total_transmittance"] = self.total_transmittance
            out["total_transmittance_stderr"] = self.total_transmittance_stderr
            out["transmission_profile"] = {"r_mfp": r.tolist(), "rT": (r * self.T).tolist(),
                                           "rT_stderr": (r * self.T_stderr).tolist()}
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "MCResult":
        """The result that ``to_json`` wrote (bins, totals, profiles and provenance; per-bin tallies come back from
        ``r R`` so a cached run serves as a ``to_tabulated_profile`` input exactly as the live one did)."""
        prof = data["profile"]
        r = np.asarray(prof["r_mfp"], np.float64)
        width = 2 * r[0]
        edges = np.arange(r.size + 1) * width
        trans = data.get("transmission_profile")
        nan = float("nan")
        T = np.asarray(trans["rT"]) / r if trans else np.zeros_like(r)
        T_err = np.asarray(trans["rT_stderr"]) / r if trans else np.zeros_like(r)
        return cls(
            albedo=data["albedo"], g=data["g"], eta=data["eta"], slab_mfp=data["slab_mfp"], incidence=data["incidence"],
            photons=data["photons"], seed=data["seed"], bin_edges_mfp=edges,
            total_reflectance=data["total_reflectance"], total_reflectance_stderr=data["total_reflectance_stderr"],
            total_transmittance=data.get("total_transmittance", 0.0),
            total_transmittance_stderr=data.get("total_transmittance_stderr", 0.0),
            specular_reflectance=nan if data["specular_reflectance"] is None else data["specular_reflectance"],
            single_scatter_reflectance=data["single_scatter_reflectance"], single_scatter_reflectance_stderr=nan,
            R=np.asarray(prof["rR"]) / r, R_stderr=np.asarray(prof["rR_stderr"]) / r, T=T, T_stderr=T_err,
            capped_photons=data["capped_photons"], capped_weight=data["capped_weight"],
            scattering_events=data["scattering_events"], seconds=data["seconds"],
        )


_KERNELS: dict[tuple, Any] = {}


def simulate(
    albedo: float,
    *,
    photons: int = 100_000,
    g: float = 0.0,
    eta: float = 1.0,
    slab_mfp: float | None = None,
    incidence: str = "pencil",
    seed: int = 0,
    bins: int = 200,
    r_max_mfp: float = 20.0,
    lanes: int = 1 << 12,
    batch_photons: int = 1 << 16,
    max_events: int = 100_000,
    max_events_hard: int | None = None,
    progress: bool = False,
    workers: int | None = None,
    unroll: int | None = None,
) -> MCResult:
    """Random-walk reflectance (and slab transmittance) of a homogeneous medium, in mean free paths.

    ``albedo``: single-scattering albedo ``sigma_s / sigma_t`` in [0, 1]; ``g``: HG asymmetry in (-1, 1); ``eta``:
    relative index of refraction (>= 1); ``slab_mfp``: slab thickness (None: semi-infinite); ``incidence``:
    ``"pencil"`` (normal) or ``"diffuse"``. Returns tallies with standard errors (per photon, so bins and totals
    carry their own statistical error).

    Termination, unbiased: for its first ``max_events`` scatterings a photon carries the albedo in its weight
    (implicit capture, Russian roulette below weight 1e-3); after them it is absorbed at each scattering with
    probability ``1 - albedo`` (analog, weight unchanged). In a half-space without absorption (albedo 1) a photon
    that has scattered ``max_events`` times is certain to leave through the top: its weight is tallied there, in the
    overflow bin ``r >= r_max_mfp``. Only a photon still inside after ``max_events_hard`` scatterings (default
    ``1000 max_events``; in practice a thick non-absorbing slab) is dropped, and counted in ``capped_photons`` and
    ``capped_weight`` (the fraction of the incident power it carried).

    Execution (none of it changes the physics; the numbers depend on ``seed``, ``photons``, ``batch_photons``,
    ``lanes`` and ``unroll``, never on ``workers``): photons run in batches of at most ``batch_photons`` (split evenly),
    each a jitted walk over ``lanes`` parallel photons advancing ``unroll`` events per loop iteration (default 4 at
    albedo >= 0.8, else 2); ``workers`` threads (default: one per core this process may use,
    ``_machine.usable_cores``) run batches side by side, at most ``workers`` at a time, so memory stays
    ``O(workers * (lanes + bins))`` for any photon count; ``progress`` shows a bar advancing per batch.
    """
    if not (0.0 <= albedo <= 1.0):
        raise ValueError(f"albedo must lie in [0, 1], got {albedo}")
    if not (-1.0 < g < 1.0):
        raise ValueError(f"g must lie in (-1, 1), got {g}")
    if not (eta >= 1.0 and math.isfinite(eta)):
        raise ValueError(f"eta must be a finite number >= 1, got {eta}")
    photons = check_host_count(photons, "photons", lo=2)  # a standard error needs two: one photon's is undefined
    bins = check_host_count(bins, "bins")
    lanes = check_host_count(lanes, "lanes")  # 0 lanes walked no photon, forever
    batch_photons = check_host_count(batch_photons, "batch_photons")
    if isinstance(r_max_mfp, (bool, np.bool_)) or not isinstance(r_max_mfp, Real) or not 0 < r_max_mfp < math.inf:
        # a negative radius sent the reflected photons' bins into the transmittance half of the histogram
        raise ValueError(f"r_max_mfp must be a finite positive radius (mean free paths), got {r_max_mfp!r}")
    if slab_mfp is not None and not (slab_mfp > 0 and math.isfinite(slab_mfp)):
        raise ValueError(f"slab thickness must be a finite positive length, got {slab_mfp}")
    if incidence not in ("pencil", "diffuse"):
        raise ValueError(f"incidence must be 'pencil' or 'diffuse', got {incidence!r}")
    if not isinstance(max_events, (int, np.integer)) or not (1 <= max_events <= 2**31 - 2):
        raise ValueError(f"max_events must be an integer from 1 to 2^31 - 2, got {max_events!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not (0 <= seed < 2**32):
        # PRNGKey keeps a seed's low 32 bits: 2^32 would silently give seed 0's photons, -1 seed 2^32 - 1's
        raise ValueError(f"seed must be an integer in [0, 2^32), got {seed!r}")
    if max_events_hard is None:
        max_events_hard = min(1000 * int(max_events), 2**31 - 2)
    if not isinstance(max_events_hard, (int, np.integer)) or not (max_events <= max_events_hard <= 2**31 - 2):
        raise ValueError(f"max_events_hard must be an integer from max_events ({max_events}) to 2^31 - 2, "
                         f"got {max_events_hard!r}")
    lanes = int(min(lanes, photons, batch_photons))
    if unroll is None:
        # events per iteration: more amortise the tally and refill, but a photon that ends mid-iteration leaves its
        # lane idle for the rest of it, which costs most where photons live few events (low albedo)
        unroll = 4 if albedo >= 0.8 else 2
    unroll = check_host_count(unroll, "unroll")
    key_cfg = (lanes, bins, float(r_max_mfp), int(max_events), int(max_events_hard), slab_mfp is not None, incidence == "diffuse",
               g == 0.0, eta == 1.0, int(unroll))
    if key_cfg not in _KERNELS:
        _KERNELS[key_cfg] = _make_kernel(*key_cfg)
    run = _KERNELS[key_cfg]
    totals = {k: 0.0 for k in ("R1", "R1sq", "capped", "capped_w", "events")}
    hist = {k: np.zeros(bins + 1) for k in ("R", "R2", "T", "T2")}
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=photons, unit="photon", unit_scale=True, desc="montecarlo")
    thickness = np.float32(slab_mfp if slab_mfp is not None else np.inf)
    params = (jnp.float32(albedo), jnp.float32(g), jnp.float32(eta), thickness)
    # the batches and their keys depend on the photon count and batch size only, never on the number of threads, and
    # tallies add up in batch order: the same seed gives the same numbers on any machine
    n_batches = -(-photons // batch_photons)
    sizes = [photons // n_batches + (i < photons % n_batches) for i in range(n_batches)]  # as even as can be
    root = jax.random.PRNGKey(seed)

    def one_batch(call: int):
        t = run(jax.random.fold_in(root, call), jnp.int32(sizes[call]), *params)
        return jax.tree.map(np.asarray, t)

    if workers is None:
        workers = usable_cores()
    workers = max(1, min(int(workers), len(sizes)))
    t0 = time.perf_counter()
    # each jitted call runs on one core; calls from several threads run side by side (XLA releases the GIL), at most
    # `workers` batches in flight so memory stays O(workers * (lanes + bins))
    with concurrent.futures.ThreadPoolExecutor(workers) as pool:
        pending = collections.deque((c, pool.submit(one_batch, c)) for c in range(workers))
        next_call = workers
        try:
            while pending:
                call, future = pending.popleft()
                t = future.result()
                if next_call < len(sizes):
                    pending.append((next_call, pool.submit(one_batch, next_call)))
                    next_call += 1
                for k in hist:
                    hist[k] += t[k].astype(np.float64)
                for k in ("R1", "R1sq", "capped_w"):
                    totals[k] += float(t[k])
                totals["capped"] += int(t["capped"])
                totals["events"] += int(t["events"].sum(dtype=np.int64))
                if bar is not None:
                    bar.update(sizes[call])
        finally:
            for _, f in pending:
                f.cancel()
            if bar is not None:
                bar.close()
    seconds = time.perf_counter() - t0
    N = float(photons)

    def mean_err(s, s2):  # the mean and its standard error, from the sample variance (N - 1: unbiased)
        mean = s / N
        var = np.maximum(s2 / N - mean * mean, 0.0) * (N / (N - 1))
        return mean, np.sqrt(var / N)

    edges = np.linspace(0.0, r_max_mfp, bins + 1)
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    R_bin, R_bin_err = mean_err(hist["R"], hist["R2"])
    T_bin, T_bin_err = mean_err(hist["T"], hist["T2"])
    # a photon leaves once, so its total contribution is its weight in one bin: the per-photon variance of the total
    # is the sum of the per-bin second moments
    R_tot, R_tot_err = mean_err(hist["R"].sum(), hist["R2"].sum())
    T_tot, T_tot_err = mean_err(hist["T"].sum(), hist["T2"].sum())
    R1, R1_err = mean_err(totals["R1"], totals["R1sq"])
    r_sp = ((eta - 1) / (eta + 1)) ** 2 if incidence == "pencil" else float("nan")
    return MCResult(
        albedo=float(albedo), g=float(g), eta=float(eta), slab_mfp=slab_mfp, incidence=incidence,
        photons=int(photons), seed=int(seed), bin_edges_mfp=edges,
        total_reflectance=float(R_tot), total_reflectance_stderr=float(R_tot_err),
        total_transmittance=float(T_tot), total_transmittance_stderr=float(T_tot_err),
        specular_reflectance=r_sp, single_scatter_reflectance=float(R1), single_scatter_reflectance_stderr=float(R1_err),
        R=R_bin[:bins] / area, R_stderr=R_bin_err[:bins] / area, T=T_bin[:bins] / area, T_stderr=T_bin_err[:bins] / area,
        capped_photons=int(totals["capped"]), capped_weight=float(totals["capped_w"]) / N,
        scattering_events=int(totals["events"]), seconds=seconds,
    )


def to_tabulated_profile(results: MCResult | list[MCResult], mfp_mm: float | list[float]):
    """The reflectance profile(s) as a ``TabulatedProfile`` in millimetres (one channel per result), each channel
    holding the energy its histogram holds (``sum R_i pi (e_{i+1}^2 - e_i^2)``): the bins' averages, read as values
    at the bins' centres, are scaled by the one factor per channel that makes the table's piecewise-linear integral
    equal it (the raw table over-integrates the peak near r = 0 by 2-4%)."""
    from ._profiles import TabulatedProfile

    results = [results] if isinstance(results, MCResult) else list(results)
    if not results or not all(isinstance(r, MCResult) for r in results):
        raise TypeError(f"results must be an MCResult or a list of them, got {results!r:.80}")
    check_host_range(mfp_mm, "mfp_mm", low_open=True)
    if np.ndim(mfp_mm) > 1 or np.size(mfp_mm) not in (1, len(results)):
        raise ValueError(f"mfp_mm must be one length or one per result ({len(results)}), got {mfp_mm!r}")
    mfps = np.broadcast_to(np.asarray(mfp_mm, np.float64), (len(results),))
    # one radius grid, the union of every channel's bin centres (so a channel with a short mean free path keeps its
    # own resolution), every channel's R (1/mm^2) interpolated onto it and 0 beyond its own range. The radii are
    # made distinct in the dtype the table is stored in (JAX's float): centres one float64 ulp apart (0.5 x 0.15 and
    # 0.3 x 0.25 mm) collapsed in float32 and the table was refused
    stored = np.dtype(jnp.result_type(float))
    r0 = np.unique(np.concatenate([res.r_mfp * m for res, m in zip(results, mfps)]).astype(stored)).astype(np.float64)
    cols = np.stack([np.interp(r0, res.r_mfp * m, res.R / (m * m), right=0.0) for res, m in zip(results, mfps)], -1)
    held = np.asarray([np.sum(res.R * np.pi * np.diff(res.bin_edges_mfp**2)) for res in results])  # (mfp-free)
    raw = np.asarray(TabulatedProfile(r0, cols).albedo, np.float64)
    return TabulatedProfile(r0, cols * np.where(raw > 0, held / np.where(raw > 0, raw, 1.0), 1.0))
