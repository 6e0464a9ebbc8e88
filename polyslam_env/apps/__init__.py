"""What the ``polyslam`` command runs, written as library functions the CLI calls.

It owns: ``simulate`` (scripted robots with SLAM, no RL env, through the env's own stages),
``rollout`` (episodes with a team policy: ``run`` and ``evaluate``), ``training`` (PPO with
shared parameters), ``reproduce`` (the paper's Table 1 and figures), ``reproduce_mblcc`` (seed
003's Table 1 and Fig 5 on the kinematic world) and ``benchmark``. Apps may
import every part and ``policies``; nothing in the library imports apps.
"""
