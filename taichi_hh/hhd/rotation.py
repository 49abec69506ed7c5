"""The rotation J of the decomposition v = grad phi + J grad psi + h."""
from __future__ import annotations

import numpy as np


def J(v: np.ndarray) -> np.ndarray:
    """J(a, b) = (b, -a): rotation by 90 degrees clockwise (Petronetto Eq. 2)."""
    return np.stack([v[..., 1], -v[..., 0]], axis=-1)
