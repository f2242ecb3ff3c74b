"""Random processes shared by the simulator's sensor models."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def gauss_markov(first: np.ndarray, drive: np.ndarray, phi: float, include_first: bool = False) -> np.ndarray:
    """x_k = phi x_{k-1} + drive_k along axis 0, starting from x = first before drive[0]
    (or, with include_first, returning first as the first row). A linear filter: fast and exact."""
    if include_first:
        return np.concatenate([first[None], gauss_markov(first, drive, phi)])
    seeded = drive.copy()
    seeded[0] += phi * first
    return lfilter([1.0], [1.0, -phi], seeded, axis=0)
