"""The free space that vetoes wrong alignments (comms/free_space.py): cells crossed by beams,
short of each return by the margin, away from the robot's own walls; it grows with the robot."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from polyslam_env.comms.free_space import FreeSpace

ANGLES = np.linspace(-np.pi, np.pi, 360, endpoint=False)


def _ring(radius: float, n: int = 720, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([np.cos(phi), np.sin(phi)]) * radius + np.asarray(centre)


def test_free_space__crossed_cells_not_the_margin_nor_beyond_the_return() -> None:
    """A robot at the origin inside a round room of radius 3 m: points at 1 and 2 m are in free
    space; points at 2.85 m (within the 0.3 m margin of the wall), on the wall and beyond it are
    not; beams without return (inf) free their whole max range (3600 of them: at 7.5 m they
    are 1.3 cm apart, so every cell on the ring is crossed)."""
    space = FreeSpace(0.1, 0.3, 8.0)
    space.add(np.zeros(3), np.full(len(ANGLES), 3.0), ANGLES)
    nothing = None
    assert space.conflict(_ring(1.0), nothing) == 1.0
    assert space.conflict(_ring(2.0), nothing) == 1.0
    for radius in (2.85, 3.0, 3.5, 20.0):
        assert space.conflict(_ring(radius), nothing) == 0.0, radius
    open_space = FreeSpace(0.1, 0.3, 8.0)
    dense = np.linspace(-np.pi, np.pi, 3600, endpoint=False)
    open_space.add(np.zeros(3), np.full(len(dense), np.inf), dense)
    assert open_space.conflict(_ring(7.5), nothing) == 1.0


def test_free_space__points_near_own_walls_are_not_conflicts() -> None:
    """A grazing beam crosses cells its own wall runs through: a received point within the
    margin of one of the robot's walls is not a conflict, one further away is."""
    space = FreeSpace(0.1, 0.3, 8.0)
    space.add(np.zeros(3), np.full(len(ANGLES), 3.0), ANGLES)
    own = cKDTree(_ring(1.0, 2000))
    assert space.conflict(_ring(1.0) * 1.01, own) == 0.0
    assert space.conflict(_ring(1.5), own) == 1.0
    half = np.vstack([_ring(1.0, 100) * 1.02, _ring(1.6, 100)])
    assert space.conflict(half, own) == pytest.approx(0.5)


def test_free_space__grows_to_every_side_and_keeps_what_it_had() -> None:
    """Scans from far apart poses (all four directions of growth): every earlier room stays
    free, and the grid only grows."""
    space = FreeSpace(0.1, 0.3, 8.0)
    centres = [(0.0, 0.0), (30.0, 0.0), (-25.0, 12.0), (5.0, -40.0)]
    shapes = []
    for k, centre in enumerate(centres):
        space.add(np.array([*centre, 0.3 * k]), np.full(len(ANGLES), 2.0), ANGLES)
        shapes.append(space.cells.shape)
        for earlier in centres[: k + 1]:
            assert space.conflict(_ring(1.0, centre=earlier), None) == 1.0
    assert all(a[0] <= b[0] and a[1] <= b[1] for a, b in itertools.pairwise(shapes))
    assert space.conflict(_ring(1.0, centre=(100.0, 100.0)), None) == 0.0


def test_free_space__clear_of_walls_drops_the_cells_near_them() -> None:
    """clear_of keeps a crossed cell exactly when its centre is further than the margin from
    every wall point (brute force over all cells)."""
    space = FreeSpace(0.1, 0.3, 8.0)
    space.add(np.zeros(3), np.full(len(ANGLES), 3.0), ANGLES)
    walls = _ring(1.2, 400, centre=(0.5, -0.4))
    corner, clear = space.clear_of(walls)
    rows, cols = np.indices(space.cells.shape)
    centres = (np.stack([cols, rows], axis=-1) + np.asarray(corner) + 0.5) * 0.1  # (R, C, 2)
    near = np.hypot(*(centres[:, :, None, :] - walls[None, None]).transpose(3, 0, 1, 2))
    expected = space.cells & (near.min(axis=2) > 0.3)
    np.testing.assert_array_equal(clear, expected)
    assert 0 < clear.sum() < space.cells.sum()


def test_free_space__sent_as_changes_rebuilds_the_senders_clear_cells() -> None:
    """What a sender's messages carry (the changes between its cells clear of its walls and
    what the receiver holds) rebuilds the sender's clear cells in the receiver's copy, cell for
    cell, while cells appear (new scans) and vanish (walls mapped later); a message without a
    change carries nothing, and undoing a lost message's changes keeps both copies equal."""
    sender, sent, heard = (FreeSpace(0.1, 0.3, 8.0) for _ in range(3))
    rng = np.random.default_rng(11)
    walls = np.zeros((0, 2))
    before: set[tuple[int, int]] = set()
    vanished = 0
    for k in range(8):
        pose = np.array([*rng.uniform(-20.0, 20.0, 2), rng.uniform(-np.pi, np.pi)])
        sender.add(pose, rng.uniform(0.5, 4.0, len(ANGLES)), ANGLES)
        walls = np.vstack([walls, _ring(0.8, 200, centre=tuple(rng.uniform(-20.0, 20.0, 2)))])
        clear = sender.clear_of(walls)
        vanished += len(before - _clear_cells(clear))
        before = _clear_cells(clear)
        changes = sent.changes(clear)
        assert changes[1].any()
        sent.toggle(*changes)
        if k == 3:  # lost: the sender undoes it, and the next message carries it again
            sent.toggle(*changes)
            continue
        heard.toggle(*changes)
        assert _lattice_cells(heard) == _lattice_cells(sent) == _clear_cells(clear)
    assert not sent.changes(sender.clear_of(walls))[1].any()
    assert vanished > 0


def _clear_cells(block: tuple[tuple[int, int], np.ndarray]) -> set[tuple[int, int]]:
    (col, row), cells = block
    rows, cols = np.nonzero(cells)
    return set(zip((cols + col).tolist(), (rows + row).tolist(), strict=True))


def _lattice_cells(space: FreeSpace) -> set[tuple[int, int]]:
    """The free cells as lattice indices (col, row): cells of the resolution, a corner at 0."""
    corner = np.rint(space.origin / space.resolution).astype(int)  # (col, row) of cell [0, 0]
    rows, cols = np.nonzero(space.cells)
    return set(zip((cols + corner[0]).tolist(), (rows + corner[1]).tolist(), strict=True))
