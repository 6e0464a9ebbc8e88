"""The PettingZoo environment ``polyslam_v0`` and its wrappers.

It owns: the parallel env and its constructors (``parallel``; ``polyslam_env.parallel_env`` and
``polyslam_env.env``), its config (``config``: ``EnvConfig`` nests the world, SLAM, channel and
reward configs), the on-board observations (``observations``), the facts a policy may know
(``facts``), the Gymnasium team env and its registration (``team``) and the SuperSuit/SB3
vectorised adapter (``vector``). It wires ``world``, ``slam``, ``comms`` and ``metrics``
together; it never imports ``apps``, ``cli`` or ``policies``.
"""
