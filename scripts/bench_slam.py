"""SLAM step against the number of landmarks: ``polyslam benchmark --only slam``.

python scripts/bench_slam.py [--quick] [--json PATH]
"""

import sys

from polyslam_env.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", "--only", "slam", *sys.argv[1:]]))
