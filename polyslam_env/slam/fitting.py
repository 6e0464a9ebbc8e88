"""The landmark generation function g: weighted LMS polynomial fits and their Jacobians.

Every landmark the SLAM creates (from a cluster), refits (from Q_bad ∪ R) or merges (from
points on two polynomials) is a weighted least-squares fit of a polynomial to points, and its
position coefficient c0 enters the EKF state through eq. 4–5 of the paper:
``P ← G_x P G_xᵀ + G_y V G_yᵀ``. To build G_x and G_y each point carries its derivatives with
respect to the state X = [x¹, x², θ, c0_1 … c0_n] and to its own measurement noise
(:class:`PointSet`); :func:`fit_polynomial` chains them through the derivative of the LMS
solution (SPEC §3 "Weighted LMS", "State augmentation / replacement").

Points come from three constructors:

* :func:`beam_points` — this step's range returns (paper eq. 3), exact derivatives;
* :func:`stored_points` — points kept from earlier steps (clusters, Q_bad), attached to the
  current pose (see its docstring for the approximation);
* :func:`polynomial_points` — points sampled on a polynomial whose c0 is in the state.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.special

from polyslam_env.slam import fit_kernels, map_kernels
from polyslam_env.slam.columns import N_POINT_REAL, PTH, PX, SIGMA, UX, UY, WEIGHT, X, Y
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.stored import PointArrays

# d/dθ of R(θ) v is J R(θ) v
J_ROT = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class PointSet:
    """Points in frame 0 with their derivatives w.r.t. the state and their noise."""

    xy: np.ndarray  # (N, 2) coordinates in the robot's frame 0
    d_state: np.ndarray  # (N, 2, 3+n) ∂point/∂X
    d_noise: np.ndarray  # (N, 2, k) ∂point/∂noise
    noise_cov: np.ndarray  # (k, k) covariance V of the noise
    weights: np.ndarray  # (N,) LMS weights, > 0

    def __post_init__(self) -> None:
        n_pts = self.xy.shape[0]
        if self.xy.shape != (n_pts, 2):
            raise ValueError(f"xy must have shape (N, 2), got {self.xy.shape}")
        if self.d_state.ndim != 3 or self.d_state.shape[:2] != (n_pts, 2):
            raise ValueError(f"d_state must have shape (N, 2, 3+n), got {self.d_state.shape}")
        k = self.noise_cov.shape[0]
        if self.d_noise.shape != (n_pts, 2, k) or self.noise_cov.shape != (k, k):
            raise ValueError(
                f"d_noise {self.d_noise.shape} and noise_cov {self.noise_cov.shape} disagree"
            )
        if self.weights.shape != (n_pts,) or not (self.weights > 0).all():
            raise ValueError("weights must be a positive (N,) array")

    @staticmethod
    def unchecked(
        xy: np.ndarray,
        d_state: np.ndarray,
        d_noise: np.ndarray,
        noise_cov: np.ndarray,
        weights: np.ndarray,
    ) -> PointSet:
        """A point set from parts known consistent (a run of a checked set's rows, or arrays
        made to these shapes), without :meth:`__post_init__`'s checks: the exchange makes
        and cuts a received chain's set several times per record."""
        out = object.__new__(PointSet)
        out.__dict__.update(  # frozen: not setattr
            xy=xy, d_state=d_state, d_noise=d_noise, noise_cov=noise_cov, weights=weights
        )
        return out

    @property
    def n_points(self) -> int:
        return int(self.xy.shape[0])

    @property
    def n_state(self) -> int:
        return int(self.d_state.shape[2])

    @property
    def n_noise(self) -> int:
        return int(self.noise_cov.shape[0])


@dataclass(frozen=True, eq=False)
class Fit:
    """Result of a weighted LMS fit: the polynomial and the rows of g's Jacobians."""

    poly: Polynomial
    c0: float
    Gx: np.ndarray  # (1, 3+n) ∂c0/∂X
    Gy: np.ndarray  # (1, k) ∂c0/∂noise
    V: np.ndarray  # (k, k) noise covariance
    rms: float  # unweighted RMS of the η residuals (m)
    order: int  # order actually fitted (≤ requested; higher coefficients are zero)
    #: (m+1, m+1) R of √W̃ A, A's columns (ξ/scale)^j and W̃ the weights over their largest:
    #: AᵀW̃A = RᵀR on the scaled coefficients a_j·scale^j (None: not from a fit)
    r_factor: np.ndarray | None = None
    scale: float = 1.0  # the abscissae's scale in the design (max |ξ|)


