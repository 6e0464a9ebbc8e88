"""Map files: load, validate and list the built-in maps.

Schema (YAML or JSON, metres and radians)::

    name: two_rooms
    walls:             # polylines, each a list of [x, y]; closed if first == last
      - [[0, 0], [6, 0], [6, 4], [0, 4], [0, 0]]
      - [[3, 0], [3, 1.5]]
    pillars:           # optional, [x, y, radius]
      - [1.5, 2.0, 0.1]
    start_poses:       # one [x, y, theta] per robot
      - [0.5, 0.5, 0.0]

Any other top-level key is an error (a misspelt ``start_pose`` must not be silently ignored).
So are a zero-length wall segment (two equal consecutive points), a coordinate or radius
beyond :data:`MAX_COORDINATE` (1,000 m: a typo such as ``40000`` for ``4.0`` would otherwise
build a world the coverage grid cannot hold) and a closed polyline that crosses itself.
Every error names the file and the field, e.g. ``maps/x.yaml: walls[1]: a polyline needs at
least 2 points, got 1``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from polyslam_env.core.errors import MapFileError
from polyslam_env.core.io import parse_yaml
from polyslam_env.core.resources import builtin_names, maps_dir, resolve_file
from polyslam_env.world.layout import Layout

REQUIRED_KEYS = ("walls", "start_poses")
OPTIONAL_KEYS = ("name", "pillars")
#: Largest |coordinate| (and pillar radius) a map may use, in metres.
MAX_COORDINATE = 1000.0
#: Clearance a start pose needs from walls, pillars and other robots' start poses (m).
DEFAULT_START_CLEARANCE = 0.065


def builtin_maps() -> list[str]:
    """Names of the maps shipped in ``configs/maps``."""
    return builtin_names(maps_dir())


def resolve_map_path(name_or_path: str | Path) -> Path:
    """A built-in map name (``"paper"``) or a path to a map file."""
    return resolve_file(name_or_path, maps_dir(), "map", MapFileError)


def load_map(name_or_path: str | Path, *, robot_radius: float = DEFAULT_START_CLEARANCE) -> Layout:
    """Load and validate a map file, or a built-in map by name."""
    path = resolve_map_path(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise MapFileError(f"{path}: cannot read map file ({err})") from None
    try:
        data = parse_yaml(text)  # JSON is a subset of YAML
    except yaml.YAMLError as err:
        raise MapFileError(f"{path}: not valid YAML/JSON: {err}") from None
    return layout_from_dict(
        data, source=str(path), default_name=path.stem, robot_radius=robot_radius
    )


def layout_from_dict(
    data: Any,
    *,
    source: str = "<map>",
    default_name: str = "map",
    robot_radius: float = DEFAULT_START_CLEARANCE,
) -> Layout:
    """Validate plain map data (the file schema) and build a :class:`Layout`."""

    def fail(field: str, msg: str) -> MapFileError:
        return MapFileError(f"{source}: {field}: {msg}")

    if not isinstance(data, dict):
        raise MapFileError(
            f"{source}: the map must be a mapping with keys 'walls' and "
            f"'start_poses', got {type(data).__name__}"
        )
    unknown = sorted(set(map(str, data)) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise fail(unknown[0], "unknown key (valid keys: name, walls, pillars, start_poses)")
    for key in REQUIRED_KEYS:
        if key not in data or data[key] is None:
            raise fail(key, "missing")

    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise fail("name", f"expected a non-empty string, got {name!r}")

    walls_raw = data["walls"]
    if not isinstance(walls_raw, list) or not walls_raw:
        raise fail("walls", "expected a non-empty list of polylines")
    walls = tuple(_points(w, f"walls[{i}]", 2, fail, min_count=2) for i, w in enumerate(walls_raw))
    for i, wall in enumerate(walls):
        _check_polyline(wall, f"walls[{i}]", fail)

    pillars_raw = data.get("pillars") or []
    if not isinstance(pillars_raw, list):
        raise fail("pillars", "expected a list of [x, y, radius]")
    pillars = _points(pillars_raw, "pillars", 3, fail, min_count=0)
    for i, r in enumerate(pillars[:, 2]):
        if r <= 0:
            raise fail(f"pillars[{i}][2]", f"radius must be > 0, got {r}")

    poses_raw = data["start_poses"]
    if not isinstance(poses_raw, list) or not poses_raw:
        raise fail("start_poses", "expected a non-empty list of [x, y, theta]")
    poses = _points(poses_raw, "start_poses", 3, fail, min_count=1)

    layout = Layout(name=name, walls=walls, pillars=pillars, start_poses=poses)
    if len(layout.segments) == 0:
        raise fail("walls", "all polylines have zero length")
    _check_start_poses(layout, robot_radius, fail)
    return layout


def layout_to_dict(layout: Layout) -> dict[str, Any]:
    """The file-schema data of a layout (what :func:`save_map` writes)."""
    out: dict[str, Any] = {
        "name": layout.name,
        "walls": [[[float(x), float(y)] for x, y in w] for w in layout.walls],
    }
    if len(layout.pillars):
        out["pillars"] = [[float(v) for v in p] for p in layout.pillars]
    out["start_poses"] = [[float(v) for v in p] for p in layout.start_poses]
    return out


def map_text(layout: Layout) -> str:
    """A layout as the text of a map file in the documented schema (YAML)."""
    return yaml.safe_dump(layout_to_dict(layout), default_flow_style=None, sort_keys=False)


def save_map(layout: Layout, path: str | Path) -> None:
    """Write a layout as a map file in the documented schema."""
    Path(path).write_text(map_text(layout), encoding="utf-8")


def _points(raw: Any, field: str, dim: int, fail: Any, *, min_count: int) -> np.ndarray:
    if not isinstance(raw, list):
        raise fail(field, f"expected a list of [{', '.join('xyz'[:dim])}...], got {raw!r}")
    if len(raw) < min_count:
        what = "a polyline needs at least 2 points" if dim == 2 else f"needs {min_count}"
        raise fail(field, f"{what}, got {len(raw)}")
    out = np.zeros((len(raw), dim))
    for i, item in enumerate(raw):
        if not isinstance(item, list | tuple) or len(item) != dim:
            raise fail(f"{field}[{i}]", f"expected {dim} numbers, got {item!r}")
        for j, v in enumerate(item):
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise fail(f"{field}[{i}][{j}]", f"expected a number, got {v!r}")
            if not math.isfinite(v):
                raise fail(f"{field}[{i}][{j}]", f"must be finite, got {v!r}")
            if abs(v) > MAX_COORDINATE and not (dim == 3 and j == 2 and field == "start_poses"):
                raise fail(
                    f"{field}[{i}][{j}]",
                    f"{v!r} is beyond the limit of ±{MAX_COORDINATE:g} m",
                )
            out[i, j] = float(v)
    return out


def _check_polyline(wall: np.ndarray, field: str, fail: Any) -> None:
    """No zero-length segment; a closed polyline (first == last) must not cross itself."""
    steps = np.hypot(*np.diff(wall, axis=0).T)  # (k-1,)
    for j in np.flatnonzero(steps == 0):
        raise fail(
            f"{field}[{j + 1}]",
            f"zero-length segment: ({wall[j, 0]:g}, {wall[j, 1]:g}) repeats the point before",
        )
    if len(wall) >= 4 and np.array_equal(wall[0], wall[-1]):
        crossing = _self_crossing(wall)
        if crossing is not None:
            a, b = crossing
            raise fail(
                field,
                f"the closed polyline crosses itself (segment {a} [{a}]→[{a + 1}] and"
                f" segment {b} [{b}]→[{b + 1}])",
            )


def _self_crossing(ring: np.ndarray) -> tuple[int, int] | None:
    """The first pair of non-adjacent segments of the closed polyline ``ring`` (k, 2) that
    touch or cross, or None. Vectorised per segment: O(k²) work, O(k) Python steps."""
    p, q = ring[:-1], ring[1:]  # (m, 2) segment starts and ends
    m = len(p)
    d = q - p  # (m, 2)

    def cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
        return ax * by - ay * bx

    for i in range(m - 2):
        js = np.arange(i + 2, m if i > 0 else m - 1)  # skip neighbours; 0 and m-1 share a point
        if len(js) == 0:
            continue
        o1 = cross(d[i, 0], d[i, 1], p[js, 0] - p[i, 0], p[js, 1] - p[i, 1])
        o2 = cross(d[i, 0], d[i, 1], q[js, 0] - p[i, 0], q[js, 1] - p[i, 1])
        o3 = cross(d[js, 0], d[js, 1], p[i, 0] - p[js, 0], p[i, 1] - p[js, 1])
        o4 = cross(d[js, 0], d[js, 1], q[i, 0] - p[js, 0], q[i, 1] - p[js, 1])
        hit = (o1 * o2 <= 0) & (o3 * o4 <= 0)
        # collinear pairs pass the sign test without overlapping: require overlapping boxes
        lo_i, hi_i = np.minimum(p[i], q[i]), np.maximum(p[i], q[i])
        lo_j, hi_j = np.minimum(p[js], q[js]), np.maximum(p[js], q[js])
        hit &= np.all((lo_j <= hi_i) & (lo_i <= hi_j), axis=1)
        if np.any(hit):
            return i, int(js[np.argmax(hit)])
    return None


def _check_start_poses(layout: Layout, radius: float, fail: Any) -> None:
    poses = layout.start_poses
    inside = layout.contains(poses[:, :2])
    clearance = layout.clearance(poses[:, :2])
    for i, (x, y, _) in enumerate(poses):
        if not inside[i]:
            raise fail(f"start_poses[{i}]", f"({x:g}, {y:g}) is outside the map")
        if clearance[i] < radius:
            raise fail(
                f"start_poses[{i}]",
                f"({x:g}, {y:g}) is inside or too close to a wall or pillar"
                f" ({clearance[i]:.3f} m < robot radius {radius:g} m)",
            )
    for i in range(len(poses)):
        for j in range(i):
            d = math.hypot(poses[i, 0] - poses[j, 0], poses[i, 1] - poses[j, 1])
            if d < 2 * radius:
                raise fail(
                    f"start_poses[{i}]",
                    f"overlaps start_poses[{j}] ({d:.3f} m apart < 2 × radius {radius:g} m)",
                )
