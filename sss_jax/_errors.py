"""The errors and warnings sss_jax raises, in one place (re-exported on the public face).

Nothing here imports another sss_jax module, so every module can import it without a cycle.
"""

from __future__ import annotations


class SSSInputError(ValueError):
    """Bad input from a user: the message names the input and what is wrong."""


class SamplingWarning(UserWarning):
    """A pass's taps or samples can no longer represent the kernel: the message states the error it implies."""


class ReferenceWindowWarning(UserWarning):
    """``reference``'s window holds less than 99.9% of the profile's energy: the result is not ground truth there."""


class NoSSSPixelsWarning(UserWarning):
    """A frame has no pixel a technique scatters (no surface, or every surface's id is 0): its output is its input,
    not a result."""


class HalfRangeWarning(UserWarning):
    """An output written as half float held values beyond half's range: they were written as its largest (a float
    output keeps them)."""


class TilePlacementError(ValueError):
    """A technique was handed a tile of a larger frame that it cannot place: its formulation takes no
    ``origin``/``frame_shape``, or would give other pixels in a tile than in its frame (separable's banded levels
    on a CPU); a batch then runs that technique's frames whole."""