# -- point constructors ------------------------------------------------------------------


def prediction_weight(pose_cov: np.ndarray) -> float:
    """LMS weight 1/‖P_{k|k−1}‖ (spectral norm of the pose block, floored at
    :data:`POSE_VAR_FLOOR`; compiled: :func:`~polyslam_env.slam.map_kernels.prediction_weight`).

    The block is a covariance (symmetric), so its norm is its largest |eigenvalue|.
    """
    block = np.ascontiguousarray(np.asarray(pose_cov, dtype=float)[:3, :3])
    return float(map_kernels.prediction_weight(block))


def _beam_directions(theta: float, beam_angles: np.ndarray) -> np.ndarray:
    phi = theta + np.asarray(beam_angles, dtype=float)
    return np.stack([np.cos(phi), np.sin(phi)], axis=-1)  # (B, 2)


def store_beams(
    pose_pred: np.ndarray,
    pose_cov: np.ndarray,
    ranges: np.ndarray,
    beam_angles: np.ndarray,
    range_sigma: float,
    step: int = -1,
) -> PointArrays:
    """Beam returns of one step as stored points (paper eq. 3: π = p + r (cos φ, sin φ),
    φ = θ + β); beams without return are skipped. The compiled association makes its points
    with the same kernel (:func:`~polyslam_env.slam.map_kernels.beam_returns`)."""
    angles = np.ascontiguousarray(beam_angles, dtype=float).reshape(-1)
    r = np.ascontiguousarray(ranges, dtype=float).reshape(-1)
    cov = np.ascontiguousarray(np.asarray(pose_cov, dtype=float)[:3, :3])
    mean = np.ascontiguousarray(pose_pred, dtype=float)[:3].copy()
    real = np.empty((r.size, N_POINT_REAL))
    beams = np.empty(r.size, dtype=np.int64)
    count = map_kernels.beam_returns(mean, cov, r, angles, float(range_sigma), real, beams)
    real = real[:count]
    return PointArrays(
        np.ascontiguousarray(real[:, X : Y + 1]),
        np.ascontiguousarray(real[:, UX : UY + 1]),
        real[:, SIGMA].copy(),
        real[:, WEIGHT].copy(),
        np.ascontiguousarray(real[:, PX : PTH + 1]),
        beams[:count].copy(),
        np.full(count, step, dtype=np.int64),
    )


def beam_points(
    pose_pred: np.ndarray,
    pose_cov: np.ndarray,
    ranges: np.ndarray,
    beam_angles: np.ndarray,
    range_sigma: float,
    n_state: int,
    anchor_pose: np.ndarray | None = None,
) -> PointSet:
    """This step's beam points π_i = p + y_i (cos(θ+β_i), sin(θ+β_i)) (paper eq. 3).

    The noise is the B ranges (V = σ² I); all points weigh 1/‖P_{k|k−1}‖. With ``anchor_pose``
    the points are computed at ``pose_pred`` but attached to ``anchor_pose`` as in
    :func:`stored_points` (identical to the exact model when both poses are equal).
    All ranges must be finite: select the beams with a return first.
    """
    r = np.asarray(ranges, dtype=float)
    if not np.all(np.isfinite(r)):
        raise ValueError("beam_points needs finite ranges; drop beams without a return")
    if anchor_pose is not None:
        stored = store_beams(pose_pred, pose_cov, r, beam_angles, range_sigma)
        return stored_points(stored, anchor_pose, n_state)
    pose = np.asarray(pose_pred, dtype=float)
    u = _beam_directions(pose[2], beam_angles)  # (B, 2)
    n_beams = len(r)
    d_state = np.zeros((n_beams, 2, n_state))
    d_state[:, :, :2] = np.eye(2)
    d_state[:, :, 2] = r[:, None] * (u @ J_ROT.T)  # ∂/∂θ = y (−sin φ, cos φ)
    return PointSet(
        xy=pose[:2] + r[:, None] * u,
        d_state=d_state,
        d_noise=_diag_noise(u),
        noise_cov=np.eye(n_beams) * float(range_sigma) ** 2,
        weights=np.full(n_beams, prediction_weight(pose_cov)),
    )


