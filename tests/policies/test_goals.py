"""Goal choice: candidates against brute force, slot 0 is the frontier's goal, features from
observations only, decisions on schedule."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import pytest

import polyslam_env
from policies.base import PolicyContext, PolicyError
from policies.frontier import Search
from policies.goals import CANDIDATES, FEATURES, GLOBALS, GoalPolicy, feature_size, region_best

OFFICE = {"map": "generator:office_floor", "num_robots": 3, "max_steps": 400}


class _Scripted(GoalPolicy):
    """Picks slots from a list, cycling; records every decision's features and search."""

    def __init__(self, context: PolicyContext, slots: list[int]) -> None:
        super().__init__(context)
        self.slots = slots
        self.decisions: list[tuple[np.ndarray, Search | None, tuple[int, int] | None]] = []

    def choose(self, features: np.ndarray, rng: np.random.Generator) -> int:
        slot = self.slots[len(self.decisions) % len(self.slots)]
        self.decisions.append((features, self._search_now, None))
        return slot

    def commit(self, slot: int) -> None:
        super().commit(slot)
        f, s, _ = self.decisions[-1]
        self.decisions[-1] = (f, s, self.goal)


def _episode(slots: list[int], seed: int, steps: int) -> tuple[Any, dict[str, _Scripted]]:
    env = polyslam_env.parallel_env(**OFFICE)
    obs, _ = env.reset(seed=seed)
    team = {a: _Scripted(PolicyContext.from_env(env, a), slots) for a in env.possible_agents}
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        if not env.agents:
            break
        obs, *_ = env.step({a: team[a].act(obs[a], rng) for a in env.agents})
    return env, team


def _components(mask: np.ndarray) -> np.ndarray:
    """8-connected component labels of ``mask`` by breadth-first search (the oracle)."""
    labels = np.zeros(mask.shape, dtype=int)
    n = 0
    for start in zip(*np.nonzero(mask), strict=True):
        if labels[start]:
            continue
        n += 1
        labels[start] = n
        queue = deque([start])
        while queue:
            r, c = queue.popleft()
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    q = (r + dr, c + dc)
                    inside = 0 <= q[0] < mask.shape[0] and 0 <= q[1] < mask.shape[1]
                    if inside and mask[q] and not labels[q]:
                        labels[q] = n
                        queue.append(q)
    return labels


@pytest.fixture(scope="module")
def played() -> dict[str, _Scripted]:
    """Robots choosing slots 0, 2, 1, 5, 3 in turn for 120 steps of an office floor."""
    return _episode([0, 2, 1, 5, 3], seed=3, steps=120)[1]


def test_goals__candidates_are_the_best_cell_of_distinct_frontier_regions(
    played: dict[str, _Scripted],
) -> None:
    checked = 0
    for policy in played.values():
        for features, search, _ in policy.decisions:
            if search is None:
                continue
            labels = _components(search.frontier)
            slots = features[: CANDIDATES * len(FEATURES)].reshape(CANDIDATES, len(FEATURES))
            valid = slots[:, 0] > 0.5
            n_valid = int(valid.sum())
            # valid slots first, then empty (all-zero) ones
            assert valid[:n_valid].all() and not slots[n_valid:].any()
            finite = [
                k
                for k in range(1, labels.max() + 1)
                if np.isfinite(search.utility[labels == k]).any()
            ]
            assert n_valid == min(CANDIDATES, len(finite))
            best = sorted((-float(search.utility[labels == k].max()), k) for k in finite)
            # utilities: the regions' maxima, best first, relative to the best (the features
            # are float32: rtol 1e-6 is a few float32 roundings, eps 6e-8)
            expected = [-u / -best[0][0] for u, _ in best[:n_valid]]
            np.testing.assert_allclose(slots[:n_valid, 7], expected, rtol=1e-6)
            checked += 1
    assert checked >= 20


def test_goals__slot_0_is_the_frontier_policys_own_goal(played: dict[str, _Scripted]) -> None:
    for policy in played.values():
        for k, (_, search, goal) in enumerate(policy.decisions):
            if search is None or policy.slots[k % len(policy.slots)] != 0:
                continue
            r, c = search.best()
            assert goal == (r + search.window[0].start, c + search.window[1].start)


def test_goals__chosen_slot_is_the_goal_driven_to(played: dict[str, _Scripted]) -> None:
    # the committed goal is the chosen slot's region's best cell (or slot 0's when the
    # chosen slot is empty)
    for policy in played.values():
        for k, (features, search, goal) in enumerate(policy.decisions):
            if search is None:
                continue
            labels = _components(search.frontier)
            slot = policy.slots[k % len(policy.slots)]
            n_valid = int(features[: CANDIDATES * len(FEATURES) : len(FEATURES)].sum())
            slot = slot if slot < n_valid else 0
            assert goal is not None
            r, c = goal[0] - search.window[0].start, goal[1] - search.window[1].start
            region = labels == labels[r, c]
            assert search.utility[r, c] == search.utility[region].max()
            rank = sorted(
                -float(search.utility[labels == k].max()) for k in range(1, labels.max() + 1)
            )
            assert -float(search.utility[r, c]) == rank[slot]


def test_goals__features_within_the_observation_bounds(played: dict[str, _Scripted]) -> None:
    for policy in played.values():
        for features, _, _ in policy.decisions:
            assert features.shape == (feature_size(),) and features.dtype == np.float32
            assert features.min() >= -1.0 and features.max() <= 3.0
    assert feature_size() == CANDIDATES * len(FEATURES) + len(GLOBALS)


def test_goals__decisions_every_decide_every_steps(played: dict[str, _Scripted]) -> None:
    # 120 steps with decisions at steps 1, 9, ..., 113: 15 of them
    assert {len(p.decisions) for p in played.values()} == {15}


def test_goals__same_seed_same_episode() -> None:
    runs = [_episode([0, 1, 4], seed=7, steps=60)[0] for _ in range(2)]
    a, b = (r.episode.world.poses for r in runs)
    assert np.array_equal(a, b)


def test_goals__decide_every_must_be_positive() -> None:
    env = polyslam_env.parallel_env(**OFFICE)
    with pytest.raises(PolicyError, match="decide_every"):
        GoalPolicy(PolicyContext.from_env(env, "robot_0"), decide_every=0)


@pytest.mark.parametrize("seed", range(5))
def test_region_best__each_regions_largest_value_first_among_ties_as_brute_force(
    seed: int,
) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    labels = rng.integers(0, n + 1, 300)
    labels[:n] = np.arange(1, n + 1)  # every label present, as ndimage.label numbers them
    # few distinct values, so most regions have ties at their best; -inf as off-candidate cells
    values = rng.choice([-np.inf, 0.1, 0.2, 0.3], 300)
    flat, best = region_best(labels, values)
    for k in range(1, n + 1):
        cells = np.flatnonzero(labels == k)
        top = values[cells].max()
        assert flat[k - 1] == next(int(c) for c in cells if values[c] == top)
        assert best[k - 1] == top
