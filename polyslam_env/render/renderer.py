"""Drawing a :class:`RenderState` with pygame: a window (``"human"``) or an RGB array.

The only module that imports pygame, and only lazily (inside functions), so ``import
polyslam_env`` never loads it. The renderer reads the state and returns pixels; nothing flows
back into observations.

What a frame shows, bottom to top: swept cells (light tint), true paths (thin, light) and
estimated paths (dashed), each robot's map polynomials (thick band in its colour) under the
true walls and pillars (dark), rendezvous links (amber), 2σ position ellipses around the
estimated poses, the robots at their true poses with heading ticks (grey when failed), and a
legend strip with the step number and ``info_text``. The map part is drawn at twice the output
resolution and smoothly downscaled, which anti-aliases the thick lines; text is drawn after.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polyslam_env.core.errors import DisplayError, OutputError
from polyslam_env.core.io import ordinary_permissions
from polyslam_env.core.names import robot_name
from polyslam_env.render.state import RenderState
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout

if TYPE_CHECKING:
    import pygame

__all__ = ["RENDER_MODES", "ROBOT_COLORS", "Renderer", "WorldToPixel", "robot_color", "save_video"]

RENDER_MODES = ("human", "rgb_array")

Color = tuple[int, int, int]

# Matplotlib's tab10 without its grey (grey marks failed robots): 9 colours that stay apart
# for colour-blind viewers better than a plain hue wheel; robot i gets ROBOT_COLORS[i % 9].
ROBOT_COLORS: tuple[Color, ...] = (
    (31, 119, 180),  # blue
    (255, 127, 14),  # orange
    (44, 160, 44),  # green
    (214, 39, 40),  # red
    (148, 103, 189),  # purple
    (140, 86, 75),  # brown
    (227, 119, 194),  # pink
    (188, 189, 34),  # olive
    (23, 190, 207),  # cyan
)
BACKGROUND: Color = (252, 252, 250)
COVERED: Color = (226, 234, 243)  # swept free cells: a light blue-grey tint
WALL: Color = (40, 40, 46)
FAILED: Color = (160, 160, 160)
LINK: Color = (240, 170, 0)  # rendezvous / mutual camera view
OUTLINE: Color = (25, 25, 25)
LEGEND_BG: Color = (238, 238, 236)
TEXT: Color = (30, 30, 30)

SUPERSAMPLE = 2  # the map is drawn at this multiple of the output size, then smoothscaled
MARGIN_PX = 16  # blank border around the layout bounds, output pixels
MIN_ELLIPSE_PX = 10.0  # auto ellipse scaling: the largest 2σ semi-axis is made at least this
# Auto ellipse factors: 1, 2, 5, 10, 20, 50, ... up to 5e6, so a stated factor is easy to read.
ELLIPSE_FACTORS = tuple(m * 10.0**e for e in range(7) for m in (1.0, 2.0, 5.0))
ELLIPSE_POINTS = 48  # vertices of a drawn ellipse


def robot_color(i: int) -> Color:
    """Robot i's colour (cycling after the palette's 9 colours)."""
    return ROBOT_COLORS[i % len(ROBOT_COLORS)]


def _blend(c: Color, other: Color, t: float) -> Color:
    """``c`` moved a fraction ``t`` towards ``other``."""
    return (
        round(c[0] + t * (other[0] - c[0])),
        round(c[1] + t * (other[1] - c[1])),
        round(c[2] + t * (other[2] - c[2])),
    )


def _pygame() -> Any:
    """Import pygame on first use, without its banner."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    import pygame

    return pygame


def _ceil_to(n: float, k: int) -> int:
    """Smallest multiple of ``k`` that is >= n (video codecs like sizes divisible by 16)."""
    return math.ceil(n / k) * k


