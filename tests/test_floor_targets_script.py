"""scripts/floor_targets.py: issue 42's targets counted per robot, the paired exchange effect."""

from __future__ import annotations

from typing import Any

from tests.scripts_module import load_script


def _episode(seed: int, nu: float, seen: float, nees_rel: float, coverage: float) -> dict[str, Any]:
    robot = {
        "nu_mean": nu, "map_precision": 0.95, "completeness_seen": seen, "duplicates": 0.0,
        "nees_rel": nees_rel,
    }  # fmt: skip
    return {
        "seed": seed,
        "steps": 1000,
        "team": {"coverage": coverage},
        "robots": {f"robot_{k}": dict(robot) for k in range(3)},
    }


def test_map_row__counts_each_target_at_its_bound_and_pairs_on_with_off() -> None:
    script = load_script("floor_targets")
    # seed 0 sits exactly on every bound (≤ 0.03 m, ≥ 0.8 counts as met); seed 1 misses
    # nu_mean and completeness_seen; the nees_rel slot means are (2 + 8) / 2 = 5 ≤ 6
    on = [_episode(0, 0.03, 0.8, 2.0, 0.85), _episode(1, 0.031, 0.79, 8.0, 0.84)]
    off = [_episode(1, 0.029, 0.69, 8.0, 0.9), _episode(0, 0.028, 0.7, 2.0, 0.9)]
    cells = [c.strip() for c in script.map_row("m", on, off).strip("|").split("|")]
    assert cells[:9] == ["m", "1000", "2", "3/6", "6/6", "3/6", "6/6", "5.00", "1/2"]
    # paired by seed: completeness +0.1 every robot (zero spread), nu_mean +2 mm every robot
    assert cells[9] == "+0.100 ± 0.000"
    assert cells[10] == "+2.00 ± 0.00"


def test_against__pairs_the_maps_both_studies_ran_by_seed() -> None:
    script = load_script("floor_targets")
    for ep in (a := [_episode(0, 0.02, 0.9, 2.0, 0.9), _episode(1, 0.04, 0.9, 2.0, 0.9)]):
        for r in ep["robots"].values():
            r["pose_error"] = 0.1
    base = {"episodes": {"m": {"exchange_on": [dict(a[1]), dict(a[0])]}, "other": {}}}
    this = {"episodes": {"m": {"exchange_on": a}, "only_here": {"exchange_on": a}}}
    rows = script.against(this, base).splitlines()[2:]
    # one map in common, one row per metric, each robot paired with itself: zero differences
    assert [r.split("|")[2].strip() for r in rows] == [f"`{m}`" for m in script.PAIRED]
    assert all("+0 ± 0" in r and r.rstrip("| ").endswith("6") for r in rows)
