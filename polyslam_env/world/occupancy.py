"""Occupancy maps in the ROS ``map_server`` format: a YAML file and its image.

The YAML (``map_server``, ROS 1 and ROS 2 ``nav2_map_server`` alike)::

    image: office.pgm          # PGM or PNG (any image Pillow reads), relative to the YAML
    resolution: 0.05           # m per pixel
    origin: [-10.0, -5.0, 0.0] # pose (x, y, yaw) of the lower-left pixel's lower-left corner
    occupied_thresh: 0.65
    free_thresh: 0.196
    negate: 0
    mode: trinary              # optional: trinary (default), scale or raw

How a pixel becomes a cell, as ``nav2_map_server``'s ``loadMapFromFile`` does it: its shade
s ∈ [0, 1] is the mean of its colour channels (grey counts three times; in ``trinary`` mode an
alpha channel is averaged in as one more channel, 1 = opaque); its occupancy is p = 1 − s
(``negate``: p = s). Then

* ``trinary``: occupied when p > occupied_thresh, free when p < free_thresh, else unknown;
* ``scale``: unknown when the pixel is not opaque, else as ``trinary`` (a value between the
  thresholds is a partial occupancy, which counts as not free here);
* ``raw``: the value round(255·s) is the occupancy in percent (0–100, above is unknown); free
  when it is below 100·free_thresh.

The image's first row is the top of the map (largest y); :class:`OccupancyGrid` stores rows
bottom-up (rows grow with y, like :class:`~polyslam_env.world.grid.FreeGrid`). A yaw in the
origin turns the map counter-clockwise about the origin (:meth:`OccupancyGrid.to_world`;
many ROS tools ignore it, the format defines it).

Every problem with the files is a :class:`~polyslam_env.core.errors.MapFileError` in one
line naming the file and the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from polyslam_env.core.errors import MapFileError
from polyslam_env.core.io import parse_yaml

__all__ = ["FREE", "MODES", "OCCUPIED", "UNKNOWN", "OccupancyGrid", "read_map_yaml"]

#: Cell values, as in a ROS ``nav_msgs/OccupancyGrid``.
FREE, OCCUPIED, UNKNOWN = 0, 100, -1
MODES = ("trinary", "scale", "raw")
_REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate")


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """Cells of a map: ``cells`` (H, W) int8 of :data:`FREE`, :data:`OCCUPIED`,
    :data:`UNKNOWN` (rows grow with y), cell (row, col) covering ``[col·res, (col+1)·res) ×
    [row·res, (row+1)·res)`` in the map frame, which ``origin`` (x, y, yaw) places in the
    world."""

    cells: np.ndarray  # (H, W) int8
    resolution: float  # m per cell
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    source: str = "<grid>"

    @property
    def free(self) -> np.ndarray:  # (H, W) bool
        return np.asarray(self.cells == FREE)

    def to_world(self, points: np.ndarray) -> np.ndarray:  # (…, 2)
        """Map-frame points (m from the lower-left corner) to the world: turned by the
        origin's yaw, then moved to its (x, y)."""
        x0, y0, yaw = self.origin
        c, s = math.cos(yaw), math.sin(yaw)
        p = np.asarray(points, dtype=float)
        return np.stack([x0 + c * p[..., 0] - s * p[..., 1], y0 + s * p[..., 0] + c * p[..., 1]],
                        axis=-1)  # fmt: skip


