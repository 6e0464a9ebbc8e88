"""``scripts/docs_tables.py``: results pages' sections written from their commands' JSON."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from tests.scripts_module import load_script

ROOT = Path(__file__).resolve().parents[2]
tables = load_script("docs_tables")

META = {
    "command": "polyslam reproduce --paper seif --runs 10 --out /tmp/x --quiet",
    "started": "2026-11-27T19:00:00Z",
    "finished": "2026-11-27T19:05:00Z",
    "load_before": "1.00 1.00 1.00",
    "load_after": "1.50 1.20 1.00",
    "wall_s": 300,
    "machine": "2 cores, a CPU",
}


def seif_summary(runs: int = 2) -> dict[str, Any]:
    """A real ``reproduce --paper seif`` summary (its own ``summarise``) of made-up runs."""
    from polyslam_env.apps.reproduce_seif import SeifReproduceConfig, summarise

    made = [
        {
            "fraction_correct": 1.0 - 0.1 * i,
            "single_rms": 0.1,
            "fused_rms": 0.11 + 0.01 * i,
            "wrong_collapses": i,
            "collapsed": 280,
        }
        for i in range(runs)
    ]
    return summarise(SeifReproduceConfig(runs=runs), made)


def test_replace_section__keeps_the_marks_and_the_rest() -> None:
    text = "a\n<!-- BEGIN generated: x -->\nold\n<!-- END generated: x -->\nb\n"
    out = tables.replace_section(text, "x", "new")
    assert out == "a\n<!-- BEGIN generated: x -->\nnew\n<!-- END generated: x -->\nb\n"
    with pytest.raises(SystemExit, match="needs one"):
        tables.replace_section("no marks", "x", "new")


def test_section__names_command_date_machine_load_and_says_when_the_run_was_smaller() -> None:
    study = tables.STUDIES["seif"]
    data = [seif_summary()]
    full = tables.section("seif", study, data, META)
    assert "`polyslam reproduce --paper seif --runs 10 --out /tmp/x --quiet`" in full
    assert "2026-11-27 19:00–19:05 UTC" in full and "2 cores, a CPU" in full
    assert "1.00 1.00 1.00 before, 1.50 1.20 1.00 after" in full
    assert "smaller run" not in full  # the study's command: only --out and --quiet differ
    smaller = tables.section(
        "seif", study, data, {**META, "command": META["command"].replace("10", "3")}
    )
    assert "**A smaller run than the study's own**" in smaller
    assert "`polyslam reproduce --paper seif --runs 10 --out OUT`" in smaller


def test_render_seif__the_apps_own_table_and_checks() -> None:
    summary = seif_summary()
    text, headline = tables.render_seif([summary])
    assert "pieces fused correctly: 95 %" in text  # mean of 1.0 and 0.9
    assert "2 of 2 checks hold" in text
    assert headline.startswith("95 % of pieces fused correctly")


def test_render_speed__targets_and_machine() -> None:
    results = {
        "targets": [
            {"target": "full-SLAM env / MPE", "measured": 0.17, "goal": 0.5, "at_most": False,
             "met": False},
            {"target": "SLAM step, 30 landmarks", "measured": 118.0, "goal": 60, "at_most": True,
             "met": False},
            {"target": "team", "measured": None, "goal": 10, "at_most": True, "met": None},
            {"target": "20 / 3", "measured": 10.0172, "goal": 10, "at_most": True, "met": False},
            {"target": "3 / 1", "measured": 9.9981, "goal": 10, "at_most": True, "met": True},
        ],
        "machine": {"blas": "openblas ×2", "numpy": "2", "pymunk": "7", "python": "3.11",
                    "load_before": 1.0, "load_after": 2.0},
    }  # fmt: skip
    text, headline = tables.render_speed([results])
    assert "| full-SLAM env / MPE | 0.17 | ≥ 0.5 | no |" in text
    assert "| team | — | ≤ 10 | not measured |" in text
    assert "| 20 / 3 | 10.02 | ≤ 10 | no |" in text  # a miss does not round onto its goal
    assert "| 3 / 1 | 10 | ≤ 10 | yes |" in text
    assert headline == "1 of 4 speed targets met; full-SLAM env at 0.17× PettingZoo MPE's steps/s"


def test_write__page_section_and_readme_headline(tmp_path: Path) -> None:
    results = tmp_path / "results"
    shutil.copytree(ROOT / "docs" / "results", results)
    readme = tmp_path / "README.md"
    readme.write_text("x\n<!-- BEGIN generated: headline -->\n<!-- END generated: headline -->\n")
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(SystemExit, match="run.json"):
        tables.write("seif", run, results, readme)
    (run / "run.json").write_text(json.dumps(META))
    (run / "summary.json").write_text(json.dumps(seif_summary()))
    tables.write("seif", run, results, readme)
    page = (results / "seif.md").read_text()
    assert page.count("<!-- BEGIN generated: seif -->") == 1 and "pieces fused correctly" in page
    row = next(line for line in readme.read_text().splitlines() if "SEIF" in line)
    assert "95 % of pieces fused correctly" in row and "(docs/results/seif.md)" in row


def test_every_study_has_its_page_with_one_section() -> None:
    for name, study in tables.STUDIES.items():
        page = (ROOT / "docs" / "results" / study.page).read_text()
        assert page.count(f"<!-- BEGIN generated: {name} -->") == 1
        assert page.count(f"<!-- END generated: {name} -->") == 1


def test_render_mblcc__seeds_markdown_tables_and_the_orderings() -> None:
    from polyslam_env.apps.reproduce_mblcc import run_one, summarise
    from tests.apps.test_reproduce_mblcc import SMALL

    summary = json.loads(json.dumps(summarise([run_one(SMALL, seed=s) for s in range(2)])))
    text, headline = tables.render_mblcc([summary])
    assert text.startswith("| robot | column | pose error (m) | landmark error (m) |")
    assert "| r3 | shared_map_motion_proposal |" in text
    held = sum(v for v in summary["checks"].values() if isinstance(v, bool))
    assert headline == (
        f"{held} of 10 checks of the seed's orderings hold for every robot at once"
        " (2 runs; the page says which hold in part)"
    )


def test_render_alignment__one_block_per_protocol_in_the_given_order() -> None:
    from polyslam_env.apps.reproduce_alignment import (
        AlignmentReproduceConfig,
        protocol_config,
        reproduce,
        summarise,
    )

    data = []
    for protocol in ("seed", "guarded"):
        cfg = protocol_config(protocol, AlignmentReproduceConfig(runs=1))
        data.append(json.loads(json.dumps(summarise(cfg, reproduce(cfg, workers=1)))))
    text, headline = tables.render_alignment(data)
    assert text.index("**seed protocol** (1 runs)") < text.index("**guarded protocol** (1 runs)")
    assert text.count("| landmarks both maps hold |") == 2
    assert headline.startswith("seed: ") and "; guarded: " in headline


def test_render_learning__a_policy_that_never_reaches_90_percent_says_never() -> None:
    never = {"mean": None, "std": None, "min": None, "max": None, "reached": 0.0, "episodes": 10.0}
    reached = {
        "mean": 200.0,
        "std": 20.0,
        "min": 180.0,
        "max": 220.0,
        "reached": 7.0,
        "episodes": 10.0,
    }
    stats = {
        "coverage": {"mean": 0.9, "std": 0.05},
        "nu_mean": {"mean": 0.01},
        "bytes_sent": {"mean": 10.0},
    }
    report = {
        "map": "generator:warehouse",
        "comparison": {
            "frontier": {**stats, "steps_to_90": reached},
            "random": {**stats, "steps_to_90": never},
        },
    }
    text, headline = tables.render_learning([report])
    assert "| generator:warehouse | frontier | 0.900 ± 0.050 | 200 ± 20 (7/10) |" in text
    assert "| generator:warehouse | random | 0.900 ± 0.050 | never (0/10) |" in text
    assert headline == "team coverage on held-out layouts: frontier 0.900, random 0.900"
