"""Tests of the pygame renderer and the video writer (headless: SDL's dummy video driver)."""

from __future__ import annotations

import os

os.environ["SDL_VIDEODRIVER"] = "dummy"
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import subprocess
import sys
from pathlib import Path

import numpy as np
import pygame
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from polyslam_env.render.renderer import (
    BACKGROUND,
    COVERED,
    FAILED,
    MIN_ELLIPSE_PX,
    Renderer,
    dash_segments,
    ellipse_factor,
    ellipse_points,
    robot_color,
    save_video,
)
from polyslam_env.render.state import RenderState
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.maps import load_map

# smoothscale averages 2×2 blocks of the supersampled canvas; inside a uniformly coloured
# shape that average is the colour itself up to integer rounding, so 2 levels is ample.
COLOR_TOL = 2


@pytest.fixture(scope="module")
def layout() -> Layout:
    return load_map("paper")


def make_state(layout: Layout, *, active: np.ndarray | None = None, step: int = 7) -> RenderState:
    """Three robots at the paper map's start poses with small fake maps, paths and coverage."""
    rng = np.random.default_rng(3)
    poses = layout.start_poses.astype(float)  # (3, 3)
    n = len(poses)
    est = poses + np.array([0.03, -0.02, 0.01])  # (3, 3)
    covs = np.tile(np.diag([4e-4, 1e-4, 1e-5]), (n, 1, 1))  # (3, 3, 3)
    t = np.linspace(0.0, 1.0, 30)[:, None]
    maps = [
        [np.hstack([np.full_like(t, 0.05), 0.5 + 2.0 * t])],  # robot 0: along the west wall
        [np.hstack([2.5 + t, np.full_like(t, 0.05)]), np.hstack([np.full_like(t, 2.05), t])],
        [np.hstack([np.full_like(t, 5.95), 0.5 + t])],
    ]
    true_paths = [p[:2] + np.cumsum(rng.normal(0, 0.02, (20, 2)), axis=0) for p in poses]
    est_paths = [p + 0.01 for p in true_paths]
    coverage = np.zeros((40, 60), dtype=bool)  # 0.1 m cells over the 6 × 4 m map
    coverage[:20, :20] = True  # the south-west quarter, rows follow y
    return RenderState(
        true_poses=poses,
        est_poses_abs=est,
        est_covs_abs=covs,
        maps_abs=maps,
        true_paths=true_paths,
        est_paths=est_paths,
        links=[(1, 2)],
        coverage=coverage,
        coverage_origin=(0.0, 0.0),
        coverage_resolution=0.1,
        active=np.ones(n, dtype=bool) if active is None else active,
        step=step,
        info_text="coverage 12.3%",
    )


def pixel_window(
    img: np.ndarray, renderer: Renderer, xy: tuple[float, float], r: int
) -> np.ndarray:
    """The (2r+1, 2r+1, 3) patch of ``img`` around the pixel of world point ``xy``."""
    c, row = np.round(renderer.view(np.array(xy))).astype(int)
    return img[row - r : row + r + 1, c - r : c + r + 1].astype(int)


def has_color(patch: np.ndarray, color: tuple[int, int, int]) -> bool:
    return bool((np.abs(patch - np.array(color)).max(axis=-1) <= COLOR_TOL).any())


@pytest.fixture(scope="module")
def rgb_renderer(layout: Layout) -> Renderer:
    return Renderer(layout, 3, "rgb_array", WorldConfig())


@pytest.fixture(scope="module")
def frame(layout: Layout, rgb_renderer: Renderer) -> np.ndarray:
    img = rgb_renderer.render(make_state(layout))
    assert img is not None
    return img


def test_render_rgb_array__shape_and_dtype(rgb_renderer: Renderer, frame: np.ndarray) -> None:
    assert frame.dtype == np.uint8
    assert frame.shape == (rgb_renderer.height, rgb_renderer.width, 3)
    # 6 × 4 m paper map at size 720: the 6 m side spans 720 px with margins, legend below.
    assert rgb_renderer.width == 720
    assert rgb_renderer.width % 16 == 0 and rgb_renderer.height % 16 == 0


def test_render__walls_are_dark(rgb_renderer: Renderer, frame: np.ndarray) -> None:
    patch = pixel_window(frame, rgb_renderer, (4.0, 0.0), 1)  # south wall, no map over it
    assert patch.max(axis=-1).min() < 100  # a wall pixel: all channels dark (WALL is ~40)
    free = pixel_window(frame, rgb_renderer, (3.5, 1.0), 0)[0, 0]  # uncovered open floor
    assert tuple(free) == BACKGROUND


