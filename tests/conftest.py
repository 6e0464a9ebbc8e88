"""Suite-wide settings: Hypothesis profiles.

``HYPOTHESIS_PROFILE=ci`` (set by ``.ci/run``) derandomises Hypothesis: every CI run draws the
same examples (seeded from each test's name), so a red CI is reproducible and a green one is
not luck of the draw. Without it (the ``dev`` default) each run draws new examples, and a
failure is saved in the local example database and replayed first next time. The tests' own
``@settings(max_examples=…, deadline=…)`` apply on top of either profile.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("dev")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))
