"""An occupancy grid turned into a layout: walls traced around its free space, start poses.

:func:`layout_from_occupancy` takes an :class:`~polyslam_env.world.occupancy.OccupancyGrid`
(free, occupied, unknown cells; unknown counts as wall) and

1. with ``shrink`` > 0 frees the occupied cells within ``shrink`` m of free space (a costmap's
   obstacles grown by the mapping robot's radius narrow doors to a few decimetres; walls no
   thicker than 2·``shrink`` between two free spaces vanish with it);
2. keeps the largest 4-connected free region (``keep="reachable"``: only where the robot's
   body with its margin can be, its centre in the largest region it can move in; slivers,
   laser spikes and rooms behind passages narrower than ``2·(robot_radius + margin)`` go);
3. traces the region's boundary between free and other cells (marching squares, so walls
   run along the cell edges: :func:`~polyslam_env.world.contours.trace_rings`) and simplifies
   it by Douglas–Peucker to ``tolerance`` (default: the grid's resolution) without letting two
   walls touch (:func:`~polyslam_env.world.contours.simplify_rings`); clutter inside stays as
   islands (closed walls) of at least ``min_island`` m²;
4. places ``robots`` start poses where the robot fits with ``2·robot_radius + margin`` to
   spare, ``start_separation`` apart: spread over the region (farthest-point, from a seeded
   first pose) or the nearest to ``start_near``;
5. finds the passages narrower than the robot with its margin (``2·(robot_radius + margin)``)
   that separate parts of the free space: :attr:`ImportResult.passages`, each with where it
   is, how wide and what it cuts off;

and validates the result like any map file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import ndimage

from polyslam_env.core.config import Config, check_positive, check_range
from polyslam_env.core.errors import ConfigError, MapFileError
from polyslam_env.world.contours import main_region, simplify_rings, trace_rings
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import layout_from_dict, layout_to_dict
from polyslam_env.world.occupancy import OCCUPIED, OccupancyGrid

__all__ = [
    "ImportOptions",
    "ImportResult",
    "Passage",
    "layout_from_occupancy",
    "shrink_that_opens",
]

#: Passages reported one by one (the rest counted).
MAX_PASSAGES = 20
#: m²: a region behind a narrow passage is reported when the robot's centre (with its
#: margin) can move over at least this much of it; smaller pockets (a corner between
#: clutter, a raster artefact of a trimmed boundary) are counted in :attr:`ImportResult.pockets`.
MIN_REGION = 0.25


@dataclass(frozen=True)
class ImportOptions(Config):
    """How an occupancy grid becomes a layout (module docstring)."""

    tolerance: float | None = None  # m, Douglas–Peucker; None: the grid's resolution
    shrink: float = 0.0  # m, occupied space eroded back
    keep: Literal["all", "reachable"] = "all"
    min_island: float | None = None  # m², smaller clutter is dropped; None: 4 cells
    robots: int = 3  # start poses
    start_separation: float = 4.0  # m
    start_near: tuple[float, float] | None = None  # (x, y): starts nearest this point
    robot_radius: float = 0.065  # m
    margin: float = 0.05  # m
    seed: int = 0  # draws the first start pose and the headings
    name: str = "imported"

    def validate(self) -> None:
        if self.tolerance is not None:
            check_range("tolerance", self.tolerance, 0.0, 10.0)
        check_range("shrink", self.shrink, 0.0, 10.0)
        if self.keep not in ("all", "reachable"):
            raise ConfigError(f"keep: must be 'all' or 'reachable', got {self.keep!r}")
        if self.min_island is not None:
            check_range("min_island", self.min_island, 0.0, 1e6)
        check_range("robots", self.robots, 1, 64)
        check_range("start_separation", self.start_separation, 0.0, 1e3)
        check_positive("robot_radius", self.robot_radius)
        check_positive("margin", self.margin)
        check_range("seed", self.seed, 0, 2**63)
        if not self.name:
            raise ConfigError("name: must be a non-empty string, got ''")


@dataclass(frozen=True)
class Passage:
    """A passage narrower than the robot with its margin: at (x, y), about ``width`` m wide,
    the only way into a region of ``area`` m² around ``region`` (x, y)."""

    x: float
    y: float
    width: float
    area: float
    region: tuple[float, float]

    def describe(self) -> str:
        return (
            f"passage at ({self.x:.2f}, {self.y:.2f}) is about {self.width:.2f} m wide; it is"
            f" the only way into {self.area:.1f} m² of free space around"
            f" ({self.region[0]:.1f}, {self.region[1]:.1f})"
        )


@dataclass
class ImportResult:
    """The layout, the narrow passages (the first :data:`MAX_PASSAGES`, ``more`` beyond),
    and what the import changed, as sentences."""

    layout: Layout
    passages: list[Passage] = field(default_factory=list)
    more_passages: int = 0
    pockets: int = 0  # regions behind narrow passages smaller than MIN_REGION
    notes: list[str] = field(default_factory=list)


def layout_from_occupancy(grid: OccupancyGrid, options: ImportOptions) -> ImportResult:
    """The layout of ``grid``'s free space (module docstring); MapFileError naming the
    source when there is no room for the robots."""
    region, notes = _free_region(grid, options)
    clearance = _clearance(region, grid.resolution)
    fit = options.robot_radius + options.margin
    moves = clearance >= fit  # where the robot's centre fits with its margin
    if not moves.any():
        raise MapFileError(
            f"{grid.source}: no free space is {2 * fit:g} m wide: no room for a robot of"
            f" radius {options.robot_radius:g} m with margin {options.margin:g} m"
        )
    passages, more, pockets = _narrow_passages(grid, region, clearance, moves, fit)
    walls = tuple(_walls(grid, region, options))
    poses = _start_poses(grid, clearance, moves, options)
    data = layout_to_dict(Layout(name=options.name, walls=walls, start_poses=poses))
    out = layout_from_dict(data, source=grid.source, robot_radius=options.robot_radius)
    return ImportResult(out, passages, more, pockets, notes)


def shrink_that_opens(grid: OccupancyGrid, options: ImportOptions, limit: float) -> float | None:
    """The least ``shrink`` (a multiple of the resolution, above ``options.shrink``, at most
    ``limit`` m) after which no region of at least :data:`MIN_REGION` m² the robot fits in is
    cut off from the main one by a passage narrower than the robot with its margin; None if
    none up to ``limit`` does (the shrink back to offer when a costmap's inflation narrowed
    the doors)."""
    res = grid.resolution
    fit = options.robot_radius + options.margin
    k = math.floor(options.shrink / res + 1e-9) + 1
    while k * res <= limit + 1e-9:
        region, _ = _free_region(grid, options.replace(shrink=k * res))
        labels, count = ndimage.label(_clearance(region, res) >= fit)
        sizes = np.bincount(labels.ravel())[1:] * res * res
        if count <= 1 or np.sort(sizes)[:-1].max() < MIN_REGION:
            return round(k * res, 9)
        k += 1
    return None


def _free_region(grid: OccupancyGrid, options: ImportOptions) -> tuple[np.ndarray, list[str]]:
    """Steps 1–2 (module docstring): the free region kept, on the raster padded by one cell
    of wall all round, and what they changed, as sentences."""
    res = grid.resolution
    notes: list[str] = []
    free = grid.free.copy()
    if options.shrink > 0:
        freed = (grid.cells == OCCUPIED) & (_distance(free, res) <= options.shrink + 1e-9)
        free |= freed
        notes.append(
            f"--shrink {options.shrink:g} m freed {int(freed.sum())} occupied cells"
            f" ({freed.sum() * res * res:.2f} m²)"
        )
    free = np.pad(free, 1)  # a wall all round: every traced ring closes
    region = _largest(free)
    dropped = int(free.sum() - region.sum())
    if dropped:
        notes.append(
            f"left out {dropped * res * res:.2f} m² of free space not connected to the largest"
            " free region"
        )
    if options.keep == "reachable":
        body = _reachable(region, res, options.robot_radius + options.margin)
        notes.append(
            f"keep reachable: left out {(region.sum() - body.sum()) * res * res:.2f} m² the"
            " robot's body cannot reach"
        )
        region = body
    return region, notes


# -- rasters ------------------------------------------------------------------------------------
def _distance(free: np.ndarray, res: float) -> np.ndarray:  # (H, W) m
    """Distance from each cell centre to the nearest free cell's centre (0 on free cells)."""
    return np.asarray(ndimage.distance_transform_edt(~free)) * res


