"""Small planar geometry shared by every layer (numpy only, so ``slam/`` may use it too)."""

from __future__ import annotations

import numpy as np


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles (any shape) wrapped to (−π, π]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi))
