"""Central finite differences shared by the SLAM Jacobian tests.

Step 1e-6 on O(1) quantities: truncation ~1e-12, round-off ~1e-10 relative; a relative
tolerance of 1e-5 leaves margin and still catches any wrong term (those are O(1) relative).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

FD_STEP = 1e-6
FD_RTOL = 1e-5
FD_ATOL = 1e-6


def fd_jacobian(func: Callable[[np.ndarray], float], x0: np.ndarray) -> np.ndarray:
    """Central finite-difference gradient of a scalar function."""
    grad = np.zeros(len(x0))
    for j in range(len(x0)):
        step = np.zeros(len(x0))
        step[j] = FD_STEP
        grad[j] = (func(x0 + step) - func(x0 - step)) / (2 * FD_STEP)
    return grad