def test_render__robots_drawn_in_their_colours(rgb_renderer: Renderer, frame: np.ndarray) -> None:
    poses = rgb_renderer.layout.start_poses
    for i, (x, y, _) in enumerate(poses):
        assert has_color(pixel_window(frame, rgb_renderer, (x, y), 3), robot_color(i))
    # robot 1's colour does not appear at robot 0's pose: colours really are per robot
    assert not has_color(pixel_window(frame, rgb_renderer, tuple(poses[0, :2]), 3), robot_color(1))


def test_render__failed_robot_is_grey(layout: Layout, rgb_renderer: Renderer) -> None:
    img = rgb_renderer.render(make_state(layout, active=np.array([True, False, True])))
    assert img is not None
    x, y, _ = layout.start_poses[1]
    patch = pixel_window(img, rgb_renderer, (x, y), 3)
    assert has_color(patch, FAILED)
    assert not has_color(patch, robot_color(1))


def test_render__coverage_rows_follow_y(rgb_renderer: Renderer, frame: np.ndarray) -> None:
    # covered block is x, y ∈ [0, 2) × [0, 2): (1.5, 0.3) is inside, (1.5, 3.3) is not
    assert tuple(pixel_window(frame, rgb_renderer, (1.5, 0.3), 0)[0, 0]) == COVERED
    assert tuple(pixel_window(frame, rgb_renderer, (1.5, 3.3), 0)[0, 0]) == BACKGROUND


def test_render__map_polylines_in_robot_colour(rgb_renderer: Renderer, frame: np.ndarray) -> None:
    # robot 1's second polyline runs along x = 2.05; walls are drawn over maps, so look beside
    # the wall at x = 2.0, on the band's east edge
    patch = pixel_window(frame, rgb_renderer, (2.07, 0.5), 2)
    assert has_color(patch, robot_color(1))


def test_render__same_state_gives_identical_frames(layout: Layout, frame: np.ndarray) -> None:
    other = Renderer(layout, 3, "rgb_array", WorldConfig())
    first, second = other.render(make_state(layout)), other.render(make_state(layout))
    assert first is not None and second is not None
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first, frame)


def test_render__step_changes_the_legend_only(
    layout: Layout, rgb_renderer: Renderer, frame: np.ndarray
) -> None:
    img = rgb_renderer.render(make_state(layout, step=12345))
    assert img is not None
    top = rgb_renderer.map_height
    np.testing.assert_array_equal(img[:top], frame[:top])
    if rgb_renderer._fonts is not None:  # the text differs only when fonts are available
        assert not np.array_equal(img[top:], frame[top:])


def test_render__wrong_robot_count_is_rejected(layout: Layout) -> None:
    renderer = Renderer(layout, 2, "rgb_array", WorldConfig())
    with pytest.raises(ValueError, match="3 robots"):
        renderer.render(make_state(layout))


def test_renderer__bad_mode_is_rejected(layout: Layout) -> None:
    with pytest.raises(ValueError, match="render_mode"):
        Renderer(layout, 3, "ansi", WorldConfig())