@dataclass(frozen=True)
class WorldToPixel:
    """World metres → pixel coordinates, y up in the world and down on screen."""

    scale: float  # pixels per metre
    x_left: float  # world x at pixel column 0
    y_top: float  # world y at pixel row 0

    def __call__(self, points: np.ndarray) -> np.ndarray:  # (..., 2) float pixels
        p = np.asarray(points, dtype=float)
        return np.stack(
            [(p[..., 0] - self.x_left) * self.scale, (self.y_top - p[..., 1]) * self.scale],
            axis=-1,
        )

    def scaled(self, k: float) -> WorldToPixel:
        """The same view on a canvas ``k`` times larger."""
        return WorldToPixel(self.scale * k, self.x_left, self.y_top)


def fit_view(
    bounds: tuple[float, float, float, float], size: int, margin: int = MARGIN_PX
) -> tuple[WorldToPixel, int, int]:
    """Fit ``bounds`` (x0, y0, x1, y1) into a ``size``-pixel square with ``margin``, centred.

    Returns the transform and the map area's width and height in pixels (multiples of 16);
    the longer side of the layout spans ``size - 2·margin`` pixels.
    """
    x0, y0, x1, y1 = bounds
    w, h = max(x1 - x0, 1e-6), max(y1 - y0, 1e-6)
    scale = (size - 2 * margin) / max(w, h)
    width, height = _ceil_to(w * scale + 2 * margin, 16), _ceil_to(h * scale + 2 * margin, 16)
    x_left = 0.5 * (x0 + x1) - 0.5 * width / scale
    y_top = 0.5 * (y0 + y1) + 0.5 * height / scale
    return WorldToPixel(scale, x_left, y_top), width, height


