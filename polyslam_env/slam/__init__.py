"""Polynomial-landmark EKF SLAM, one instance per robot (SPEC §3).

It owns the estimator and nothing else: ``robot`` (``PolySlam``, the stateful shell of one
robot), ``ekf`` (prediction, gated Joseph update, augmentation, removal), ``measurement`` and
``beamcast`` (the range model and its Jacobians), ``association`` (good / Q_bad / cluster),
``fitting`` (weighted LMS fits with G_x, G_y), ``merging``, ``landmarks`` (the landmark table),
``polynomial`` (the polynomial segment) and ``config`` (``SlamConfig``, the paper's §4
parameters). numpy/scipy and ``core`` only: usable and testable without the world or the env.
"""