def test_render__without_fonts_still_draws(
    layout: Layout, frame: np.ndarray, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_font(*_args: object) -> None:
        raise pygame.error("no fonts here")

    monkeypatch.setattr(pygame.font, "Font", no_font)
    renderer = Renderer(layout, 3, "rgb_array", WorldConfig())
    img = renderer.render(make_state(layout))
    assert renderer._fonts is None
    assert img is not None and img.shape[1:] == frame.shape[1:]  # legend strip is shorter
    # robot labels are the only map-area difference: west of the robots the pixels match,
    # and the legend strip is left blank
    top = renderer.map_height
    np.testing.assert_array_equal(img[:top, :60], frame[:top, :60])
    assert (img[top + 2 :] == img[top + 2, 0]).all()


def test_render_human__runs_headless_and_close_is_idempotent(layout: Layout) -> None:
    renderer = Renderer(layout, 3, "human", WorldConfig())
    assert renderer.render(make_state(layout)) is None
    assert pygame.display.get_surface() is not None
    renderer.close()
    renderer.close()
    assert pygame.display.get_surface() is None


def test_render_human__window_quit_stops_drawing(layout: Layout) -> None:
    renderer = Renderer(layout, 3, "human", WorldConfig())
    renderer.render(make_state(layout))
    pygame.event.post(pygame.event.Event(pygame.QUIT))
    assert renderer.render(make_state(layout)) is None
    assert pygame.display.get_surface() is None  # window closed on QUIT ...
    assert renderer.render(make_state(layout)) is None
    assert pygame.display.get_surface() is None  # ... and not reopened by later renders
    renderer.close()


def test_import__does_not_load_pygame() -> None:
    code = (
        "import sys, polyslam_env, polyslam_env.render.renderer; assert 'pygame' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_ellipse_points__axes_match_covariance() -> None:
    pts = ellipse_points(np.array([1.0, 2.0, 0.0]), np.diag([4.0, 1.0, 9.0]), 2.0)
    assert pts is not None
    # 2σ semi-axes are 4 (x) and 2 (y); the 48 vertices include the axis ends exactly
    np.testing.assert_allclose(np.abs(pts - [1.0, 2.0]).max(axis=0), [4.0, 2.0], rtol=1e-12)
    assert ellipse_points(np.zeros(3), np.zeros((3, 3)), 2.0) is None


def test_ellipse_factor__makes_small_ellipses_visible(
    layout: Layout, rgb_renderer: Renderer
) -> None:
    state = make_state(layout)
    px = rgb_renderer.view.scale
    factor = ellipse_factor(state, px)
    largest = 2.0 * np.sqrt(4e-4) * px  # 2σ of the larger variance in make_state, pixels
    assert factor * largest >= MIN_ELLIPSE_PX
    assert factor == 1.0 or factor / 2.5 * largest < MIN_ELLIPSE_PX  # smallest 1-2-5 step
    big = make_state(layout)
    big.est_covs_abs[:] = np.diag([1.0, 1.0, 1.0])
    assert ellipse_factor(big, px) == 1.0


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-500, 500), st.floats(-500, 500)), min_size=2, max_size=12),
    st.floats(1.0, 20.0),
    st.floats(1.0, 20.0),
)
def test_dash_segments__cover_the_on_fraction(
    vertices: list[tuple[float, float]], on: float, off: float
) -> None:
    pts = np.array(vertices)  # (k, 2)
    total = float(np.hypot(*np.diff(pts, axis=0).T).sum())
    dashes = dash_segments(pts, on, off)  # (D, 2, 2)
    drawn = float(np.hypot(*(dashes[:, 1] - dashes[:, 0]).T).sum())
    period = on + off
    full = np.floor(total / period)
    # whole periods contribute exactly `on`; the last partial period up to `on`; 1e-6 relative
    # slack covers float rounding in the cumulative arclengths
    slack = 1e-6 * max(total, 1.0)
    assert full * on - slack <= drawn <= full * on + on + slack


def test_save_video__gif_has_every_frame(tmp_path: Path) -> None:
    frames = [np.full((32, 48, 3), 40 * i, dtype=np.uint8) for i in range(5)]  # distinct
    path = save_video(frames, tmp_path / "out" / "clip.gif", fps=5)
    assert path.stat().st_size > 0
    with Image.open(path) as gif:
        assert gif.n_frames == 5
        assert gif.size == (48, 32)
        assert gif.info["duration"] == 200  # ms per frame at 5 fps
    assert [p.name for p in path.parent.iterdir()] == ["clip.gif"]  # no temp file left


def test_save_video__rejects_bad_frames(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="at least one frame"):
        save_video([], tmp_path / "a.gif")
    with pytest.raises(ValueError, match="frame 1"):
        save_video(
            [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8)], tmp_path / "b.gif"
        )
    with pytest.raises(ValueError, match="uint8"):
        save_video([np.zeros((4, 4, 3))], tmp_path / "c.gif")
    assert list(tmp_path.iterdir()) == []


def test_save_video__mp4_without_imageio_says_how(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Hide imageio even where it is installed: None in sys.modules makes its import fail.
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(RuntimeError, match="imageio"):
        save_video([np.zeros((16, 16, 3), np.uint8)], tmp_path / "clip.mp4")
    assert list(tmp_path.iterdir()) == []


def test_save_video__mp4_through_imageio(tmp_path: Path) -> None:
    import imageio.v2 as imageio  # the ``video`` extra, installed by CI

    frames = [np.full((32, 48, 3), 40 * i, dtype=np.uint8) for i in range(4)]
    path = save_video(frames, tmp_path / "clip.mp4", fps=4)
    back = imageio.mimread(path)
    assert len(back) == 4 and back[0].shape == (32, 48, 3)


def test_legend__names_robots_as_the_env_does() -> None:
    from polyslam_env.environment.parallel import parallel_env
    from polyslam_env.render.renderer import legend_items

    env = parallel_env(map="two_rooms", num_robots=3)
    dots = [item.label for item in legend_items(3, "2σ ellipse", False) if item.kind == "dot"]
    assert dots == env.possible_agents == ["robot_0", "robot_1", "robot_2"]