def _diag_noise(u: np.ndarray) -> np.ndarray:
    """(N, 2, N) with point i moving along u_i under noise i only."""
    n_pts = len(u)
    d_noise = np.zeros((n_pts, 2, n_pts))
    d_noise[np.arange(n_pts), :, np.arange(n_pts)] = u
    return d_noise


def stored_points(
    points: PointArrays,
    anchor_pose: np.ndarray,
    n_state: int,
    pose: np.ndarray | None = None,
    noise: np.ndarray | None = None,
) -> PointSet:
    """Stored points as a function of the current pose: π_i = p + R(θ − θ̂)(π̂_i − p̂) + e_i u_i.

    ``anchor_pose`` = (p̂, θ̂) is the current pose estimate (the linearisation point), π̂_i the
    stored frame-0 coordinates, u_i the beam direction and e_i ~ N(0, σ_i²) the range noise.
    The point is modelled as rigidly attached to the current pose: ∂/∂(x, y) = I and
    ∂/∂θ = J(π̂_i − p̂). This is an approximation: the pose at the point's own step is no longer
    in the state, so its correlation with the map is carried through the current pose, and the
    odometry drift between the point's step and now is neglected (it is small over the few
    steps a point spends in a cluster or Q_bad). ``pose`` and ``noise`` (default: the anchor
    and zero) evaluate the model elsewhere, for finite-difference checks. One compiled call
    (:func:`~polyslam_env.slam.fit_kernels.stored_point_arrays`).
    """
    if len(points) == 0:
        raise ValueError("stored_points needs at least one point")
    anchor = np.asarray(anchor_pose, dtype=float)
    at = anchor if pose is None else np.asarray(pose, dtype=float)
    e = np.zeros(len(points)) if noise is None else np.asarray(noise, dtype=float)
    xy, d_state, d_noise, noise_cov = fit_kernels.stored_point_arrays(
        np.ascontiguousarray(points.xy, dtype=float), np.ascontiguousarray(points.direction),
        points.sigma, anchor, at, e, n_state, 2.0,
    )  # fmt: skip
    return PointSet(xy, d_state, d_noise, noise_cov, np.array(points.weight, dtype=float))


def polynomial_points(
    poly: Polynomial,
    c0_index: int,
    c0_var: float,
    n: int,
    lo: float,
    hi: float,
    n_state: int,
    turn: tuple[int, float] | None = None,
) -> PointSet:
    """``n`` points equally spaced in ξ ∈ [lo, hi] on ``poly``; its c0 is state ``c0_index``.

    ``poly`` must carry the current state value of c0. ∂η/∂c0 = 1 (η = x² for variate 1, x¹
    for variate 2); there is no measurement noise; every point weighs 1/var(c0). ``turn`` =
    (state index of the shape's turn α, pivot ξ_c): the true wall is the shape turned by α
    about its point at ξ_c, so ∂π/∂α = J(π − π_c) (a landmark's considered rotation state,
    see :class:`~polyslam_env.slam.robot.PolySlam`). One compiled call
    (:func:`~polyslam_env.slam.fit_kernels.sample_into`).
    """
    xy, d_state, weights = np.empty((n, 2)), np.zeros((n, 2, n_state)), np.empty(n)
    sample_into(poly, c0_index, c0_var, (lo, hi, n), turn, (xy, d_state, weights), 0)
    # sample_into checked its arguments (weights 1/var(c0) > 0): made to PointSet's shapes
    return PointSet.unchecked(xy, d_state, np.zeros((n, 2, 0)), np.zeros((0, 0)), weights)


def sample_into(
    poly: Polynomial,
    c0_index: int,
    c0_var: float,
    span: tuple[float, float, int],
    turn: tuple[int, float] | None,
    out: tuple[np.ndarray, np.ndarray, np.ndarray],
    start: int,
) -> None:
    """:func:`polynomial_points`' n points over ξ ∈ [lo, hi] (``span`` = (lo, hi, n)) into
    rows ``start`` … ``start + n − 1`` of ``out`` = (xy (·, 2), d_state (·, 2, S), zero
    there, weights (·,)): a merge samples two polynomials into one set
    (:func:`~polyslam_env.slam.merging.merge_points`). The arguments are checked here, the
    points made by one compiled call (:func:`~polyslam_env.slam.fit_kernels.sample_into`)."""
    xy, d_state, weights = out
    c0, rotation = sample_args(c0_index, c0_var, turn, d_state.shape[2])
    fit_kernels.sample_into(
        poly.coeffs, poly.variate, (float(span[0]), float(span[1])), c0, rotation,
        xy, d_state, weights, start, span[2],
    )  # fmt: skip


