"""``python -m polyslam_env.cli``: the ``polyslam`` command."""

import sys

from polyslam_env.cli.main import main

sys.exit(main())
