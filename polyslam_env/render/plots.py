"""Pictures of SLAM results, in the style of the paper's Figs 5–8 (matplotlib, no window).

Per robot: true walls red, the robot's polynomials (moved to the absolute frame through its
known start pose) green, true path blue, estimated path dashed red.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from polyslam_env import metrics
from polyslam_env.core.geometry import transform_points
from polyslam_env.core.names import robot_name
from polyslam_env.world.layout import Layout

if TYPE_CHECKING:
    from polyslam_env.metrics.episode import RobotRun


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: str | Path, dpi: int) -> Path:  # type: ignore[no-untyped-def]
    """Lay out ``fig``, write it as a PNG at ``path`` (folders made) and close it."""
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out


def draw_layout(ax, layout: Layout) -> None:  # type: ignore[no-untyped-def]
    """True walls (red) and pillars."""
    for wall in layout.walls:
        ax.plot(wall[:, 0], wall[:, 1], color="tab:red", lw=1.2, zorder=1)
    for x, y, r in layout.pillars:
        t = np.linspace(0, 2 * np.pi, 48)
        ax.plot(x + r * np.cos(t), y + r * np.sin(t), color="tab:red", lw=1.2, zorder=1)
    x0, y0, x1, y1 = layout.bounds
    pad = 0.3
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - pad, y1 + pad)
    ax.set_aspect("equal")


def plot_layouts(
    layouts: Sequence[tuple[str, Layout]], path: str | Path, dpi: int = 80, columns: int = 3
) -> Path:
    """Layouts (title, layout) side by side: walls black, pillars, start poses as red
    arrows; axes in metres."""
    plt = _pyplot()
    n = len(layouts)
    cols = min(columns, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 4.2 * rows), squeeze=False)
    for ax, (title, layout) in zip(axes.ravel(), layouts, strict=False):
        for wall in layout.walls:
            ax.plot(wall[:, 0], wall[:, 1], color="k", lw=0.8)
        for x, y, r in layout.pillars:
            ax.add_patch(plt.Circle((x, y), r, color="k"))
        for x, y, th in layout.start_poses:
            ax.annotate("", xy=(x + 0.8 * np.cos(th), y + 0.8 * np.sin(th)), xytext=(x, y),
                        arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 1.2})  # fmt: skip
            ax.plot(x, y, "o", color="tab:red", ms=3)
        x0, y0, x1, y1 = layout.bounds
        ax.set_xlim(x0 - 0.5, x1 + 0.5)
        ax.set_ylim(y0 - 0.5, y1 + 0.5)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    return _save(plt, fig, path, dpi)


def draw_robot_map(ax, run, color: str = "tab:green") -> None:  # type: ignore[no-untyped-def]
    """One robot's polynomials, true path and estimated path, in the absolute frame, placed
    by the robot's true start (as the map metrics place them: the frame's offset from the
    true start is unobservable)."""
    sp = run.true_poses[0]
    for poly in run.polynomials:
        pts = transform_points(poly.sample_arclength(0.01), sp)
        ax.plot(pts[:, 0], pts[:, 1], color=color, lw=2.2, zorder=3)
    ax.plot(run.true_poses[:, 0], run.true_poses[:, 1], color="tab:blue", lw=1.0, zorder=2)
    est = metrics.pose_to_absolute(run.est_poses, sp)
    ax.plot(est[:, 0], est[:, 1], "--", color="tab:red", lw=1.0, zorder=2)
    ax.plot(*run.true_poses[0, :2], "o", color="tab:blue", ms=4)


def plot_runs(
    layout: Layout,
    runs: Sequence,  # Sequence[RobotRun]
    path: str | Path,
    titles: Sequence[str] | None = None,
) -> Path:
    """One panel per robot (paper Figs 5–7); saves a PNG and returns its path."""
    plt = _pyplot()
    n = max(len(runs), 1)
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    x0, y0, x1, y1 = layout.bounds
    aspect = (y1 - y0 + 0.6) / (x1 - x0 + 0.6)
    fig, axes = plt.subplots(
        rows, cols, figsize=(5.2 * cols, 5.2 * cols * aspect * rows / cols + 0.6)
    )
    axes = np.atleast_1d(axes).ravel()
    for i, ax in enumerate(axes):
        if i >= len(runs):
            ax.axis("off")
            continue
        draw_layout(ax, layout)
        draw_robot_map(ax, runs[i])
        ax.set_title(titles[i] if titles else robot_name(i), fontsize=10)
        ax.tick_params(labelsize=7)
    fig.suptitle(
        "green: mapped polynomials · red: true walls · blue: true path · dashed red: estimate",
        fontsize=9,
    )
    return _save(plt, fig, path, 110)


def plot_map_errors(
    layout: Layout,
    run: RobotRun,
    path: str | Path,
    title: str,
    tol: float = 0.05,
) -> Path:
    """One robot's map over the true walls, placed by its true start as the map metrics place
    it: the stretches farther than ``tol`` from a true wall (what ``map_precision`` counts as
    wrong) orange, the rest green; its true path coloured by step (where it was when it mapped
    a stretch) and its estimated path dashed. Saves a PNG and returns its path."""
    plt = _pyplot()
    x0, y0, x1, y1 = layout.bounds
    width = 10.0
    fig, ax = plt.subplots(figsize=(width, width * (y1 - y0 + 0.6) / (x1 - x0 + 0.6) + 0.9))
    draw_layout(ax, layout)
    start = run.true_poses[0]
    points = metrics.map_points(run.polynomials, start)
    for pts in points:
        off = metrics.distance_to_boundary(pts, layout) > tol
        good = np.where(off[:, None], np.nan, pts)
        bad = np.where(off[:, None], pts, np.nan)
        ax.plot(good[:, 0], good[:, 1], color="tab:green", lw=2.2, zorder=3)
        ax.plot(bad[:, 0], bad[:, 1], color="tab:orange", lw=3.0, zorder=4)
    steps = np.arange(len(run.true_poses))
    dots = ax.scatter(
        run.true_poses[:, 0], run.true_poses[:, 1], c=steps, s=3, cmap="viridis", zorder=2
    )
    est = metrics.pose_to_absolute(run.est_poses, start)
    ax.plot(est[:, 0], est[:, 1], "--", color="0.4", lw=0.6, zorder=2)
    fig.colorbar(dots, ax=ax, label="step (true path)", shrink=0.8)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    return _save(plt, fig, path, 100)


def plot_learning_curve(steps: np.ndarray, values: np.ndarray, path: str | Path) -> Path:
    """Team coverage (N,) against training timesteps (N,), with a running mean over 10 points;
    a PNG at ``path``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.plot(steps, values, ".", color="tab:blue", alpha=0.35, label="per logging interval")
    if len(values) >= 10:
        mean = np.convolve(values, np.ones(10) / 10, mode="valid")
        ax.plot(steps[9:], mean, color="tab:blue", label="running mean of 10")
    ax.set_xlabel("timesteps (robot-decisions or robot-steps)")
    ax.set_ylabel("team coverage at episode end")
    ax.set_ylim(0.0, 1.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    return _save(plt, fig, path, 100)