def sample_args(
    c0_index: int, c0_var: float, turn: tuple[int, float] | None, n_state: int
) -> tuple[tuple[int, float], tuple[int, float]]:
    """:func:`sample_into`'s checked (c0's state index, its variance) and (α's state index
    or −1, pivot ξ), as the compiled samplers take them."""
    if not 3 <= c0_index < n_state:
        raise ValueError(
            f"c0_index must be a landmark state index in [3, {n_state}), got {c0_index}"
        )
    if not c0_var > 0:
        raise ValueError(f"c0_var must be > 0, got {c0_var}")
    if turn is not None and (not 3 <= turn[0] < n_state or turn[0] == c0_index):
        raise ValueError(f"turn index must be another state index, got {turn[0]}")
    return (c0_index, float(c0_var)), NO_TURN if turn is None else (turn[0], float(turn[1]))


def concat(*pointsets: PointSet) -> PointSet:
    """Stack point sets; their noises are independent, so V is block diagonal."""
    if not pointsets:
        raise ValueError("concat needs at least one PointSet")
    n_state = pointsets[0].n_state
    if any(ps.n_state != n_state for ps in pointsets):
        raise ValueError("all point sets must share the state size")
    k_total = sum(ps.n_noise for ps in pointsets)
    d_noise = np.zeros((sum(ps.n_points for ps in pointsets), 2, k_total))
    noise_cov = np.zeros((k_total, k_total))  # block diagonal
    row = col = 0
    for ps in pointsets:
        n_points, n_noise = ps.xy.shape[0], ps.noise_cov.shape[0]
        d_noise[row : row + n_points, :, col : col + n_noise] = ps.d_noise
        noise_cov[col : col + n_noise, col : col + n_noise] = ps.noise_cov
        row, col = row + n_points, col + n_noise
    return PointSet(
        xy=np.concatenate([ps.xy for ps in pointsets]),
        d_state=np.concatenate([ps.d_state for ps in pointsets]),
        d_noise=d_noise,
        noise_cov=noise_cov,
        weights=np.concatenate([ps.weights for ps in pointsets]),
    )


#: :func:`~polyslam_env.slam.fit_kernels.sample_into`'s turn argument for a shape without one
NO_TURN = (-1, 0.0)


# -- fitting --------------------------------------------------------------------------------
#: Steepest tangent |dη/dξ| a landmark's shape may have anywhere on its extent: tan 75°. The
#: variate is the points' principal direction
#: (:func:`~polyslam_env.slam.fit_kernels.principal_variate`), so a wall's mean
#: tangent lies within 45° of its ξ axis, and a corner is split before it is fitted; a shape
#: turning further than 75° from the axis is a fit curving away between tight groups of
#: points. Found on a merge of two short arcs of one round pillar: a parabola 0.34 m long on
#: ξ whose curve ran 9 m across the hall and back (slope 116 at its ends).
MAX_SLOPE = float(np.tan(np.radians(75.0)))


def _split(xy: np.ndarray, variate: int) -> tuple[np.ndarray, np.ndarray]:
    """(ξ, η) of points for the given variate."""
    return (xy[:, 0], xy[:, 1]) if variate == 1 else (xy[:, 1], xy[:, 0])


@functools.lru_cache(maxsize=256)
def order_limits(n_points: int, order: int, noise_var: float) -> np.ndarray:  # (1, order)
    """The residual sum of squares below which order m = 1 … ``order`` is accepted (the order
    selection of :func:`fit_polynomial`): the 99 % χ² quantile with N − m − 1 dof times the
    points' noise variance, or, without noise (points sampled on polynomials), N · 1e-8
    (0.1 mm RMS). Orders without a positive dof are never tested against theirs. Cached: a
    SLAM's fits repeat a few sizes and noise levels (merges: 2 ε_M points, σ_range²); the
    array is shared, never written."""
    if noise_var > 0:
        dof = n_points - 1 - np.arange(1, order + 1)
        return np.asarray(scipy.special.chdtri(np.maximum(dof, 1), 0.01) * noise_var)[None, :]
    return np.full((1, order), n_points * 1e-8)