def read_map_yaml(path: str | Path) -> OccupancyGrid:
    """Read a ``map_server`` YAML and its image into an :class:`OccupancyGrid`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise MapFileError(f"{path}: cannot read the map YAML ({_reason(err)})") from None
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as err:
        raise MapFileError(f"{path}: not valid YAML ({_one_line(str(err))})") from None
    if not isinstance(data, dict):
        raise MapFileError(
            f"{path}: expected a mapping with keys {', '.join(_REQUIRED)}, got"
            f" {type(data).__name__}"
        )

    def fail(field: str, message: str) -> MapFileError:
        return MapFileError(f"{path}: {field}: {message}")

    for key in _REQUIRED:
        if key not in data or data[key] is None:
            raise fail(key, "missing (a map_server YAML needs image, resolution, origin,"
                            " occupied_thresh, free_thresh, negate)")  # fmt: skip
    image = data["image"]
    if not isinstance(image, str) or not image:
        raise fail("image", f"expected a file name, got {image!r}")
    resolution = _number(data["resolution"], "resolution", fail)
    if resolution <= 0:
        raise fail("resolution", f"must be > 0 m per pixel, got {resolution!r}")
    origin = data["origin"]
    if not isinstance(origin, list | tuple) or len(origin) != 3:
        raise fail("origin", f"expected [x, y, yaw], got {origin!r}")
    ox, oy, yaw = (_number(v, f"origin[{i}]", fail) for i, v in enumerate(origin))
    occ = _number(data["occupied_thresh"], "occupied_thresh", fail)
    free = _number(data["free_thresh"], "free_thresh", fail)
    for key, value in (("occupied_thresh", occ), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise fail(key, f"must be in [0, 1], got {value!r}")
    if free > occ:
        raise fail("free_thresh", f"must not exceed occupied_thresh ({occ:g}), got {free!r}")
    negate = data["negate"]
    if negate not in (0, 1) or isinstance(negate, float):
        raise fail("negate", f"expected 0 or 1 (or true/false), got {negate!r}")
    mode = data.get("mode", "trinary")
    if mode not in MODES:
        raise fail("mode", f"expected one of {', '.join(MODES)}, got {mode!r}")
    image_path = Path(image) if Path(image).is_absolute() else path.parent / image
    colour, alpha = _read_image(image_path, path)
    # map_server averages an alpha channel in with the three colour channels in trinary mode
    shade = (3 * colour + alpha) / 4 if mode == "trinary" and alpha is not None else colour
    if alpha is None:
        alpha = np.ones_like(colour)
    occupancy = shade if negate else 1.0 - shade
    if mode == "raw":
        percent = np.rint(shade * 255.0)
        cells = np.where(percent > 100, UNKNOWN, np.where(percent < 100 * free, FREE, OCCUPIED))
    else:
        cells = np.where(occupancy > occ, OCCUPIED, np.where(occupancy < free, FREE, UNKNOWN))
        if mode == "scale":
            cells = np.where(alpha < 1.0, UNKNOWN, np.where(cells == UNKNOWN, OCCUPIED, cells))
    return OccupancyGrid(
        cells=np.ascontiguousarray(cells[::-1].astype(np.int8)),  # first image row: top
        resolution=resolution,
        origin=(ox, oy, yaw),
        source=str(path),
    )


def _read_image(image: Path, yaml_path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The mean of the colour channels (H, W) in [0, 1] (grey: its value) and the alpha
    channel (H, W) (1 = opaque; None without one); top row first."""
    where = f"{yaml_path}: image: {image}"
    if not image.is_file():
        raise MapFileError(f"{where}: no such file")
    if image.suffix.lower() == ".pgm":
        return _read_pgm(image, where), None
    from matplotlib import image as mpimg  # Pillow through matplotlib: PNG, BMP, JPEG, …

    try:
        read = np.asarray(mpimg.imread(str(image)))
    except Exception as err:  # any decoder error: the file is not an image we can read
        raise MapFileError(f"{where}: cannot read the image ({_one_line(str(err))})") from None
    # PNG comes as floats in [0, 1]; other formats as 8-bit integers
    pixels = read / 255.0 if np.issubdtype(read.dtype, np.integer) else read.astype(float)
    if pixels.ndim == 2:
        return pixels, None
    if pixels.ndim != 3 or pixels.shape[2] not in (2, 3, 4):
        raise MapFileError(f"{where}: expected a grey or colour image, got shape {pixels.shape}")
    colour = pixels[..., :3].mean(axis=2) if pixels.shape[2] >= 3 else pixels[..., 0]
    return colour, pixels[..., -1] if pixels.shape[2] in (2, 4) else None


def _read_pgm(image: Path, where: str) -> np.ndarray:  # (H, W) in [0, 1]
    """A binary (P5) or plain (P2) PGM: header tokens, comments after #, 8 or 16 bits."""
    try:
        raw = image.read_bytes()
    except OSError as err:
        raise MapFileError(f"{where}: cannot read ({_reason(err)})") from None
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4 and pos < len(raw):
        if raw[pos : pos + 1] == b"#":
            end = raw.find(b"\n", pos)
            pos = len(raw) if end < 0 else end + 1
        elif raw[pos : pos + 1].isspace():
            pos += 1
        else:
            end = pos
            while end < len(raw) and not raw[end : end + 1].isspace() and raw[end] != ord("#"):
                end += 1
            tokens.append(raw[pos:end])
            pos = end
    if len(tokens) < 4 or tokens[0] not in (b"P5", b"P2"):
        raise MapFileError(f"{where}: not a PGM image (expected a P5 or P2 header)")
    try:
        width, height, maxval = (int(t) for t in tokens[1:4])
    except ValueError:
        raise MapFileError(
            f"{where}: bad PGM header {b' '.join(tokens).decode(errors='replace')!r}"
        ) from None
    if width < 1 or height < 1 or not 0 < maxval < 65536:
        raise MapFileError(f"{where}: bad PGM size or maximum ({width} × {height}, {maxval})")
    if tokens[0] == b"P2":
        values = np.array(raw[pos:].split(), dtype=np.int64)
    else:
        pos += 1  # the single whitespace after the maximum
        dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
        values = np.frombuffer(raw, dtype=dtype, count=min(width * height, (len(raw) - pos) //
                               dtype.itemsize), offset=pos).astype(np.int64)  # fmt: skip
    if values.size < width * height:
        raise MapFileError(f"{where}: truncated: {values.size} of {width} × {height} pixels")
    return values[: width * height].reshape(height, width) / float(maxval)


def _number(value: Any, field: str, fail: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(field, f"expected a finite number, got {value!r}")
    return float(value)


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _reason(err: BaseException) -> str:
    return getattr(err, "strerror", None) or _one_line(str(err))
