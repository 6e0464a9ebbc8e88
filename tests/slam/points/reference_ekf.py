"""A textbook EKF over point landmarks: the oracle the SEIF must equal without sparsification.

Same car and range-bearing models (``slam.points.models``), dense covariance, prediction per
control period, one batched update per sweep linearised at the predicted mean. A landmark
seen for the first time enters at the point its measurement places, with that measurement's
exact linearised covariance (the information form's "no prior information"), and that
measurement is not used again in the update.
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.points import models
from polyslam_env.slam.points.config import PointSlamConfig
from polyslam_env.slam.points.interface import PointMeasurements


class PointEkf:
    def __init__(self, config: PointSlamConfig, initial_pose: np.ndarray) -> None:
        self.config = config
        self.mu = np.asarray(initial_pose, dtype=float).copy()
        self.P = np.zeros((3, 3))  # the start is known, as the SEIF's
        self.slot: dict[int, int] = {}
        sv, sg = config.control_sigmas
        self.W = np.diag([sv * sv, sg * sg])
        sr, sb = config.measurement_sigmas
        self.Q = np.diag([sr * sr, sb * sb])

    def step(self, controls: np.ndarray, meas: PointMeasurements) -> None:
        cfg = self.config
        for v, g in np.asarray(controls, dtype=float).reshape(-1, 2):
            pose, F, G = models.move(self.mu[:3], float(v), float(g), cfg.dt, cfg.wheelbase)
            Fx = np.eye(len(self.mu))
            Fx[:3, :3] = F
            self.P = Fx @ self.P @ Fx.T
            self.P[:3, :3] += G @ self.W @ G.T
            self.mu[:3] = pose
        fresh = set()
        for lid, z in zip(meas.ids.tolist(), meas.z, strict=True):
            if lid not in self.slot:
                self._augment(z)
                self.slot[lid] = len(self.mu) - 2
                fresh.add(lid)
        rows, innovs = [], []
        for lid, z in zip(meas.ids.tolist(), meas.z, strict=True):
            if lid in fresh:  # its measurement placed it (``_augment``)
                continue
            k = self.slot[lid]
            z_hat, jp, jm = models.observe(self.mu[:3], self.mu[k : k + 2])
            C = np.zeros((2, len(self.mu)))
            C[:, :3], C[:, k : k + 2] = jp, jm
            v = z - z_hat
            v[1] = float(wrap_angle(v[1]))
            rows.append(C)
            innovs.append(v)
        if not rows:
            return
        C = np.vstack(rows)
        R = np.kron(np.eye(len(rows)), self.Q)
        S = C @ self.P @ C.T + R
        K = np.linalg.solve(S, C @ self.P).T
        self.mu = self.mu + K @ np.concatenate(innovs)
        self.mu[2] = float(wrap_angle(self.mu[2]))
        I_KC = np.eye(len(self.mu)) - K @ C
        self.P = I_KC @ self.P @ I_KC.T + K @ R @ K.T

    def _augment(self, z: np.ndarray) -> None:
        """Add the landmark measurement z places, with its exact linearised covariance:
        m = locate(x, z), P_mm = G_x P_xx G_xᵀ + G_z Q G_zᵀ, P_m· = G_x P_x·."""
        point, g_z = models.locate(self.mu[:3], z)
        angle = self.mu[2] + z[1]
        g_x = np.array([[1.0, 0.0, -z[0] * np.sin(angle)], [0.0, 1.0, z[0] * np.cos(angle)]])
        n = len(self.mu)
        cross = g_x @ self.P[:3, :]  # (2, n)
        P = np.zeros((n + 2, n + 2))
        P[:n, :n] = self.P
        P[n:, :n] = cross
        P[:n, n:] = cross.T
        P[n:, n:] = g_x @ self.P[:3, :3] @ g_x.T + g_z @ self.Q @ g_z.T
        self.mu = np.concatenate([self.mu, point])
        self.P = P