def _finite_rows(points: np.ndarray) -> np.ndarray:  # (k', 2)
    """Rows of an (k, 2) array with both coordinates finite."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    return p[np.isfinite(p).all(axis=1)]


def dash_segments(points: np.ndarray, on: float, off: float) -> np.ndarray:  # (D, 2, 2)
    """Cut a pixel polyline (k, 2) into the little segments of a dashed line.

    Every vertex and every dash boundary (at arclengths n·(on+off) and n·(on+off)+on) becomes a
    breakpoint; the pieces whose middle falls in an "on" stretch are kept.
    """
    p = _finite_rows(points)
    if len(p) < 2:
        return np.zeros((0, 2, 2))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])  # (k,)
    period = on + off
    marks = np.arange(0.0, s[-1], period)
    t = np.unique(np.concatenate([s, marks, marks + on]))
    t = t[t <= s[-1]]
    xy = np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])  # (T, 2)
    mid = 0.5 * (t[:-1] + t[1:])
    keep = np.mod(mid, period) < on
    return np.stack([xy[:-1][keep], xy[1:][keep]], axis=1)


def ellipse_points(mean: np.ndarray, cov: np.ndarray, k: float) -> np.ndarray | None:
    """Vertices (ELLIPSE_POINTS, 2) of the k-σ ellipse of a 2×2 covariance; None if degenerate."""
    c = np.asarray(cov, dtype=float)[:2, :2]
    if not (np.isfinite(c).all() and np.isfinite(mean[:2]).all()):
        return None
    vals, vecs = np.linalg.eigh(0.5 * (c + c.T))
    axes = k * np.sqrt(np.clip(vals, 0.0, None))  # (2,)
    if axes.max() <= 0.0:
        return None
    t = np.linspace(0.0, 2.0 * np.pi, ELLIPSE_POINTS, endpoint=False)
    circle = np.stack([np.cos(t), np.sin(t)])  # (2, M)
    return np.asarray(mean[:2] + (vecs @ (axes[:, None] * circle)).T)


def ellipse_factor(state: RenderState, px_per_m: float) -> float:
    """Smallest of 1, 2, 5, 10, ... making the largest active 2σ semi-axis >= MIN_ELLIPSE_PX."""
    covs = np.asarray(state.est_covs_abs, dtype=float)[:, :2, :2]  # (N, 2, 2)
    ok = np.asarray(state.active, dtype=bool) & np.isfinite(covs).all(axis=(1, 2))
    if not ok.any():
        return 1.0
    sym = 0.5 * (covs[ok] + np.swapaxes(covs[ok], 1, 2))
    largest = 2.0 * math.sqrt(max(float(np.linalg.eigvalsh(sym).max()), 0.0)) * px_per_m
    if largest <= 0.0:
        return 1.0
    fits = [f for f in ELLIPSE_FACTORS if f * largest >= MIN_ELLIPSE_PX]
    return fits[0] if fits else ELLIPSE_FACTORS[-1]


class Renderer:
    """Draws :class:`RenderState` frames for one layout and team size.

    ``render_mode="rgb_array"`` makes :meth:`render` return an (H, W, 3) uint8 array;
    ``"human"`` shows the frame in a pygame window (opened on the first render; honours
    ``SDL_VIDEODRIVER``, e.g. ``dummy`` in tests) and returns None. Closing the window stops
    further drawing for this renderer instead of reopening it. ``size`` is the pixel span of
    the layout's longer side plus margins; a legend strip is added below. ``ellipse_scale``
    fixes the factor applied to the 2σ ellipses; None picks 1, 2, 5, 10, 20, ... per frame so the
    largest one is visible (the legend always states the factor in use). ``render_fps``, when
    given, paces the human window.
    """

    def __init__(
        self,
        layout: Layout,
        num_robots: int,
        render_mode: str,
        world_config: WorldConfig,
        size: int = 720,
        ellipse_scale: float | None = None,
        render_fps: float | None = None,
    ) -> None:
        if render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
        if num_robots < 1:
            raise ValueError(f"num_robots must be >= 1, got {num_robots}")
        if size < 64:
            raise ValueError(f"size must be >= 64 pixels, got {size}")
        if ellipse_scale is not None and not ellipse_scale > 0:
            raise ValueError(f"ellipse_scale must be > 0 or None, got {ellipse_scale}")
        self.layout = layout
        self.num_robots = num_robots
        self.render_mode = render_mode
        self.world_config = world_config
        self.ellipse_scale = ellipse_scale
        self.render_fps = render_fps
        self.view, self.map_width, self.map_height = fit_view(layout.bounds, size)
        self.font_px = max(12, size // 45)
        self._pg: Any = _pygame()
        self._fonts = self._load_fonts(self._pg)  # (legend font, label font), or None
        self.width = self.map_width
        self.legend_height = self._legend_rows_height()
        self.height = self.map_height + self.legend_height
        self._window: Any = None
        self._clock: Any = None
        self._window_closed = False  # the user closed the window: draw no more

    # -- public -----------------------------------------------------------------------------
    def render(self, state: RenderState) -> np.ndarray | None:
        """Draw one frame: an (H, W, 3) uint8 array in rgb_array mode, None in human mode."""
        if state.num_robots != self.num_robots:
            raise ValueError(
                f"state has {state.num_robots} robots, renderer was built for {self.num_robots}"
            )
        if self.render_mode == "human" and self._window_closed:
            return None
        pg = self._pg
        frame = self._draw_frame(pg, state)
        if self.render_mode == "rgb_array":
            return np.ascontiguousarray(np.transpose(pg.surfarray.array3d(frame), (1, 0, 2)))
        self._show(pg, frame)
        return None

    def close(self) -> None:
        """Close the window if one is open; safe to call any number of times."""
        if self._window is not None:
            self._pg.display.quit()
        self._window = None
        self._clock = None

    # -- setup ------------------------------------------------------------------------------
    def _load_fonts(self, pg: Any) -> tuple[Any, Any] | None:
        """pygame's bundled default font at two sizes; None (no text) if fonts are unavailable."""
        try:
            pg.font.init()
            return pg.font.Font(None, self.font_px + 4), pg.font.Font(None, self.font_px + 2)
        except Exception:  # pygame.error, missing SDL_ttf or font file: draw without text
            return None

    def _show(self, pg: Any, frame: pygame.Surface) -> None:
        """Blit the frame to the window (opening it on first use) and handle window events."""
        if self._window is None:
            try:
                pg.display.init()
                self._window = pg.display.set_mode((self.width, self.height))
            except pg.error as e:
                raise DisplayError(
                    f"cannot open a pygame window ({e}); on a headless machine use "
                    "render_mode='rgb_array' (polyslam run: --video out.gif instead of --render)"
                ) from e
            pg.display.set_caption(f"polyslam: {self.layout.name}")
            self._clock = pg.time.Clock()
        for event in pg.event.get():
            if event.type == pg.QUIT:
                self._window_closed = True
                self.close()
                return
        self._window.blit(frame, (0, 0))
        pg.display.flip()
        if self.render_fps:
            self._clock.tick(self.render_fps)

    # -- drawing ----------------------------------------------------------------------------
    def _draw_frame(self, pg: Any, state: RenderState) -> pygame.Surface:
        """The whole frame: supersampled map area, downscaled, then labels and legend."""
        k = SUPERSAMPLE
        big = pg.Surface((self.map_width * k, self.map_height * k))
        big.fill(BACKGROUND)
        view = self.view.scaled(k)
        factor = self.ellipse_scale or ellipse_factor(state, self.view.scale)
        self._draw_coverage(pg, big, view, state)
        self._draw_paths(pg, big, view, state)
        self._draw_maps(pg, big, view, state)
        self._draw_layout(pg, big, view)
        self._draw_links(pg, big, view, state)
        self._draw_ellipses(pg, big, view, state, factor)
        self._draw_robots(pg, big, view, state)
        frame = pg.Surface((self.width, self.height))
        frame.blit(pg.transform.smoothscale(big, (self.map_width, self.map_height)), (0, 0))
        self._draw_labels(pg, frame, state)
        self._draw_legend(pg, frame, state, factor)
        return frame

    def _draw_coverage(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState
    ) -> None:
        """Swept cells as a tint; the grid is scaled with nearest-neighbour, so cells stay crisp."""
        cov = np.asarray(state.coverage, dtype=bool)  # (H, W), row 0 = lowest y
        if cov.size == 0 or not cov.any():
            return
        rgb = np.where(cov[::-1].T[..., None], COVERED, BACKGROUND).astype(np.uint8)  # (W, H, 3)
        cells = pg.surfarray.make_surface(rgb)
        cells.set_colorkey(BACKGROUND)
        res = state.coverage_resolution
        ox, oy = state.coverage_origin
        top_left = view(np.array([ox, oy + cov.shape[0] * res]))
        bottom_right = view(np.array([ox + cov.shape[1] * res, oy]))
        x0, y0 = np.round(top_left).astype(int)
        x1, y1 = np.round(bottom_right).astype(int)
        surf.blit(pg.transform.scale(cells, (max(x1 - x0, 1), max(y1 - y0, 1))), (x0, y0))

    def _draw_paths(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState
    ) -> None:
        """True paths thin and light, estimated paths dashed, in each robot's colour."""
        k = SUPERSAMPLE
        for i, true_path in enumerate(state.true_paths):
            true_px = view(_finite_rows(true_path))
            if len(true_px) >= 2:
                light = _blend(self._color(i, state), BACKGROUND, 0.45)
                pg.draw.lines(surf, light, False, true_px, 2 * k)
        for i, est_path in enumerate(state.est_paths):
            dark = _blend(self._color(i, state), OUTLINE, 0.25)
            for a, b in dash_segments(view(_finite_rows(est_path)), 6.0 * k, 4.0 * k):
                pg.draw.line(surf, dark, a, b, k + 1)

    def _draw_maps(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState
    ) -> None:
        """Each robot's polynomials as a thick band in its colour (walls are drawn over them)."""
        k = SUPERSAMPLE
        for i, polylines in enumerate(state.maps_abs):
            color = self._color(i, state)
            for line in polylines:
                _thick_polyline(pg, surf, color, view(_finite_rows(line)), 5 * k)

    def _draw_layout(self, pg: Any, surf: pygame.Surface, view: WorldToPixel) -> None:
        """True walls and pillars, dark and thin enough to show the map bands beneath."""
        k = SUPERSAMPLE
        for wall in self.layout.walls:
            _thick_polyline(pg, surf, WALL, view(wall), 2 * k)
        for x, y, r in self.layout.pillars:
            centre = view(np.array([x, y]))
            pg.draw.circle(surf, WALL, centre, max(r * view.scale, k))

    def _draw_links(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState
    ) -> None:
        """Rendezvous / mutual-view links between the robots' true positions."""
        pos = view(np.asarray(state.true_poses, dtype=float)[:, :2])
        for i, j in state.links:
            if np.isfinite(pos[[i, j]]).all():
                pg.draw.line(surf, LINK, pos[i], pos[j], 3 * SUPERSAMPLE)

    def _draw_ellipses(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState, k: float
    ) -> None:
        """Estimated position (small cross) and its 2σ ellipse, scaled by ``k``."""
        ss = SUPERSAMPLE
        for i in range(state.num_robots):
            mean = np.asarray(state.est_poses_abs[i], dtype=float)
            if not np.isfinite(mean[:2]).all():
                continue
            color = _blend(self._color(i, state), OUTLINE, 0.25)
            pts = ellipse_points(mean, state.est_covs_abs[i], 2.0 * k)
            if pts is not None:
                pg.draw.polygon(surf, color, view(pts), ss + 1)
            cx, cy = view(mean[:2])
            arm = 4 * ss
            pg.draw.line(surf, color, (cx - arm, cy), (cx + arm, cy), ss)
            pg.draw.line(surf, color, (cx, cy - arm), (cx, cy + arm), ss)

    def _draw_robots(
        self, pg: Any, surf: pygame.Surface, view: WorldToPixel, state: RenderState
    ) -> None:
        """Robots at their true poses: filled disc, dark rim and a heading tick."""
        ss = SUPERSAMPLE
        radius = max(self.world_config.robot.radius * view.scale, 6.0 * ss)
        for i, (x, y, theta) in enumerate(np.asarray(state.true_poses, dtype=float)):
            if not np.isfinite([x, y, theta]).all():
                continue
            cx, cy = view(np.array([x, y]))
            tip = (cx + 1.5 * radius * math.cos(theta), cy - 1.5 * radius * math.sin(theta))
            pg.draw.circle(surf, self._color(i, state), (cx, cy), radius)
            pg.draw.circle(surf, OUTLINE, (cx, cy), radius, ss)
            pg.draw.line(surf, OUTLINE, (cx, cy), tip, ss + 1)

    def _draw_labels(self, pg: Any, frame: pygame.Surface, state: RenderState) -> None:
        """Robot names next to the robots (output resolution, so text stays sharp)."""
        if self._fonts is None:
            return
        font = self._fonts[1]
        offset = max(self.world_config.robot.radius * self.view.scale, 6.0) + 3
        for i, (x, y, _) in enumerate(np.asarray(state.true_poses, dtype=float)):
            if not np.isfinite([x, y]).all():
                continue
            cx, cy = self.view(np.array([x, y]))
            text = font.render(robot_name(i), True, _blend(self._color(i, state), OUTLINE, 0.3))
            frame.blit(text, (round(cx + offset), round(cy - offset - text.get_height() + 4)))

    def _draw_legend(
        self, pg: Any, frame: pygame.Surface, state: RenderState, factor: float
    ) -> None:
        """Bottom strip: step and info text, then the keys flowed into rows."""
        top = self.map_height
        pg.draw.rect(frame, LEGEND_BG, (0, top, self.width, self.legend_height))
        pg.draw.line(frame, (200, 200, 200), (0, top), (self.width, top), 1)
        if self._fonts is None:
            return
        font = self._fonts[0]
        line1 = f"step {state.step}" + (f"   {state.info_text}" if state.info_text else "")
        frame.blit(font.render(line1, True, TEXT), (LEGEND_PAD, top + LEGEND_PAD))
        failed = not np.asarray(state.active, dtype=bool).all()
        items = legend_items(state.num_robots, _ellipse_label(factor), failed)
        row_h = font.get_height() + 4
        y0 = top + LEGEND_PAD + row_h
        for row, x, item in _flow(items, font, self.width):
            y = y0 + row * row_h
            _draw_glyph(pg, frame, item, x, y + font.get_height() // 2)
            frame.blit(font.render(item.label, True, TEXT), (x + GLYPH_W + 4, y))

    def _legend_rows_height(self) -> int:
        """Legend strip height for the widest case (a failed robot, a large ellipse factor)."""
        if self._fonts is None:
            return 16
        font = self._fonts[0]
        items = legend_items(self.num_robots, _ellipse_label(ELLIPSE_FACTORS[-1]), True)
        rows = 1 + max(row for row, _, _ in _flow(items, font, self.width))
        row_h = font.get_height() + 4
        return _ceil_to(2 * LEGEND_PAD + row_h * (1 + rows), 16)

    def _color(self, i: int, state: RenderState) -> Color:
        active = np.asarray(state.active, dtype=bool)
        return robot_color(i) if active[i] else FAILED


def _thick_polyline(
    pg: Any, surf: pygame.Surface, color: Color, points: np.ndarray, width: int
) -> None:
    """A polyline of the given width with round joints and caps (pygame leaves notches)."""
    if len(points) == 0:
        return
    if len(points) >= 2:
        pg.draw.lines(surf, color, False, points, width)
    for p in _joint_points(points):
        pg.draw.circle(surf, color, p, width / 2)


def _joint_points(points: np.ndarray) -> np.ndarray:  # (J, 2)
    """The ends of a polyline and the vertices where it turns by more than ~15°."""
    if len(points) < 3:
        return points
    d = np.diff(points, axis=0)  # (k-1, 2)
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs(np.angle(np.exp(1j * np.diff(heading))))  # (k-2,)
    inner = points[1:-1][turn > np.radians(15.0)]
    return np.vstack([points[:1], inner, points[-1:]])


# -- legend ---------------------------------------------------------------------------------
LEGEND_PAD = 6  # pixels around the legend text
GLYPH_W = 18  # width of a legend key's sample line or dot area
ITEM_GAP = 14  # pixels between legend items


@dataclass(frozen=True)
class LegendItem:
    """One legend key: a sample glyph and its label."""

    kind: str  # "dot", "line", "dash" or "ellipse"
    color: Color
    width: int  # line width of the glyph, pixels
    label: str


def legend_items(num_robots: int, ellipse_label: str, failed: bool) -> list[LegendItem]:
    """The keys: robot colours, then what walls, maps, paths, ellipses and links look like."""
    c = ROBOT_COLORS[0]
    items = [LegendItem("dot", robot_color(i), 0, robot_name(i)) for i in range(num_robots)]
    items += [
        LegendItem("line", WALL, 2, "wall"),
        LegendItem("line", c, 5, "map"),
        LegendItem("line", _blend(c, BACKGROUND, 0.45), 2, "true path"),
        LegendItem("dash", _blend(c, OUTLINE, 0.25), 2, "estimate"),
        LegendItem("ellipse", _blend(c, OUTLINE, 0.25), 1, ellipse_label),
        LegendItem("line", LINK, 3, "link"),
    ]
    if failed:
        items.append(LegendItem("dot", FAILED, 0, "failed"))
    return items


def _ellipse_label(factor: float) -> str:
    return "2σ ellipse" if factor == 1.0 else f"2σ ellipse ×{factor:g}"


def _flow(items: list[LegendItem], font: Any, width: int) -> list[tuple[int, int, LegendItem]]:
    """(row, x, item) for each item, wrapping to a new row when the next one would not fit."""
    out: list[tuple[int, int, LegendItem]] = []
    row, x = 0, LEGEND_PAD
    for item in items:
        w = GLYPH_W + 4 + font.size(item.label)[0]
        if x > LEGEND_PAD and x + w > width - LEGEND_PAD:
            row, x = row + 1, LEGEND_PAD
        out.append((row, x, item))
        x += w + ITEM_GAP
    return out


def _draw_glyph(pg: Any, frame: pygame.Surface, item: LegendItem, x: int, mid: int) -> None:
    """A legend key's sample, GLYPH_W wide, centred vertically on ``mid``."""
    if item.kind == "dot":
        pg.draw.circle(frame, item.color, (x + GLYPH_W // 2, mid), 5)
    elif item.kind == "line":
        pg.draw.line(frame, item.color, (x, mid), (x + GLYPH_W, mid), item.width)
    elif item.kind == "dash":
        for a in range(0, GLYPH_W, 8):
            pg.draw.line(
                frame, item.color, (x + a, mid), (x + min(a + 4, GLYPH_W), mid), item.width
            )
    else:
        pg.draw.ellipse(frame, item.color, (x, mid - 5, GLYPH_W, 10), item.width)


# -- video ----------------------------------------------------------------------------------
def save_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 10) -> Path:
    """Write (H, W, 3) uint8 frames as a video chosen by the extension; return the path.

    ``.gif`` is written with Pillow (a matplotlib dependency, so always present), one GIF frame
    per input frame except that Pillow merges identical consecutive frames into one longer
    frame. Other extensions (``.mp4``, ``.webm``, ...) need imageio with its ffmpeg plugin
    (``pip install imageio[ffmpeg]``). The file appears atomically (written next to the target,
    then renamed).

    Single-agent (Gymnasium wrapper) users can instead record with Gymnasium's own wrapper,
    which needs ``moviepy``::

        env = gymnasium.make("polyslam/Team-v0", render_mode="rgb_array")
        env = gymnasium.wrappers.RecordVideo(env, "videos", episode_trigger=lambda e: True)
    """
    path = check_video_path(path)
    array = _check_frames(frames)
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    suffix = path.suffix.lower()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=suffix)
    except OSError as err:
        raise OutputError(f"{path}: cannot write ({err.strerror or err})") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        if suffix == ".gif":
            _write_gif(array, tmp, fps)
        else:
            _write_with_imageio(array, tmp, fps)
        ordinary_permissions(tmp)  # mkstemp made it 0600
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write ({err.strerror or err})") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


#: Extensions :func:`save_video` writes: GIF with Pillow, the others with imageio's ffmpeg.
VIDEO_SUFFIXES = (".gif", ".mp4", ".webm", ".avi", ".mkv", ".mov")


def check_video_path(path: str | Path) -> Path:
    """``path`` as a Path if its extension is one :func:`save_video` writes, else
    :class:`~polyslam_env.core.errors.OutputError` (before any frame is drawn)."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        got = f"{path.suffix!r}" if path.suffix else "no extension"
        raise OutputError(
            f"{path}: unknown video extension ({got}); use one of {', '.join(VIDEO_SUFFIXES)}"
        )
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file name")
    return path


def _check_frames(frames: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Frames as a list of (H, W, 3) uint8 arrays of one shape, or a ValueError saying why."""
    out = [np.asarray(f) for f in frames]
    if not out:
        raise ValueError("save_video needs at least one frame, got none")
    shape = out[0].shape
    for n, f in enumerate(out):
        if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
            raise ValueError(f"frame {n} must be an (H, W, 3) uint8 array, got {f.dtype} {f.shape}")
        if f.shape != shape:
            raise ValueError(f"frame {n} has shape {f.shape}, frame 0 has {shape}")
    return out


def _write_gif(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """Animated, looping GIF through Pillow (GIF timing has 10 ms resolution)."""
    try:
        from PIL import Image
    except ImportError as e:  # pragma: no cover - matplotlib depends on Pillow
        raise RuntimeError("writing a GIF needs Pillow: pip install pillow") from e
    images = [Image.fromarray(f) for f in frames]
    images[0].save(
        path,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=max(round(1000.0 / fps), 10),
        loop=0,
    )


def _write_with_imageio(frames: list[np.ndarray], path: Path, fps: float) -> None:
    """mp4 and friends through imageio's ffmpeg plugin."""
    try:
        import imageio.v2 as imageio
    except ImportError as e:
        raise RuntimeError(
            f"writing {path.suffix} video needs imageio with ffmpeg "
            "(pip install 'imageio[ffmpeg]'); or save a .gif, which needs only Pillow"
        ) from e
    stack: Any = np.stack(frames)  # imageio's stubs want a list of its own array type
    imageio.mimwrite(path, stack, fps=fps)
