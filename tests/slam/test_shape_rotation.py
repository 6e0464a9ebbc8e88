"""Shape rotations as considered states (``SlamConfig.shape_rotation = "considered"``).

A landmark's frozen shape is turned from the true wall by the heading error it was fitted
with (plus its slope's fit error). The filter carries that angle α per landmark as a state it
never estimates (Schmidt–Kalman): the tests check its Jacobian against finite differences of
the predicted range, the clone that creates it, and the state's layout and its covariance
through a SLAM run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.optimize

from polyslam_env.slam import kernels
from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.fitting import Fit
from polyslam_env.slam.landmarks import LandmarkTable
from polyslam_env.slam.maintenance import fit_inverse_table as _fit_inverse_table
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from tests.slam.finite_differences import FD_RTOL, fd_jacobian
from tests.slam.test_ekf import assert_symmetric_psd, random_spd

#: One wall per case: a line and a cubic, each in both variates, seen from a pose that hits
#: them away from their centroid (so the lever is not zero).
WALLS = [
    Polynomial(1, np.array([1.5, 0.2]), -2.0, 2.0),
    Polynomial(2, np.array([-1.2, -0.3]), -1.5, 2.5),
    Polynomial(1, np.array([1.8, 0.1, 0.05, -0.02]), -2.0, 2.0),
    Polynomial(2, np.array([1.6, -0.15, 0.04, 0.01]), -2.0, 2.5),
]


def _range_to_turned(
    poly: Polynomial, angle: float, pivot: float, origin: np.ndarray, phi: float, xi0: float
) -> float:
    """Distance along the ray (origin, phi) to ``poly`` turned counter-clockwise by ``angle``
    about its point at ξ = ``pivot``: the curve's parameter where the ray crosses it, by a
    bracketed root search around ``xi0``, not by any formula of the code under test."""
    centre = poly.points_at(np.array([pivot]))[0]
    c, s = math.cos(angle), math.sin(angle)
    d = np.array([math.cos(phi), math.sin(phi)])

    def point(xi: float) -> np.ndarray:
        p = poly.points_at(np.array([xi]))[0] - centre
        return centre + np.array([c * p[0] - s * p[1], s * p[0] + c * p[1]])

    def cross(xi: float) -> float:
        v = point(xi) - origin
        return float(v[0] * d[1] - v[1] * d[0])

    xi = scipy.optimize.brentq(cross, xi0 - 0.3, xi0 + 0.3, xtol=1e-15, rtol=1e-15)
    return float((point(xi) - origin) @ d)


@pytest.mark.parametrize("wall", range(len(WALLS)))
def test_range_jacobian_in_the_shape_rotation__matches_finite_differences(wall: int) -> None:
    """∂h/∂α of every beam that hits the wall equals the central difference of the range to
    the wall turned by ±ε about its centroid: ε = 1e-6 rad leaves a truncation error of
    O(ε²·h''') and a rounding error of O(1e-16/ε) ≈ 1e-10 m per radian, far below 1e-6."""
    poly = WALLS[wall]
    table = LandmarkTable()
    pivot = 0.5 * (poly.lo + poly.hi)
    table.append(poly, pivot=pivot, xi_var=0.0, model_var=0.0, fit_half=2.0)
    x, y, theta = -0.3, 0.2, 0.4
    angles = np.linspace(-1.4, 1.4, 15) + (0.0 if poly.variate == 1 else -1.2)
    origin = np.array([x, y])
    eps = 1e-6
    checked = 0
    for beam in range(angles.size):  # one beam per call: its row is then known to be its own
        rows = (
            np.empty(1), np.empty((1, 3)), np.empty(1, dtype=np.int64), np.empty(1),
            np.empty(1, dtype=np.int64), np.empty(1), np.empty(1), np.empty(1), np.empty((1, 4)),
        )  # fmt: skip
        used = kernels.beam_rows(
            x, y, theta, angles, np.zeros(angles.size), np.array([beam]), math.inf,
            *table.arrays(), np.array([poly.c0]), table.boxes(np.array([poly.c0])), 10.0, 0.17,
            4e-4, table.model_var, True, False, table.pivot, table.xi_var, np.zeros(2),
            table.shift_slope,
            np.zeros(1),
            table.fit_half, _fit_inverse_table(16, 3), 16, 4, *rows,
        )  # fmt: skip
        if not used:
            continue
        innovation, _, _, _, alpha_index, h_alpha, *_ = rows
        h = -float(innovation[0])  # the reading was 0
        phi = theta + float(angles[beam])
        xi0 = _xi_of(poly, origin + h * np.array([math.cos(phi), math.sin(phi)]))
        assert _range_to_turned(poly, 0.0, pivot, origin, phi, xi0) == pytest.approx(h, abs=1e-9)
        plus = _range_to_turned(poly, eps, pivot, origin, phi, xi0)
        minus = _range_to_turned(poly, -eps, pivot, origin, phi, xi0)
        assert alpha_index[0] == 4  # α_1 sits after [pose, c0_1]
        np.testing.assert_allclose(h_alpha[0], (plus - minus) / (2 * eps), rtol=1e-6, atol=1e-8)
        checked += 1
    assert checked >= 2, "the pose must see the wall with several beams"


def _xi_of(poly: Polynomial, point: np.ndarray) -> float:
    return float(point[0] if poly.variate == 1 else point[1])


def _fit(poly: Polynomial, n_state: int) -> Fit:
    return Fit(poly, poly.c0, np.zeros((1, n_state)), np.zeros((1, 0)), np.zeros((0, 0)), 0.0, 1)


def test_new_landmark__its_rotation_is_a_clone_of_the_heading_plus_the_fit_variance() -> None:
    """Inserting landmarks keeps the layout [pose, c0 × n, α × n]; a new α's row is the
    heading's (cross-covariances with the pose and every earlier entry), its variance the
    heading's plus the slope's fit variance σ²·M⁻¹[1, 1]/h² / (1 + b'²)², its mean 0."""
    rng = np.random.default_rng(0)
    config = SlamConfig()
    assert config.shape_rotation == "considered"
    slam = PolySlam(config, np.linspace(-1.5, 1.5, 9), 4.0)
    slam.mean = rng.normal(size=3)
    slam.cov = random_spd(rng, 3, 0.01)
    for n, poly in enumerate(WALLS[:3]):
        before = slam.cov.copy()
        slam.insert_landmark(_fit(poly, slam.mean.size), merge=False)
        n += 1
        assert slam.mean.shape == (3 + 2 * n,)
        alpha = 3 + 2 * n - 1  # the newest α is last
        heading = slam.cov[2].copy()
        np.testing.assert_array_equal(slam.cov[alpha, :3], heading[:3])
        np.testing.assert_array_equal(slam.cov[alpha, 3 : 3 + n - 1], heading[3 : 3 + n - 1])
        np.testing.assert_array_equal(slam.cov[alpha, 3 + n : alpha], heading[3 + n : alpha])
        half = 0.5 * (poly.hi - poly.lo)
        centre = 0.5 * (poly.lo + poly.hi)
        slope = float(poly.slope(centre))
        order = int(np.flatnonzero(poly.coeffs[1:]).max()) + 1
        inverse = _fit_inverse_table(config.eps_z + 1, config.order)[order]
        fit_var = config.range_sigma**2 * inverse[1, 1] / half**2 / (1 + slope**2) ** 2
        assert slam.cov[alpha, alpha] == pytest.approx(heading[2] + fit_var, rel=1e-12)
        assert slam.mean[alpha] == 0.0
        # what was there stays (the old α's moved one index on, past the new c0)
        np.testing.assert_array_equal(slam.cov[:3, :3], before[:3, :3])
        assert_symmetric_psd(slam.cov)
    slam.remove_landmark(slam.landmark_ids[1])
    assert slam.mean.shape == (3 + 2 * 2,)


def test_heading_rotation_mode__keeps_the_old_layout() -> None:
    """``shape_rotation="heading"`` (the paper preset's) adds no state: [pose, c0 × n]."""
    slam = PolySlam(SlamConfig(shape_rotation="heading"), np.linspace(-1.5, 1.5, 9), 4.0)
    slam.insert_landmark(_fit(WALLS[0], 3), merge=False)
    assert slam.mean.shape == (4,)


def test_shape_rotation__bad_value_names_the_field() -> None:
    from polyslam_env.core.errors import ConfigError

    with pytest.raises(ConfigError, match="slam.shape_rotation"):
        SlamConfig(shape_rotation="estimated")
    with pytest.raises(ConfigError, match="slam.merge_turn"):
        SlamConfig(merge_turn="mean")


def _two_pieces(config: SlamConfig) -> tuple[PolySlam, np.ndarray]:
    """A SLAM whose map is two pieces of one straight wall end to end (2 m and 1 m, a 10 cm
    gap), their c0s and turns correlated with the pose and each other as a run would make
    them; and its covariance before they merge."""
    rng = np.random.default_rng(3)
    slam = PolySlam(config, np.linspace(-1.5, 1.5, 9), 4.0)
    slam.mean = np.zeros(3)
    slam.cov = random_spd(rng, 3, 1e-4)
    a = Polynomial(1, np.array([1.0, 0.0]), 0.0, 2.0)
    b = Polynomial(1, np.array([1.0, 0.0]), 2.1, 3.1)
    slam.insert_landmark(_fit(a, 3), merge=False)
    slam.insert_landmark(_fit(b, slam.mean.size), merge=False)
    slam.cov[3:, 3:] += 1e-6 * np.eye(4)
    assert_symmetric_psd(slam.cov)
    return slam, slam.cov.copy()


def test_merged_landmark__with_weights_its_rotation_is_the_length_weighted_mean_of_the_parts() -> (
    None
):
    """``merge_turn="weights"`` (an option): the merged turn is w·α_a + (1 − w)·α_b with
    w = L_a³/(L_a³ + L_b³): its covariance row is that combination of the parts' rows (taken
    before the merge), and the layout stays [pose, c0 × n, α × n]."""
    config = SlamConfig(merge_turn="weights")
    slam, before = _two_pieces(config)
    assert slam.maintenance.merge_once(slam.landmark_ids[1]) is not None and slam.n_landmarks == 1
    w_a = 2.0**3 / (2.0**3 + 1.0**3)  # the 2 m piece weighs 8/9, the 1 m one 1/9
    weights = np.array([w_a, 1.0 - w_a])  # over (α_a, α_b): state 5, 6 before
    assert slam.mean.shape == (5,)  # [pose, c0, α]
    np.testing.assert_allclose(slam.cov[4, :3], weights @ before[5:7, :3], rtol=1e-9, atol=1e-15)
    own = before[5:7, 5:7]
    assert slam.cov[4, 4] == pytest.approx(weights @ own @ weights, rel=1e-9)
    assert_symmetric_psd(slam.cov)


def test_merged_landmark__its_rotation_is_the_merged_fits_direction() -> None:
    """``merge_turn="fit"`` (the default): the merged turn is the direction of the line fitted
    through both pieces, so it depends on their offsets as well as their turns. The oracle:
    a weighted ``np.polyfit`` through ε_M points on each piece, each piece moved by its c0
    and turned by its α about its pivot, differentiated numerically over (c0_a, c0_b, α_a,
    α_b); the merged α's covariance row is that gradient times the parts' rows."""
    config = SlamConfig(merge_turn="fit")
    slam, before = _two_pieces(config)
    pieces = [(0.0, 2.0, 1.0, before[3, 3]), (2.1, 3.1, 2.6, before[4, 4])]  # lo, hi, pivot, var

    def direction(x: np.ndarray) -> float:  # x = (c0_a, c0_b, α_a, α_b)
        xs, ys, ws = [], [], []
        for k, (lo, hi, pivot, var) in enumerate(pieces):
            px = np.linspace(lo, hi, config.eps_m)
            c, s = math.cos(x[2 + k]), math.sin(x[2 + k])
            dx, dy = px - pivot, np.zeros_like(px)
            xs.append(pivot + c * dx - s * dy)
            ys.append(1.0 + x[k] + s * dx + c * dy)
            ws.append(np.full(len(px), 1.0 / math.sqrt(var)))  # polyfit weighs residuals
        slope = np.polyfit(np.concatenate(xs), np.concatenate(ys), 1, w=np.concatenate(ws))[0]
        return math.atan(slope)

    # central differences: FD_STEP and FD_RTOL's stated truncation and round-off margins
    g = fd_jacobian(direction, np.zeros(4))
    assert slam.maintenance.merge_once(slam.landmark_ids[1]) is not None and slam.n_landmarks == 1
    assert slam.mean.shape == (5,)
    np.testing.assert_allclose(slam.cov[4, :3], g @ before[3:7, :3], rtol=FD_RTOL, atol=1e-15)
    assert slam.cov[4, 4] == pytest.approx(g @ before[3:7, 3:7] @ g, rel=FD_RTOL)
    # 1 cm between the pieces' offsets turns a wall ~2.6 m between their centres by ~1/260
    assert g[1] > 0.3 and g[0] < -0.3
    assert_symmetric_psd(slam.cov)


def test_merged_landmark__turns_about_the_weighted_centroid_of_its_points() -> None:
    """A merge fits ε_M points on each piece weighted 1/var(c0): its c0 is their weighted
    mean offset, so its pivot (what α turns it about, ``kernels.beam_rows``' lever) is their
    weighted centroid, here pulled towards the certain piece, not the middle of the extent."""
    slam = PolySlam(SlamConfig(), np.linspace(-1.5, 1.5, 9), 4.0)
    slam.mean = np.zeros(3)
    slam.cov = np.diag([1e-4, 1e-4, 1e-5])
    a = Polynomial(1, np.array([1.0, 0.0]), 0.0, 2.0)
    b = Polynomial(1, np.array([1.0, 0.0]), 2.1, 3.1)
    slam.insert_landmark(_fit(a, 3), merge=False)
    slam.insert_landmark(_fit(b, slam.mean.size), merge=False)
    slam.cov[3, 3] += 1e-6  # a: certain
    slam.cov[4, 4] += 1e-3  # b: vague
    w_a, w_b = 1.0 / slam.cov[3, 3], 1.0 / slam.cov[4, 4]
    assert slam.maintenance.merge_once(slam.landmark_ids[1]) is not None and slam.n_landmarks == 1
    expected = (w_a * 1.0 + w_b * 2.6) / (w_a + w_b)  # each piece's points centre on its middle
    assert slam.table.pivot[0] == pytest.approx(expected, rel=1e-9)
    assert slam.table.pivot[0] < 0.5 * (0.0 + 3.1) - 0.3


def test_received_landmark__its_rotation_is_the_given_turn_not_the_heading() -> None:
    """A received wall is turned by the frame transform: ``insert_landmark(..., turn=(g, v))``
    gives α the row g·P[:3] (its dependence on the receiver's pose) and the variance
    g P g + v plus the shape's fit variance, instead of the heading's clone."""
    rng = np.random.default_rng(4)
    slam = PolySlam(SlamConfig(), np.linspace(-1.5, 1.5, 9), 4.0)
    slam.mean = rng.normal(size=3)
    slam.cov = random_spd(rng, 3, 0.01)
    g, v = np.array([0.1, -0.2, 1.0]), 3e-4
    poly = WALLS[0]
    slam.insert_landmark(_fit(poly, 3), merge=False, turn=(g, v))
    np.testing.assert_allclose(slam.cov[4, :3], g @ slam.cov[:3, :3], rtol=1e-12)
    fit_var = slam.maintenance.rotation_fit_var(poly)
    assert slam.cov[4, 4] == pytest.approx(g @ slam.cov[:3, :3] @ g + v + fit_var, rel=1e-12)
    assert_symmetric_psd(slam.cov)
