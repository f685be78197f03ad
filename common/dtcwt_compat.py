"""The one place the project imports :mod:`dtcwt` through.

dtcwt 0.14 declares ``numpy<2`` and calls two functions that NumPy 2 removed:
``np.asfarray`` and ``np.issubsctype``. Everything else in its forward transform
works on NumPy 2. This module supplies the two names with their NumPy 1 meaning
(only when missing) and then imports dtcwt, so every other module does
``from common.dtcwt_compat import dtcwt``.
"""

from __future__ import annotations

import numpy as np


def asfarray(a, dtype=np.float64):
    """NumPy 1's ``asfarray``: ``a`` as a floating array, keeping float dtypes."""
    dtype = np.dtype(dtype)
    if not np.issubdtype(dtype, np.inexact):
        dtype = np.dtype(np.float64)
    return np.asarray(a, dtype=dtype)


def _scalar_type(obj) -> type:
    if isinstance(obj, type) and issubclass(obj, np.generic):
        return obj
    return np.dtype(obj).type


def issubsctype(arg1, arg2) -> bool:
    """NumPy 1's ``issubsctype``: is the scalar type of ``arg1`` a subclass of ``arg2``'s."""
    return issubclass(_scalar_type(arg1), _scalar_type(arg2))


if not hasattr(np, "asfarray"):
    np.asfarray = asfarray  # type: ignore[attr-defined]
if not hasattr(np, "issubsctype"):
    np.issubsctype = issubsctype  # type: ignore[attr-defined]

import dtcwt  # noqa: E402  (must follow the shims above)

BIORT = "near_sym_b_bp"
QSHIFT = "qshift_b_bp"

__all__ = ["dtcwt", "asfarray", "issubsctype", "BIORT", "QSHIFT"]