def _clearance(region: np.ndarray, res: float) -> np.ndarray:  # (H, W) m
    """For free cells, the distance from the centre to the nearest other cell's edge (half a
    cell less than to its centre); 0 elsewhere."""
    d = np.asarray(ndimage.distance_transform_edt(region)) * res - 0.5 * res
    return np.where(region, np.maximum(d, 0.0), 0.0)


def _largest(mask: np.ndarray) -> np.ndarray:
    """The largest 4-connected component of ``mask`` (all False if none)."""
    labels, count = ndimage.label(mask)
    if count == 0:
        return np.zeros_like(mask)
    sizes = np.bincount(labels.ravel())[1:]
    return np.asarray(labels == int(np.argmax(sizes)) + 1)


def _reachable(region: np.ndarray, res: float, radius: float) -> np.ndarray:
    """The cells of ``region`` within ``radius`` of a centre a disc of that radius (the robot
    with its margin) can reach: centres with the radius clear, in their largest component."""
    centres = _largest(_clearance(region, res) >= radius)
    near = np.asarray(ndimage.distance_transform_edt(~centres)) * res <= radius
    return region & near


def _narrow_passages(
    grid: OccupancyGrid, region: np.ndarray, clearance: np.ndarray, moves: np.ndarray, fit: float
) -> tuple[list[Passage], int, int]:
    """Regions where the robot fits that only passages narrower than ``2·fit`` join to the
    largest one: for each, the passage where the two meet when the clearance asked for is
    lowered in half-cell steps (the widest way between them), as a :class:`Passage`; then
    how many more there are, and how many pockets smaller than :data:`MIN_REGION`."""
    res = grid.resolution
    labels, count = ndimage.label(moves)
    if count <= 1:
        return [], 0, 0
    sizes = np.bincount(labels.ravel())[1:]
    main = int(np.argmax(sizes)) + 1
    others = [k for k in range(1, count + 1) if k != main]
    pockets = sum(sizes[k - 1] * res * res < MIN_REGION for k in others)
    others = [k for k in others if sizes[k - 1] * res * res >= MIN_REGION]
    others.sort(key=lambda k: -sizes[k - 1])
    out = []
    levels = np.arange(fit - 0.5 * res, -0.5 * res, -0.5 * res)
    from_main = ndimage.distance_transform_edt(labels != main)
    for k in others[:MAX_PASSAGES]:
        piece = labels == k
        for level in levels:
            lab, _ = ndimage.label(region & (clearance >= level))
            a, b = lab[labels == main][0], lab[piece][0]
            if a != b:
                continue
            band = (lab == a) & (clearance < level + 0.5 * res) & ~moves
            d = from_main + ndimage.distance_transform_edt(~piece)
            cell = np.unravel_index(int(np.argmin(np.where(band, d, np.inf))), band.shape)
            xy = _centres(grid, np.array([cell]))[0]
            rows, cols = np.nonzero(piece)
            centre = _centres(grid, np.array([[rows.mean(), cols.mean()]]))[0]
            # the region: free cells nearer to the piece than to the rest of the space
            grown = ndimage.binary_dilation(piece, iterations=math.ceil(fit / res) + 1)
            out.append(
                Passage(
                    x=float(xy[0]),
                    y=float(xy[1]),
                    width=2 * max(float(level), 0.0) + 0.5 * res,
                    area=float((region & grown).sum()) * res * res,
                    region=(float(centre[0]), float(centre[1])),
                )
            )
            break
    return out, max(0, len(others) - MAX_PASSAGES), pockets


