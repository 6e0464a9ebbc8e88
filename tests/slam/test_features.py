"""The robot's pillar map used for aligning maps (``slam/features.py``)."""

from __future__ import annotations

import numpy as np

from polyslam_env.core.geometry import wrap_angle
from polyslam_env.slam.features import FeatureBook


def _observe(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact (range, bearing) (m, 2) of points (m, 2) from pose (3,)."""
    d = points - pose[:2]
    return np.column_stack(
        [np.hypot(d[:, 0], d[:, 1]), wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2])]
    )


def test_exact_sightings__place_pillars_where_they_are() -> None:
    rng = np.random.default_rng(0)
    pillars = rng.uniform(-5, 5, size=(6, 2))
    desc = rng.normal(size=(6, 8))
    book = FeatureBook(8)
    for _ in range(5):
        pose = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi)])
        ids = np.sort(rng.choice(6, size=4, replace=False))
        book.add(pose, ids, _observe(pose, pillars[ids]), desc[ids])
    fmap = book.feature_map()
    seen = sorted(book._slot, key=book._slot.__getitem__)  # ids in order of first sighting
    assert len(fmap) == len(seen) == len(book)
    np.testing.assert_allclose(fmap.positions, pillars[seen], atol=1e-12)
    np.testing.assert_allclose(fmap.descriptors, desc[seen], atol=1e-12)


def test_means_and_min_sightings() -> None:
    """A feature is the mean of its placements and descriptors; rarely seen ones are held
    back."""
    book = FeatureBook(2)
    origin = np.zeros(3)
    book.add(origin, np.array([7]), np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]]))
    book.add(origin, np.array([7, 3]), np.array([[3.0, 0.0], [2.0, np.pi / 2]]),
             np.array([[3.0, 2.0], [5.0, 5.0]]))  # fmt: skip
    both = book.feature_map()
    np.testing.assert_allclose(both.positions, [[2.0, 0.0], [0.0, 2.0]], atol=1e-15)
    np.testing.assert_allclose(both.descriptors, [[2.0, 1.0], [5.0, 5.0]])
    only = book.feature_map(min_sightings=2)
    np.testing.assert_allclose(only.positions, [[2.0, 0.0]], atol=1e-15)
    assert len(book.feature_map(min_sightings=3)) == 0


def test_grows_past_its_first_allocation_and_ignores_empty_sweeps() -> None:
    book = FeatureBook(1)
    pose = np.array([1.0, -2.0, 0.3])
    book.add(pose, np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros((0, 1)))
    assert len(book) == 0
    points = np.column_stack([np.arange(40.0), np.ones(40)])
    book.add(pose, np.arange(40), _observe(pose, points), np.arange(40.0)[:, None])
    fmap = book.feature_map()
    np.testing.assert_allclose(fmap.positions, points, atol=1e-12)
    # placements are in the robot's frame: seen from another pose, the same points land at
    # the same place
    moved = np.array([0.5, 0.5, -1.0])
    book2 = FeatureBook(1)
    book2.add(moved, np.arange(40), _observe(moved, points), np.arange(40.0)[:, None])
    np.testing.assert_allclose(book2.feature_map().positions, points, atol=1e-12)