def next_term_limits(order: int, noise_var: float) -> np.ndarray:  # (order,)
    """The drop of the residual sum of squares from order m to m + 1 (m = 1 … ``order``)
    below which the next coefficient is not needed (``SlamConfig.curvature_test``): the 99 %
    χ²(1) quantile times the points' noise variance. With known noise that drop over σ² is
    the next coefficient's z² (its estimate over its standard error, squared), χ²(1) when it
    is zero: a line whose points' order-2 coefficient is significant at 1 % is not kept a
    line even when :func:`order_limits`' test over all N − 2 dof passes it (that test spreads
    its power over every shape of misfit; a short arc's sagitta is one)."""
    return np.full(order, scipy.special.chdtri(1, 0.01) * noise_var)


_NO_LIMITS = np.zeros((0, 0))


def fit_polynomial(
    points: PointSet,
    order: int = 3,
    variate: int | None = None,
    shape_fixed: bool = False,
    auto_order: bool = False,
    min_noise_var: float = 0.0,
    curvature_test: bool = False,
) -> Fit:
    """Weighted LMS polynomial a = (AᵀWA)⁻¹AᵀWη, with ∂c0/∂X and ∂c0/∂noise, in one compiled
    call (:func:`~polyslam_env.slam.fit_kernels.fit_points`).

    The variate is chosen by direction unless given; the extent is [min ξ, max ξ]. With fewer
    distinct ξ than order+1 (or a rank-deficient design) the order is lowered and the missing
    coefficients are zero, so the result always has ``order + 1`` coefficients. Columns are
    scaled by max|ξ| and solved by QR, never by forming (AᵀWA)⁻¹; the fit keeps R
    (:attr:`Fit.r_factor`) so a caller can form the coefficients' covariance. Derivatives of
    c0 = a_0 (M = AᵀWA, r_i the residual, A_i' = d/dξ of row A_i):
    ∂a/∂η_i = M⁻¹A_iᵀ w_i and ∂a/∂ξ_i = M⁻¹[w_i A_i'ᵀ r_i − w_i A_iᵀ (A_i' a)];
    G_x = Σ_i ∂c0/∂π_i ∂π_i/∂X and G_y likewise. The weights are treated as constants.

    ``shape_fixed=True`` differentiates c0 with the shape b held at its fitted value instead
    (same c0: the normal equation of the constant column gives c0 = Σw(η − B(ξ))/Σw), i.e.
    ∂c0/∂η_i = w_i/Σw and ∂c0/∂ξ_i = −w_i B'(ξ_i)/Σw. That matches the SLAM's model, where
    c0 is a rigid offset of a fixed shape; the full derivative also carries the change of
    shape extrapolated to ξ = 0, which is huge for a segment far from the origin.

    ``auto_order=True`` fits the lowest order in 1 … ``order`` whose residuals the point noise
    explains (:func:`order_limits`), with the points' mean noise variance, floored at
    ``min_noise_var``. The paper's m is the *largest* order a segment may take: a cubic through
    a dozen points with 2 cm noise over half a metre of straight wall has slopes that are pure
    noise, and those slopes enter ∂h/∂x and ∂h/∂θ, making the pose look observable where it is
    not (an overconfident filter). Points sampled on polynomials (merges, refits) carry no
    noise of their own, but their polynomials came from noisy ranges, and a 1 cm disagreement
    between two segments of one straight wall must not buy a cubic whose spurious curvature
    then makes the pose look observable.

    ``curvature_test=True`` (with ``auto_order``) also keeps the next order when its one more
    coefficient is significant at 1 % (:func:`next_term_limits`), for points with noise of
    their own only (beam hits: new landmarks and refits), not for points sampled on
    polynomials, whose noise is only the floor ``min_noise_var``, not their scatter.
    """
    n_points = points.n_points
    check_fit_size(n_points, order)
    limits = fit_limits(
        n_points, float(points.noise_cov.trace()), order, auto_order, min_noise_var,
        curvature_test,
    )  # fmt: skip
    result = fit_kernels.fit_points(
        points.xy, points.weights, points.d_state, points.d_noise, order,
        0 if variate is None else variate, shape_fixed, auto_order, limits,
    )  # fmt: skip
    return fit_of(result, points.noise_cov)


