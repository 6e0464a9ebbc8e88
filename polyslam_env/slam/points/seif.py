"""Sparse extended information filter over point landmarks (seed 001, Thrun & Liu, §3).

The posterior over X = [x, y, φ, m_1, …, m_n] is kept in natural parameters: the information
matrix H = Σ⁻¹ and vector b = H μ. One sensor sweep:

1. **motion update** per control period, additive and local: with F the car model's Jacobian
   (identity off the pose) and U = L W Lᵀ the control noise mapped onto the pose,
   H₀ = F⁻ᵀ H F⁻¹ and H' = H₀ − H₀ S (U⁻¹ + Sᵀ H₀ S)⁻¹ Sᵀ H₀ (S selects the pose; this is the
   seed's eq. 7 written with F⁻¹ for its Ψ); the terms are non-zero only in the rows of the
   pose and of the landmarks linked to it (the **active** ones), so the cost does not grow
   with the map. b' = H' μ' with μ' the predicted mean;
2. **measurement update** (eqs. 4–5), additive: H += Cᵀ Q⁻¹ C and b += (z − ẑ + C μ)ᵀ Q⁻¹ C,
   C non-zero on the pose and the observed landmark; a landmark seen for the first time
   enters at the point its first measurement places, with no prior information;
3. **sparsification** (§3.3): when more than ``max_active`` landmarks are linked to the
   pose, the longest-active ones are deactivated — their links to the pose removed — by the
   SEIF approximation that conditions on the passive landmarks' means (Thrun et al. 2004):
   H̃ = H − H⁰S₀(S₀ᵀH⁰S₀)⁻¹S₀ᵀH⁰ + H⁰S_{x0}(S_{x0}ᵀH⁰S_{x0})⁻¹S_{x0}ᵀH⁰ − H S_x(S_xᵀH S_x)⁻¹S_xᵀH,
   b̃ = b + μᵀ(H̃ − H), where H⁰ is H restricted to the pose, the active and the deactivated
   landmarks;
4. **mean recovery**: μ = H⁻¹ b by a Cholesky solve. The seed amortises this with a few
   relaxation sweeps per step (constant time); our maps have a few hundred landmarks, so the
   exact solve is cheap and keeps the linearisation points exact.

With ``max_active = None`` nothing is sparsified and the filter is the exact information form
of the EKF, step for step (tested against an EKF oracle). Data association is by landmark id
(the kinematic world's sensor reports identities), within one map; fusing maps of different
robots (:mod:`polyslam_env.slam.points.seif_fusion`) never uses ids.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.linalg

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.points import models
from polyslam_env.slam.points.config import PointSlamConfig
from polyslam_env.slam.points.interface import LandmarkMap, LandmarkMessage, PointMeasurements

__all__ = ["PointSeif"]


class PointSeif:
    """One robot's SEIF; implements :class:`~polyslam_env.slam.points.interface.PointSlamBackend`.

    ``initial_pose`` is known exactly (the robot's own frame); ``max_active`` bounds the
    landmarks linked to the pose (None: no sparsification, the exact EKF in information form).
    Keep it at least the number of landmarks a sweep sees (~17 in the kinematic world's
    default field): below that, sparsification drops most of each sweep's links and the
    filter grows overconfident (tests/slam/points/test_seif.py).
    """

    def __init__(
        self,
        config: PointSlamConfig,
        initial_pose: np.ndarray,
        max_active: int | None = 20,
        robot_id: int = 0,
    ) -> None:
        if max_active is not None and max_active < 1:
            raise ValueError(f"max_active must be >= 1 or None, got {max_active}")
        self.config = config
        self.max_active = max_active
        self.robot_id = robot_id
        sr, sb = config.measurement_sigmas
        self._Q_inv = np.diag([1.0 / (sr * sr), 1.0 / (sb * sb)])  # (2, 2)
        self.mu = np.asarray(initial_pose, dtype=float).copy()  # (3 + 2n,)
        # the start is known: a large but finite information keeps H invertible
        self.H = np.eye(3) * 1e12  # (3 + 2n, 3 + 2n)
        self.b = self.H @ self.mu
        self.ids: list[int] = []  # landmark ids in state order
        self._slot: dict[int, int] = {}  # id → state index of its x
        self.active: list[int] = []  # state indices of active landmarks, oldest first
        self._factor: tuple[np.ndarray, bool] | None = None  # Cholesky factor of H, or None

    # -- the interface ---------------------------------------------------------------------------
    def step(self, controls: np.ndarray, measurements: PointMeasurements) -> None:
        """One sweep: a motion update per control period, the sweep's measurements,
        sparsification, mean recovery."""
        width = models.control_width(self.config)
        for control in np.asarray(controls, dtype=float).reshape(-1, width):
            self._motion(control)
        self._measure(measurements)
        self._sparsify()
        self._factor = None  # H changed
        self._recover()

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The pose and its marginal covariance, three columns of H⁻¹ (O(n²) with the
        factor of the last mean recovery)."""
        cols = scipy.linalg.cho_solve(self._cholesky(), np.eye(len(self.mu), 3))
        cov = np.asarray(cols[:3])
        return self.mu[:3].copy(), 0.5 * (cov + cov.T)

    def landmarks(self) -> LandmarkMap:
        cov = self.covariance()
        n = len(self.ids)
        covs = np.array([cov[3 + 2 * k : 5 + 2 * k, 3 + 2 * k : 5 + 2 * k] for k in range(n)])
        return LandmarkMap(
            np.array(self.ids, dtype=np.int64),
            self.mu[3:].reshape(n, 2).copy(),
            covs.reshape(n, 2, 2),
        )

    def export_message(self) -> LandmarkMessage:
        return LandmarkMessage(self.robot_id, np.zeros(0, np.int64), np.zeros((0, 2)))

    def import_messages(self, messages: Sequence[LandmarkMessage]) -> None:
        """SEIF robots fuse whole maps (``seif_fusion``), not per-sweep messages."""

    # -- inspection -----------------------------------------------------------------------------
    def covariance(self) -> np.ndarray:
        """Σ = H⁻¹ (3 + 2n, 3 + 2n)."""
        return np.asarray(scipy.linalg.cho_solve(self._cholesky(), np.eye(len(self.mu))))

    def pose_links(self) -> np.ndarray:
        """State indices of the landmarks whose information is linked to the pose."""
        row = np.abs(self.H[:3, 3:]).max(axis=0) if len(self.mu) > 3 else np.zeros(0)
        xs = np.flatnonzero(row[0::2] + row[1::2] > 0)
        return 3 + 2 * xs

    def landmark_information(self) -> tuple[np.ndarray, np.ndarray]:
        """The map's marginal information: the pose eliminated (Schur complement), as
        (H_m (2n, 2n), b_m (2n,)) with H_m μ_m = b_m."""
        hxx, hxm, hmm = self.H[:3, :3], self.H[:3, 3:], self.H[3:, 3:]
        gain = np.linalg.solve(hxx, hxm)  # (3, 2n)
        h_m = hmm - hxm.T @ gain
        h_m = 0.5 * (h_m + h_m.T)
        return h_m, h_m @ self.mu[3:]

    # -- the updates ------------------------------------------------------------------------------
    def _motion(self, control: np.ndarray) -> None:
        new_pose, F, G, W = models.motion(self.mu[:3], control, self.config)
        U = G @ W @ G.T  # (3, 3) control noise on the pose
        idx = np.concatenate([np.arange(3), self._linked_indices()])  # pose + active coords
        F_inv = np.linalg.inv(F)
        H = self.H
        # H₀ = F⁻ᵀ H F⁻¹: only the pose rows and columns change
        H[:3, 3:] = F_inv.T @ H[:3, 3:]
        H[3:, :3] = H[:3, 3:].T
        pose_block = F_inv.T @ H[:3, :3] @ F_inv
        H[:3, :3] = 0.5 * (pose_block + pose_block.T)
        # H' = H₀ − H₀ S (U⁻¹ + Sᵀ H₀ S)⁻¹ Sᵀ H₀ on the rows linked to the pose, with
        # (U⁻¹ + A)⁻¹ = U (I + A U)⁻¹: the car's U = L W Lᵀ has rank 2 (two controls move
        # three pose coordinates), so it has no inverse
        h0s = H[np.ix_(idx, np.arange(3))]  # (k, 3)
        mid = U @ np.linalg.inv(np.eye(3) + H[:3, :3] @ U)
        correction = h0s @ mid @ h0s.T
        H[np.ix_(idx, idx)] -= 0.5 * (correction + correction.T)
        self.mu = self.mu.copy()
        self.mu[:3] = new_pose
        self.b = H @ self.mu

    def _linked_indices(self) -> np.ndarray:
        """State indices (x and y) of the landmarks linked to the pose."""
        xs = self.pose_links()
        return np.sort(np.concatenate([xs, xs + 1])).astype(int)

    def _measure(self, measurements: PointMeasurements) -> None:
        ids, z = measurements.ids, measurements.z
        for lid, zk in zip(ids.tolist(), np.asarray(z, dtype=float), strict=True):
            k = self._slot.get(lid)
            if k is None:
                k = self._add_landmark(lid, zk)
            pose, point = self.mu[:3], self.mu[k : k + 2]
            z_hat, j_pose, j_point = models.observe(pose, point)
            C_idx = np.array([0, 1, 2, k, k + 1])
            C = np.hstack([j_pose, j_point])  # (2, 5)
            innov = zk - z_hat
            innov[1] = float(wrap_angle(innov[1]))
            info = C.T @ self._Q_inv @ C
            self.H[np.ix_(C_idx, C_idx)] += 0.5 * (info + info.T)
            self.b[C_idx] += C.T @ self._Q_inv @ (innov + C @ self.mu[C_idx])
            if k not in self.active:
                self.active.append(k)
            else:  # most recently observed last: the oldest are deactivated first
                self.active.remove(k)
                self.active.append(k)

    def _add_landmark(self, lid: int, z: np.ndarray) -> int:
        point, _ = models.locate(self.mu[:3], z)
        n = len(self.mu)
        H = np.zeros((n + 2, n + 2))
        H[:n, :n] = self.H
        self.H = H
        self.mu = np.concatenate([self.mu, point])
        self.b = np.concatenate([self.b, np.zeros(2)])
        self.ids.append(lid)
        self._slot[lid] = n
        return n

    def _sparsify(self) -> None:
        """Deactivate the oldest active landmarks beyond ``max_active`` (module docstring)."""
        if self.max_active is None:
            return
        linked = [int(k) for k in self.pose_links()]
        self.active = [k for k in self.active if k in linked] + [
            k for k in linked if k not in self.active
        ]
        excess = len(self.active) - self.max_active
        if excess <= 0:
            return
        leaving, staying = self.active[:excess], self.active[excess:]
        pose = [0, 1, 2]
        y0 = [i for k in leaving for i in (k, k + 1)]
        yp = [i for k in staying for i in (k, k + 1)]
        block = pose + yp + y0  # H⁰ lives on these indices
        H, mu = self.H, self.mu
        h0 = H[np.ix_(block, block)]
        npose, nyp = 3, len(yp)
        s0 = list(range(npose + nyp, len(block)))  # Y0 within the block
        sx0 = list(range(npose)) + s0
        sx = list(range(npose))

        def marginal_term(h: np.ndarray, keep: list[int]) -> np.ndarray:
            sub = h[:, keep]
            return np.asarray(sub @ np.linalg.solve(h[np.ix_(keep, keep)], sub.T))

        delta = -marginal_term(h0, s0) + marginal_term(h0, sx0)
        full_x = marginal_term(H[np.ix_(block, block)], sx)
        # the last term −H S_x (S_xᵀ H S_x)⁻¹ S_xᵀ H touches every landmark linked to the
        # pose; after deactivation those are exactly Y+ and Y0, all inside the block
        new_block = H[np.ix_(block, block)] - full_x + delta
        old = H[np.ix_(block, block)].copy()
        new_block = 0.5 * (new_block + new_block.T)
        # the links pose–Y0 are zero in exact arithmetic; rounding leaves ~1e-13 of H
        new_block[:npose, npose + nyp :] = 0.0
        new_block[npose + nyp :, :npose] = 0.0
        H[np.ix_(block, block)] = new_block
        self.b[block] += mu[block] @ (new_block - old)
        self.active = staying

    def _recover(self) -> None:
        self.mu = np.asarray(scipy.linalg.cho_solve(self._cholesky(), self.b))
        self.mu[2] = float(wrap_angle(self.mu[2]))

    def _cholesky(self) -> tuple[np.ndarray, bool]:
        """The Cholesky factor of H, computed once per change of H."""
        if self._factor is None:
            self._factor = scipy.linalg.cho_factor(self.H)
        factor: tuple[np.ndarray, bool] = self._factor
        return factor
