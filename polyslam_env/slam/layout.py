"""Where each landmark sits in the EKF state, and how one enters or leaves it
(:class:`StateLayout`).

The state of :class:`~polyslam_env.slam.robot.PolySlam` is ``[x¹, x², θ, c0_1 … c0_n,
α_1 … α_n]``: the pose, one position coefficient per landmark (row i of the landmark table is
state 3 + i) and, with rotation states (``SlamConfig.shape_rotation="considered"``), one shape
turn α per landmark after all the c0s (state 3 + n + i). A new landmark's c0 and α go in at
the end of their blocks (:meth:`StateLayout.add`); a removed landmark's leave
(:meth:`StateLayout.remove`); both keep the rest of the covariance (paper eq. 4–5, a
marginalisation).

**How α is made, said once** (:class:`TurnSource`, :func:`turn_row`). α is the angle by which
the true wall is turned from the stored shape about its pivot. A shape fitted now, to points
placed with the current pose estimate, is turned by the current heading error plus its
slope's fit error: its row is a copy of the heading's, with the fit's variance added (a
clone, as in Roumeliotis & Burdick's stochastic cloning). A shape fitted over older
landmarks' points (a refit, or a merge with ``merge_turn="weights"``) takes their turns with
the source's weights, and the rest, 1 − Σ w, from the current heading (or from a received
wall's frame transform) with that share of the fit variance. A merge with
``merge_turn="fit"`` (the default) gives the merged fit's own direction instead, (∂α/∂X,
variance) (:func:`~polyslam_env.slam.fitting.turn_gradient`): the pieces' offsets fix a long
wall's direction far better than their own short turns. α is then *considered*, not
estimated (no gain: the stored shape stays the estimate), and its correlations carry how a
wall made long ago ties the current heading to the heading of its time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from polyslam_env.slam import ekf
from polyslam_env.slam.fitting import Fit


class TurnSource(NamedTuple):
    """What a new landmark's turn α is made of (module docstring); the default is a clone of
    the current heading."""

    rotation: Sequence[tuple[int, float]] = ()  # (row, weight) of older landmarks' turns
    turn: tuple[np.ndarray, float] | None = None  # received: (∂α/∂pose (3,), variance)
    gradient: tuple[np.ndarray, float] | None = None  # a merged fit's (∂α/∂X, variance)


def turn_row(size: int, n: int, source: TurnSource, fit_var: float) -> tuple[np.ndarray, float]:
    """α's row G_x (``size``,) over the state [pose, c0 × n, α × n, c0_new] and its
    variance beyond what the state holds; ``fit_var`` is the new shape's own slope error
    (``PolySlam._rotation_fit_var``)."""
    gx = np.zeros(size)
    if source.gradient is not None:  # a merge's turn from its fit (config.merge_turn "fit")
        gx[: size - 1], var = source.gradient
        return gx, var
    rest = 1.0
    for row, weight in source.rotation:
        gx[3 + n + row] += weight
        rest -= weight
    var = fit_var
    if source.turn is None:
        gx[2] += rest
    else:  # e.g. a received wall: the frame transform's turn
        gx[:3] += rest * np.asarray(source.turn[0], dtype=float)
        var += source.turn[1]
    return gx, var * (rest * rest)


class StateLayout:
    """Index arithmetic of the state and the landmarks' way in and out (module docstring)."""

    def __init__(self, rotation_states: bool) -> None:
        self.rotation_states = rotation_states

    @staticmethod
    def c0_index(row: int) -> int:
        """State index of landmark ``row``'s c0."""
        return 3 + row

    @staticmethod
    def turn_index(row: int, n: int) -> int:
        """State index of landmark ``row``'s turn α among ``n`` landmarks (the α block follows
        the n c0s)."""
        return 3 + n + row

    def turn_of(self, row: int, n: int, pivot: float) -> tuple[int, float] | None:
        """(state index of landmark ``row``'s turn α, its pivot ξ), None without rotation
        states: points sampled on its shape move with α (``fitting.polynomial_points``), so
        a fit over them (a refit's R, a merge) has its c0's dependence on α in G_x."""
        if not self.rotation_states:
            return None
        return self.turn_index(row, n), pivot

    def add(
        self,
        mean: np.ndarray,
        cov: np.ndarray,
        n: int,
        fit: Fit,
        source: TurnSource,
        fit_var: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The state with a new landmark's c0 (``fit``: its value and G_x, G_y, V; paper eq.
        4–5) and, with rotation states, its turn α (:func:`turn_row` of ``source``; ``fit_var``
        its shape's own slope error), each at the end of its block: [pose, c0_1 … c0_n,
        α_1 … α_n] becomes [pose, c0_1 … c0_new, α_1 … α_new]."""
        if not self.rotation_states:
            return ekf.augment(mean, cov, fit.c0, fit.Gx, fit.Gy, fit.V)
        # α's row over the state grown by the c0 (3 + 2n + 1: the new c0 last), both in one
        # compiled call
        gx, var = turn_row(mean.size + 1, n, source, fit_var)
        return ekf.augment_pair(
            mean, cov, fit.c0, fit.Gx, fit.Gy, fit.V, gx, var, new_c0_before_turns(n)
        )

    def remove(
        self, mean: np.ndarray, cov: np.ndarray, row: int | Sequence[int], n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The state without the c0 (and α) of landmark ``row`` (or of each of ``row``, a
        merge's two at once: one copy of the covariance) among ``n`` landmarks."""
        rows = [row] if isinstance(row, int | np.integer) else list(row)
        drop = [self.c0_index(r) for r in rows]
        if self.rotation_states:
            drop += [self.turn_index(r, n) for r in rows]
        return ekf.remove(mean, cov, drop)


def new_c0_before_turns(n: int) -> np.ndarray:
    """The order that takes [pose, c0_1 … c0_n, α_1 … α_n, c0_new, α_new] to [pose, c0_1 …
    c0_new, α_1 … α_new]: ``np.r_[0:3+n, last−1, 3+n:last−1, last]`` (last = 3 + 2n + 1)."""
    last = 3 + 2 * n + 1
    order = np.arange(last + 1)
    order[3 + n] = last - 1
    order[4 + n : last] = np.arange(3 + n, last - 1)
    return order