def check_fit_size(n_points: int, order: int) -> None:
    """The fits' one-line errors: no points to fit, or no order to fit them with."""
    if n_points == 0:
        raise ValueError("cannot fit a polynomial to zero points")
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order}")


def fit_limits(
    n_points: int,
    noise_trace: float,
    order: int,
    auto_order: bool,
    min_noise_var: float,
    curvature_test: bool,
) -> np.ndarray:
    """The order tests' limits :func:`fit_polynomial` hands its compiled fit for ``n_points``
    points whose noise covariance has trace ``noise_trace``: none without ``auto_order``;
    :func:`order_limits` at their mean noise variance (floored at ``min_noise_var``), and
    with ``curvature_test`` for points with noise of their own :func:`next_term_limits`."""
    if not auto_order:
        return _NO_LIMITS
    noise_var = max(noise_trace / n_points, min_noise_var)
    limits = order_limits(n_points, order, noise_var)
    if curvature_test and noise_trace > 0:
        limits = np.vstack([limits, next_term_limits(order, noise_var)])
    return limits


def fit_of(
    result: tuple[int, int, np.ndarray, float, float, float, np.ndarray, np.ndarray, np.ndarray,
                  float],
    noise_cov: np.ndarray,
) -> Fit:  # fmt: skip
    """The :class:`Fit` of :func:`~polyslam_env.slam.fit_kernels.fit_points`' ``result`` for
    points of noise covariance ``noise_cov``."""
    var, m, coeffs, lo, hi, rms, gx, gy, r, scale = result
    # lo ≤ hi (the points' ξ range) and coeffs a float (order+1,) array: a fit of a known
    # variate with finite numbers needs no more of Polynomial's checks; any other gets them
    # (and their error)
    valid = var in (1, 2) and math.isfinite(lo) and math.isfinite(hi)
    valid = valid and bool(np.isfinite(coeffs).all())
    return Fit(
        poly=Polynomial.unchecked(var, coeffs, lo, hi)
        if valid
        else Polynomial(var, coeffs, lo, hi),
        c0=float(coeffs[0]),
        Gx=gx[None, :],
        Gy=gy[None, :],
        V=noise_cov,
        rms=rms,
        order=m,
        r_factor=r,
        scale=scale,
    )


def turn_gradient(points: PointSet, fit: Fit, pivot: float) -> tuple[np.ndarray, float]:
    """(∂α/∂X (n_state,), residual variance) of the turn α of ``fit``, the LMS fit of
    ``points``, about its point at ξ = ``pivot``.

    ∂α/∂X: how the fitted curve's direction there, atan(p'(ξ_p)), moves when the points move
    as their ``d_state`` says, the weights held (as :func:`fit_polynomial`'s c0 gradient, with
    the full derivative: the shape is what moves). For points sampled on landmarks (a merge)
    this is the merged shape's turn as a linear function of their c0s and turns: two pieces
    of one straight wall far apart fix its direction through their offsets.

    The residual variance is the part no state holds: where the points disagree with the fit
    (pieces that are not quite one curve), an error of the shape of size ``fit.rms`` at each
    point, taken as independent between points: rms² · Σ_i (∂α/∂η_i)², the least-squares
    variance of the turn for that scatter.

    One compiled call (:func:`~polyslam_env.slam.fit_kernels.turn_gradient`); its readable
    numpy form is the oracle in ``tests/slam/reference_fitting.py``, bit for bit."""
    return fit_kernels.turn_gradient(
        points.xy, points.weights, points.d_state, fit.poly.variate, fit.order,
        fit.poly.coeffs, fit.rms, float(pivot), 2.0,
    )  # fmt: skip


def centroid_xi(points: PointSet, variate: int) -> float:
    """ξ of the points' weighted centroid: where a shape-fixed fit's c0 measures the offset
    (its ∂c0/∂η_i are w_i/Σw, so a turn α of the points about ξ_p moves c0 by (ξ̄ − ξ_p)·α)."""
    xi, _ = _split(points.xy, variate)
    return float(points.weights @ xi / points.weights.sum())
