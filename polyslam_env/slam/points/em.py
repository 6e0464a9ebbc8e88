"""EM-FastSLAM's electromagnetism-like move (seed 003, eqs. 4, 6, 7 as SPEC §8 corrects them).

Each particle is a charge. With objective values f (the normalised weights) and f_best their
maximum, particle i carries

    Q_i = exp(−n (f_best − f_i) / Σ_k (f_best − f_k)),        n = 3 (pose dimension),

feels F_i = Σ_{j≠i} s_ij Q_i Q_j (x_j − x_i) with s_ij = +1 if f_j > f_i (attraction) and −1
otherwise (repulsion, eq. 7, no distance scaling), and moves x_i += λ_i R ⊙ F_i / ‖F_i‖ with
λ_i ~ U(0, 1): never more than R_d along axis d. The paper prints eq. 6 as
(x_i + λ R F_i)/‖F_i‖; SPEC §8 fixes it. As in Birbil and Fang's method the best particle is
not moved (it has nothing to be attracted to), and when all f are equal nothing moves (the
charges are undefined: there is no information to move on).
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.points.models import pose_difference


def charges(f: np.ndarray, dim: int = 3) -> np.ndarray | None:
    """Q (N,) of eq. 4 for objective values f (N,) of points of dimension ``dim``;
    ``None`` when all f are equal."""
    gap = np.max(f) - f
    total = gap.sum()
    if not total > 0.0:
        return None
    return np.exp(-dim * gap / total)


def forces(x: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Total force (N, 3) of eq. 7 on poses x (N, 3) (heading differences wrapped)."""
    toward = pose_difference(x[None, :, :], x[:, None, :])  # [i, j] = x_j − x_i
    sign = np.where(f[None, :] > f[:, None], 1.0, -1.0)
    np.fill_diagonal(sign, 0.0)
    return np.einsum("ij,ijd->id", sign * np.outer(q, q), toward)


def em_move(
    rng: np.random.Generator, x: np.ndarray, f: np.ndarray, mobility: np.ndarray
) -> np.ndarray:
    """Poses x (N, 3) after one attraction-repulsion move; x itself when nothing moves.

    Draws the N step lengths λ whether or not a particle moves, so the random stream does not
    depend on the weights' values.
    """
    step = rng.random(len(x))
    q = charges(f)
    if q is None:
        return x
    force = forces(x, f, q)
    norm = np.linalg.norm(force, axis=1)
    movable = norm > 0.0
    movable[int(np.argmax(f))] = False
    out = x.copy()
    scale = step[movable] / norm[movable]
    out[movable] += scale[:, None] * mobility[None, :] * force[movable]
    out[movable, 2] = wrap_angle(out[movable, 2])
    return out
