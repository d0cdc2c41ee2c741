"""Checks shared by the model language (:mod:`cases.model`, :mod:`cases.constraints`): each appends what is wrong to
``problems`` (so that every violated precondition is reported together) and returns the checked value or None."""

from __future__ import annotations

from typing import Sequence

import numpy as np


def frozen(values, shape, dtype=float) -> np.ndarray:
    """A read-only array of ``values`` in ``shape``."""
    arr = np.array(values, dtype=dtype).reshape(shape)
    arr.setflags(write=False)
    return arr


def finite(problems: list[str], where: str, arr: np.ndarray) -> bool:
    if not np.all(np.isfinite(arr)):
        problems.append(f"{where} has non-finite entries (NaN or inf): {arr.tolist()}")
        return False
    return True


def as_array(problems: list[str], where: str, value, shape) -> np.ndarray | None:
    """``value`` as a finite float array of ``shape``."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        problems.append(f"{where} is not numeric: {value!r}")
        return None
    if arr.shape != shape:
        problems.append(f"{where} has shape {arr.shape}, expected {shape}")
        return None
    return arr if finite(problems, where, arr) else None


def orthonormal_rows(problems: list[str], where: str, value, counts: Sequence[int]) -> np.ndarray | None:
    """``value`` as orthonormal rows of world 3-vectors (read-only), as many as one of ``counts``."""
    try:
        D = np.array(value, dtype=float)
    except (TypeError, ValueError):
        problems.append(f"{where} are not numeric: {value!r}")
        return None
    if D.ndim != 2 or D.shape[1] != 3 or D.shape[0] not in counts:
        problems.append(f"{where} have shape {D.shape}; give {' or '.join(map(str, counts))} rows of world 3-vectors")
        return None
    if not finite(problems, where, D):
        return None
    err = np.abs(D @ D.T - np.eye(D.shape[0])).max()
    if err > 1e-9:
        problems.append(f"{where} are not orthonormal rows (|D D^T - I| = {err:.2e}): {D.tolist()}")
        return None
    return frozen(D, D.shape)
