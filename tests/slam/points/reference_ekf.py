"""A textbook EKF over point landmarks: the oracle the SEIF must equal without sparsification.

Same car and range-bearing models (``slam.points.models``), dense covariance, prediction per
control period, one batched update per sweep linearised at the predicted mean. A landmark
seen for the first time enters at the point its measurement places with a prior of
``NEW_VARIANCE`` (the information form's "no prior information", up to ~1e-10 relative).
"""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.points import models
from polyslam_env.slam.points.config import PointSlamConfig
from polyslam_env.slam.points.interface import PointMeasurements

NEW_VARIANCE = 1e10
START_VARIANCE = 1e-12


class PointEkf:
    def __init__(self, config: PointSlamConfig, initial_pose: np.ndarray) -> None:
        self.config = config
        self.mu = np.asarray(initial_pose, dtype=float).copy()
        self.P = np.eye(3) * START_VARIANCE
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
        for lid, z in zip(meas.ids.tolist(), meas.z, strict=True):
            if lid not in self.slot:
                point, _ = models.locate(self.mu[:3], z)
                n = len(self.mu)
                self.mu = np.concatenate([self.mu, point])
                P = np.zeros((n + 2, n + 2))
                P[:n, :n] = self.P
                P[n:, n:] = np.eye(2) * NEW_VARIANCE
                self.P = P
                self.slot[lid] = n
        rows, innovs = [], []
        for lid, z in zip(meas.ids.tolist(), meas.z, strict=True):
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
