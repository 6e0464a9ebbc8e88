"""World step against the number of robots, next to bare pymunk: ``polyslam benchmark --only
world``.

    python scripts/bench_world.py [--quick] [--json PATH]
"""

import sys

from polyslam_env.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["benchmark", "--only", "world", *sys.argv[1:]]))
