"""Env steps per second (full SLAM, no SLAM, MPE reference): ``polyslam benchmark --only
reference env``.

    python scripts/bench_env.py [--quick] [--json PATH]
"""

import sys

from polyslam_env.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", "--only", "reference", "env", *sys.argv[1:]]))
