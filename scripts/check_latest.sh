#!/usr/bin/env bash
# The suite against the newest releases pyproject.toml allows (CI pins .ci/constraints.txt),
# in a fresh virtual environment; says which packages moved and whether the golden episodes
# still hold. Usage: scripts/check_latest.sh [VENV_DIR]   (default /tmp/polyslam-latest)
# Exit 0 only if the goldens hold and the whole suite passes. docs/notes/tests.md.
set -uo pipefail
cd "$(dirname "$0")/.."
venv=${1:-/tmp/polyslam-latest}
export SDL_VIDEODRIVER=dummy MPLBACKEND=Agg PIP_DISABLE_PIP_VERSION_CHECK=1 HYPOTHESIS_PROFILE=ci

python -m venv --clear "$venv" || exit 2
# shellcheck disable=SC1091
. "$venv/bin/activate"
pip install -q torch==2.13.0 &&
    pip install -q --upgrade --upgrade-strategy eager -e ".[dev,rl,video,ray,bench]" || exit 2

echo "== packages newer than .ci/constraints.txt"
python - <<'EOF'
from importlib import metadata
from pathlib import Path

from packaging.utils import canonicalize_name

moved = []
for line in Path(".ci/constraints.txt").read_text().splitlines():
    if not line or line.startswith("#"):
        continue
    name, pinned = line.split("==")
    try:
        now = metadata.version(name).split("+")[0]
    except metadata.PackageNotFoundError:
        now = "(not installed)"
    if now != pinned:
        moved.append(f"  {canonicalize_name(name)}: {pinned} -> {now}")
print("\n".join(moved) if moved else "  none: the newest releases are the pinned ones")
EOF

echo "== golden episodes (tests/test_golden.py)"
if python -m pytest -q -p no:cacheprovider tests/test_golden.py; then
    golden="HOLD"
else
    golden="DIFFER"
fi
echo "== the whole suite"
python -m pytest -n 2 -q -p no:cacheprovider
suite=$?
echo "goldens with the newest releases: $golden"
echo "suite with the newest releases: $([ "$suite" -eq 0 ] && echo passed || echo FAILED)"
[ "$golden" = HOLD ] && [ "$suite" -eq 0 ]
