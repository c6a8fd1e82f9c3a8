"""Value checks that work under ``jit``: the one place techniques and materials turn a bad parameter into an error."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def checked(x: Array, name: str, *, positive: bool = False, finite: bool = True) -> Array:
    """``x`` unchanged, or an error naming ``name`` where it holds NaN, inf (unless ``finite=False``: +inf allowed)
    or a negative (with ``positive``: non-positive) value. Written so NaN trips it (``~(x >= 0)``, not ``x < 0``)."""
    bad = ~(x > 0) if positive else ~(x >= 0)
    if finite:
        bad = bad | ~jnp.isfinite(x)
    what = ("finite and " if finite else "") + ("> 0" if positive else ">= 0")
    return eqx.error_if(x, bad, f"{name} must be {what}")


def clamp(x: Array, low: float, high: float | None = None) -> Array:
    """``x`` held to ``[low, high]`` with the whole derivative at the bounds themselves: ``jnp.clip`` and
    ``jnp.maximum`` split a tie's derivative in two, which halved the gradient at an albedo or ``w`` of exactly 0 or 1
    or a thickness of 0 (valid values, and where a bounded optimiser parks a parameter)."""
    x = jnp.where(x < low, jnp.asarray(low, x.dtype), x)
    return x if high is None else jnp.where(x > high, jnp.asarray(high, x.dtype), x)


def check_host_range(x, name: str, *, low: float = 0.0, high: float = math.inf, low_open: bool = False,
                     finite: bool = True) -> None:
    """An error naming ``name`` where ``x``, known on the host (Python, NumPy, a concrete JAX array), is not finite
    (``finite=False``: +inf allowed, NaN never) and in ``[low, high]`` (``(low, high]`` with ``low_open``). Traced
    values (under jit, vmap, grad) pass: their callers check them with ``checked``. For the public builders
    (kernels, profiles, transmittances) that a user calls directly."""
    if isinstance(x, jax.core.Tracer):
        return
    if is_bool(x):  # True reads as 1.0: a flag given where a number belongs
        raise TypeError(f"{name} must be a number or an array of numbers, not a bool, got {x!r}")
    try:
        v = np.asarray(x, np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number or an array of numbers, got {x!r}") from None
    ok = (np.isfinite(v) if finite else ~np.isnan(v)) & ((v > low) if low_open else (v >= low)) & (v <= high)
    if not np.all(ok):
        bound = f"{'>' if low_open else '>='} {low:g}" + (f" and <= {high:g}" if high < math.inf else "")
        shown = _shown(x) if v.size <= 8 else f"{v.size} values, {int(np.sum(~ok))} of them outside"
        raise ValueError(f"{name} must be {'finite and ' if finite else ''}{bound}, got {shown}")


def is_bool(x) -> bool:
    """Whether host value ``x`` is a bool, or an array or sequence holding one (``(True, 0.0, 1.0)``)."""
    if isinstance(x, (bool, np.bool_)):
        return True
    if isinstance(x, (list, tuple)):
        return any(is_bool(v) for v in x)
    dtype = getattr(x, "dtype", None)
    return dtype is not None and np.dtype(dtype) == np.bool_


def _shown(x) -> str:
    """A few host values as the user gave them: each at its own dtype's shortest repr (a float32 1.2 reads 1.2, not
    the 1.2000000476837158 of its float64), flattened."""
    a = np.asarray(x)
    items = [str(e) for e in a.ravel()]
    return items[0] if a.ndim == 0 else "[" + ", ".join(items) + "]"


# the largest count: the passes count samples, taps and frames in int32 on the device (a larger one stopped a jitted
# call with an OverflowError from deep inside JAX)
COUNT_MAX = 2**31 - 1


def check_host_count(x, name: str, *, lo: int = 1, hi: int | None = None, whole_floats: bool = False) -> int:
    """``x`` as a Python integer in ``[lo, hi]`` (``hi=None``: up to ``COUNT_MAX``), or an error naming it. Python
    and NumPy integers and 0-d integer arrays pass; bools never (``True == 1``); floats only with ``whole_floats``
    and an integer value (a count read from JSON, 17.0). Every count of the library's public functions, techniques
    and engine conversions is checked here, with one message."""
    v = _as_count(x, whole_floats)
    if v is None or v < lo or (hi is not None and v > hi):
        what = ("a positive integer" if lo == 1 and hi is None else f"an integer >= {lo}" if hi is None
                else f"an integer in [{lo}, {hi}]")
        raise ValueError(f"{name} must be {what}, got {x!r}")
    if hi is None and v > COUNT_MAX:
        raise ValueError(f"{name} must be at most {COUNT_MAX} (the passes count in int32), got {x!r}")
    return v


def _as_count(x, whole_floats: bool) -> int | None:
    """``check_host_count``'s reading of ``x`` as an integer, or None."""
    if isinstance(x, (bool, np.bool_)):
        return None
    if isinstance(x, (int, np.integer)):
        return int(x)
    if whole_floats and isinstance(x, (float, np.floating)):
        return int(x) if math.isfinite(x) and x == int(x) else None
    dtype = getattr(x, "dtype", None)
    if (dtype is not None and not isinstance(x, jax.core.Tracer) and np.ndim(x) == 0
            and np.issubdtype(dtype, np.integer)):
        return int(x)
    return None
