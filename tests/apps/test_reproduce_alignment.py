"""``polyslam reproduce --paper alignment`` end to end on a small setting."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from polyslam_env.apps.reproduce_alignment import (
    METHODS,
    AlignmentReproduceConfig,
    protocol_config,
    protocol_of,
    reproduce,
    robot_descriptors,
    run_one,
    summarise,
)
from polyslam_env.cli.main import main
from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.alignment.aligners import candidate_matches

#: Two robots 50 m apart driving 40 m towards and past each other: maps that share many
#: landmarks after a few seconds of driving.
SHORT_WORLD = AlignmentReproduceConfig().world.replace(
    speeds=(4.0, 4.0), paths=(((0.0, 0.0), (40.0, 0.0)), ((50.0, 10.0), (10.0, 10.0)))
)


def test_run_one__same_seed_same_records() -> None:
    cfg = AlignmentReproduceConfig(runs=1, stages=2)
    a, b = run_one(cfg, 3), run_one(cfg, 3)
    strip = [{k: v for k, v in r.items() if k != "time_s"} for r in a]
    assert strip == [{k: v for k, v in r.items() if k != "time_s"} for r in b]
    assert {r["method"] for r in a} == set(METHODS)


def test_summary__maps_sharing_nothing_decline_and_grown_maps_align() -> None:
    """The robots start 150 m apart (range 30 m): at the first of 7 stages their maps share
    no landmark and every aligner declines; at the last every accepted RANSAC alignment is
    right (within 1 m and 3°)."""
    cfg = AlignmentReproduceConfig(runs=2)
    summary = summarise(cfg, reproduce(cfg, workers=1))
    for method in METHODS:
        assert summary["table"][method]["stages"][0]["accepted"] == 0.0
    last = summary["table"]["ransac"]["stages"][-1]
    assert last["accepted"] > 0 and last["wrong"] == 0.0
    assert summary["protocol"] == "guarded"
    assert summary["descriptor_wrong_match_rate"]["measured"] == 0.0
    assert all(isinstance(v, bool) for v in summary["checks"].values())


def test_cli__writes_summary_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(
        [
            "reproduce",
            "--paper",
            "alignment",
            "--runs",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary["table"]) == set(METHODS) and summary["runs"] == 1
    assert summary["protocol"] == "guarded"
    assert (tmp_path / "figs3-5_errors.png").stat().st_size > 0
    assert (tmp_path / "fig6_time.png").stat().st_size > 0
    assert "check ransac_most_accurate_at_largest_maps" in capsys.readouterr().out


def test_config__same_robot_twice__is_a_named_error() -> None:
    with pytest.raises(ConfigError, match="robots"):
        AlignmentReproduceConfig(robots=(1, 1))


def test_cli__seif_reproduction_writes_summary(tmp_path: Path) -> None:
    """``--paper seif`` on one run: the summary's table and boolean checks."""
    code = main(
        [
            "reproduce",
            "--paper",
            "seif",
            "--runs",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 1 and summary["pieces"] == 8
    assert all(isinstance(v, bool) for v in summary["checks"].values())
    assert summary["table"]["wrong_collapses"] == 0


def test_protocols__presets_and_their_names() -> None:
    guarded, seed = protocol_config("guarded"), protocol_config("seed")
    assert guarded == AlignmentReproduceConfig()  # the default stays the guarded protocol
    assert (seed.slam.particles, seed.map_estimate) == (100, "best_particle")
    assert (seed.align.refinement, seed.align.declines) == ("own", "seed")
    assert seed.descriptor_confusion == 0.25 and seed.align.min_support == 20
    assert protocol_of(seed) == "seed" and protocol_of(guarded) == "guarded"
    assert protocol_of(seed.replace(descriptor_confusion=0.3)) == "custom"
    with pytest.raises(ConfigError, match="protocol"):
        protocol_config("paper")
    with pytest.raises(ConfigError, match="descriptor_confusion"):
        AlignmentReproduceConfig(descriptor_confusion=1.5)


def test_descriptors__confusions_are_nested_and_at_the_stated_rate() -> None:
    """A robot's descriptor of a landmark is another landmark's with probability p: over
    3000 landmarks the share lies within 4 binomial standard deviations of p; a landmark
    confused at p = 0.1 is confused the same way at p = 0.5."""
    config = AlignmentReproduceConfig(descriptor_sigma=0.0, confusion_sweep=(0.1, 0.5))
    described = robot_descriptors(config, seed=0, landmarks=3000)
    truth = described[0.0][0]
    for p in (0.1, 0.5):
        for desc in described[p]:
            confused = np.any(desc != truth, axis=1)
            assert abs(confused.mean() - p) < 4 * np.sqrt(p * (1 - p) / 3000)
    low, high = described[0.1][0], described[0.5][0]
    moved = np.any(low != truth, axis=1)
    np.testing.assert_array_equal(low[moved], high[moved])


def test_seed_protocol__declines_only_ransac_by_support_and_counts_wrong_matches() -> None:
    """The seed's protocol (10 particles to stay fast) on two short runs: every declined
    answer is RANSAC's, for too few supports; the recorded wrong descriptor matches equal a
    direct count; the summary has the protocol, the rate and the per-stage table."""
    config = protocol_config("seed").replace(
        runs=2, stages=3, world=SHORT_WORLD, confusion_sweep=()
    )
    config = config.replace(slam=config.slam.replace(particles=10))
    records = reproduce(config, workers=1)
    declined = [r for r in records if not r["accepted"] and "descriptor matches" not in r["reason"]]
    assert declined and all(r["method"] == "ransac" for r in declined)
    assert all("supports <" in r["reason"] for r in declined)
    assert any(r["accepted"] for r in records if r["method"] != "ransac")
    summary = summarise(config, records)
    assert summary["protocol"] == "custom"  # 10 particles, not the seed's 100
    rate = summary["descriptor_wrong_match_rate"]
    assert rate["confusion"] == 0.25 and 0 < rate["measured"] < 1
    matched = sum(r["matches"] for r in records if r["method"] == "ransac")
    wrong = sum(r["wrong_matches"] for r in records if r["method"] == "ransac")
    assert rate["measured"] == pytest.approx(wrong / matched)
    for method in METHODS:
        cells = summary["table"][method]
        assert len(cells["stages"]) == 3 and "position_error_std" in cells["all_stages"]


def test_run_one__wrong_matches_are_matches_between_different_landmarks() -> None:
    """The record's count against a direct pairing of the maps' landmark ids."""
    from polyslam_env.apps.reproduce_alignment import _maps_at_stages
    from polyslam_env.slam.alignment import FeatureMap

    config = protocol_config("seed").replace(runs=1, stages=2, world=SHORT_WORLD)
    config = config.replace(slam=config.slam.replace(particles=5), confusion_sweep=())
    records = run_one(config, seed=1)
    maps, _, _ = _maps_at_stages(config, seed=1)
    desc_a, desc_b = robot_descriptors(config, 1, config.world.landmarks)[0.25]
    (ids_a, pos_a), (ids_b, pos_b) = maps[0][1], maps[1][1]
    matches = candidate_matches(
        FeatureMap(pos_a, desc_a[ids_a]), FeatureMap(pos_b, desc_b[ids_b]), 0.7
    )
    wrong = sum(ids_a[i] != ids_b[j] for i, j in matches)
    stage = next(r for r in records if r["stage"] == 1 and r["method"] == "svd")
    assert stage["matches"] == len(matches) and stage["wrong_matches"] == wrong > 0


def test_cli__seed_protocol_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``--protocol seed`` over a short world (100 particles, 2 stages, 1 run), and again
    with ``--resume`` from its results log."""
    config = tmp_path / "short.yaml"
    short = AlignmentReproduceConfig(stages=2, world=SHORT_WORLD, confusion_sweep=(0.5,))
    config.write_text(yaml.safe_dump(short.to_dict()))
    args = ["reproduce", "--paper", "alignment", "--protocol", "seed", "--config", str(config)]
    code = main([*args, "--runs", "1", "--workers", "1", "--quiet", "--out", str(tmp_path)])
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["protocol"] == "seed" and summary["config"]["slam"]["particles"] == 100
    assert set(summary["by_confusion"]) == {"0.25", "0.0", "0.1", "0.5"}
    assert summary["descriptor_wrong_match_rate"]["confusion"] == 0.25
    out = capsys.readouterr().out
    assert "protocol" in out and "per descriptor confusion" in out
    # through the results log: a resumed study runs nothing and gives the same tables
    (tmp_path / "summary.json").unlink()
    assert (
        main(
            [*args, "--runs", "1", "--workers", "1", "--quiet", "--out", str(tmp_path), "--resume"]
        )
        == 0
    )
    resumed = json.loads((tmp_path / "summary.json").read_text())
    assert "1 of 1 runs already in" in capsys.readouterr().err
    for key in ("table", "by_confusion", "descriptor_wrong_match_rate", "paired_against_ransac"):
        assert resumed[key] == summary[key]


def test_cli__protocol_with_another_paper__is_a_one_line_error(
    capsys: pytest.CaptureFixture,
) -> None:
    assert main(["reproduce", "--paper", "mblcc", "--protocol", "seed"]) == 2
    assert "--protocol applies to --paper alignment only" in capsys.readouterr().err