def _centres(grid: OccupancyGrid, cells: np.ndarray) -> np.ndarray:  # (n, 2) world
    """World coordinates of padded-raster cells (n, 2) as (row, col)."""
    res = grid.resolution
    local = np.column_stack([(cells[:, 1] - 0.5) * res, (cells[:, 0] - 0.5) * res])
    return grid.to_world(local)


# -- walls and starts ---------------------------------------------------------------------------
def _walls(grid: OccupancyGrid, region: np.ndarray, options: ImportOptions) -> list[np.ndarray]:
    """The region's boundary (padded raster: sample (r, c) is the centre of cell (r−1, c−1),
    at ((c − ½)·res, (r − ½)·res) in the map frame), traced and simplified, in the world."""
    res = grid.resolution
    rings = trace_rings(region.astype(float), 0.5, (-0.5 * res, -0.5 * res), res)
    min_island = 4 * res * res if options.min_island is None else options.min_island
    outer, holes = main_region(rings, min_island)
    tol = res if options.tolerance is None else options.tolerance
    return [grid.to_world(r) for r in simplify_rings([outer, *holes], tol)]


def _start_poses(
    grid: OccupancyGrid,
    clearance: np.ndarray,
    moves: np.ndarray,
    options: ImportOptions,
) -> np.ndarray:  # (n, 3)
    """``robots`` poses in the largest region the robot moves in, with ``2·robot_radius +
    margin`` from the traced walls and ``start_separation`` (at least that) from each other:
    spread (farthest-point from a seeded first pose) or nearest to ``start_near``."""
    rng = np.random.default_rng(options.seed)
    clear = 2 * options.robot_radius + options.margin
    apart = max(clear, options.start_separation)
    # The traced walls lie within the tolerance of the cell edges, so a cell this clear of
    # the edges is clear of the walls: no exact distance to every wall needed.
    tol = grid.resolution if options.tolerance is None else options.tolerance
    cells = np.argwhere(_largest(moves) & (clearance >= clear + tol + 1e-9))
    if len(cells) < options.robots:
        raise MapFileError(f"{grid.source}: no room for {options.robots} starts {clear:g} m"
                           " clear of the walls")  # fmt: skip
    xy = _centres(grid, cells)
    chosen: list[np.ndarray] = []
    if options.start_near is not None:
        order = np.argsort(np.hypot(*(xy - np.asarray(options.start_near)).T))
        for i in order:
            if all(math.dist(xy[i], c) >= apart for c in chosen):
                chosen.append(xy[i])
                if len(chosen) == options.robots:
                    break
    else:
        chosen.append(xy[int(rng.integers(len(xy)))])
        nearest = np.hypot(*(xy - chosen[0]).T)
        while len(chosen) < options.robots and nearest.max() >= apart:
            chosen.append(xy[int(np.argmax(nearest))])
            nearest = np.minimum(nearest, np.hypot(*(xy - chosen[-1]).T))
    if len(chosen) < options.robots:
        raise MapFileError(
            f"{grid.source}: only {len(chosen)} start poses {apart:g} m apart fit in the free"
            f" space, {options.robots} asked (lower --start-separation or --robots)"
        )
    heading = rng.uniform(-np.pi, np.pi, size=options.robots)
    return np.column_stack([np.array(chosen), heading])
