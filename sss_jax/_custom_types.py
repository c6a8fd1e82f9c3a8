"""Types shared by the signatures (optimistix keeps its own in ``_custom_types.py``): what a parameter accepts
beyond jaxtyping's ``ArrayLike`` (which has no Python sequences), so the annotations stay true under the checker."""

from collections.abc import Sequence
from typing import Any, Union

from jaxtyping import ArrayLike

# A per-channel parameter as users write it: an array, a number, or (nested) lists/tuples such as (0.8, 0.5, 0.4).
ParamLike = Union[ArrayLike, Sequence[Any]]
