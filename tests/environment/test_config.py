"""EnvConfig: the forms parallel_env accepts, and errors that name the bad key or value."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from polyslam_env import ConfigError, EnvConfig, MapFileError, parallel_env
from polyslam_env.environment.config import resolve_config
from polyslam_env.slam.config import SlamConfig, slam_preset


def test_env_config__defaults_are_valid_and_match_the_brief() -> None:
    cfg = EnvConfig()
    assert (cfg.map, cfg.num_robots, cfg.max_steps) == ("paper", 3, 500)
    assert cfg.channel is not None and cfg.slam_enabled
    assert (cfg.coverage_target, cfg.coverage_resolution) == (0.95, 0.1)
    assert cfg.num_detections == 2


def test_parallel_env__keyword_overrides_reach_nested_fields() -> None:
    env = parallel_env(map="two_rooms", num_robots=2, reward__coverage=2.0, world__dt=0.5)
    assert env.config.map == "two_rooms"
    assert env.config.num_robots == 2
    assert env.config.reward.coverage == 2.0
    assert env.config.world.dt == 0.5
    assert env.possible_agents == ["robot_0", "robot_1"]


def test_resolve_config__accepts_dict_yaml_and_config(tmp_path: Path) -> None:
    data = {"map": "two_rooms", "num_robots": 2, "reward": {"shared": True}}
    path = tmp_path / "env.yaml"
    path.write_text(yaml.safe_dump(data))
    from_dict = resolve_config(data)
    assert resolve_config(path) == from_dict
    assert resolve_config(str(path)) == from_dict
    assert resolve_config(from_dict) is from_dict
    assert resolve_config(data, max_steps=7).max_steps == 7
    assert from_dict.reward.shared


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        ({"rewrd": {"coverage": 1.0}}, "rewrd"),
        ({"reward__coverag": 1.0}, "reward.coverag"),
        ({"observation__grid_sise": 3}, "observation.grid_sise"),
        ({"num_robots": 0}, "num_robots"),
        ({"max_steps": 0}, "max_steps"),
        ({"coverage_target": 1.5}, "coverage_target"),
        ({"map": "generator:maze"}, "map"),
        ({"map_params": {"width": 3.0}}, "map_params"),
        ({"observation__mode": "image"}, "observation.mode"),
        ({"observation__grid_size": 10}, "observation.grid_size"),
        ({"action__mode": "wheels"}, "action.mode"),
        ({"action__discrete": [[2.0, 0.0]]}, "action.discrete[0][0]"),
        ({"faults": [[5, 3]]}, "faults[0]"),
        ({"faults": [[0, 0]]}, "faults[0]"),
        ({"slam_preset": "fast"}, "slam preset"),
        ({"channel__loss_prob": 2.0}, "loss_prob"),
        ({"reward__time": "often"}, "reward.time"),
    ],
)
def test_env_config__bad_key_or_value_raises_naming_it(
    overrides: dict[str, object], named: str
) -> None:
    with pytest.raises(ConfigError, match=named.replace("[", r"\[").replace("]", r"\]")):
        EnvConfig().replace(**overrides)


def test_env_config__unknown_top_level_key_in_yaml_names_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("map: paper\nnum_robot: 2\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*num_robot"):
        parallel_env(path)


def test_env_config__slam_preset_replaces_slam_and_conflicts_with_custom_slam() -> None:
    assert EnvConfig(slam_preset="paper").slam == slam_preset("paper")
    assert slam_preset("paper") == SlamConfig(
        eps_z=10,
        join_pieces=False,
        stretch_ends=False,
        end_sigma=0.0,
        min_update_extent=0.0,
        update_spacing_deg=0.0,
        link_clusters=False,
        link_gap=0.0,
        square_walls=False,
        shape_rotation="heading",
        reuse_bound="none",
    )
    with pytest.raises(ConfigError, match="slam_preset"):
        EnvConfig(slam=SlamConfig(rho_min=0.05), slam_preset="paper")


def test_env_config__channel_none_disables_exchange() -> None:
    cfg = resolve_config({"channel": None})
    assert cfg.channel is None
    assert EnvConfig.from_dict(cfg.to_dict()) == cfg


def test_parallel_env__bad_map_file_names_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "broken_map.yaml"
    path.write_text(
        yaml.safe_dump(
            {"walls": [[[0, 0], [3, 0], [3, 2], [0, 2], [0, 0]]], "start_poses": [[1, 1]]}
        )
    )
    with pytest.raises(MapFileError, match=r"broken_map\.yaml.*start_poses"):
        parallel_env(map=str(path), num_robots=1)


def test_parallel_env__missing_map_and_too_few_start_poses_raise_map_errors(
    tmp_path: Path,
) -> None:
    with pytest.raises(MapFileError, match="no_such_map"):
        parallel_env(map="no_such_map")
    path = tmp_path / "one_start.yaml"
    path.write_text(
        yaml.safe_dump(
            {"walls": [[[0, 0], [3, 0], [3, 2], [0, 2], [0, 0]]], "start_poses": [[1, 1, 0]]}
        )
    )
    with pytest.raises(MapFileError, match="start_poses"):
        parallel_env(map=str(path), num_robots=2)


@settings(max_examples=25, deadline=None)
@given(
    num_robots=st.integers(1, 8),
    weights=st.lists(st.floats(-10, 10, allow_nan=False), min_size=5, max_size=5),
    shared=st.booleans(),
    mode=st.sampled_from(["vector", "grid"]),
    grid=st.integers(0, 10).map(lambda k: 2 * k + 1),
)
def test_env_config__round_trips_through_plain_data(
    num_robots: int, weights: list[float], shared: bool, mode: str, grid: int
) -> None:
    names = ("coverage", "mapping", "bytes", "collision", "time")
    reward = dict(zip(names, weights, strict=True)) | {"shared": shared}
    cfg = EnvConfig.from_dict(
        {
            "map": "generator:rooms",
            "map_params": {"width": 4.0},
            "num_robots": num_robots,
            "reward": reward,
            "observation": {"mode": mode, "grid_size": grid},
            "faults": [[num_robots - 1, 3]],
        }
    )
    assert EnvConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.num_detections == num_robots - 1


def test_real_building_config__sets_only_the_three_slam_fields_the_maps_guide_names() -> None:
    """``configs/real_building.yaml`` (docs/guide/maps.md, "SLAM settings for imported
    buildings"): the shape shift predicted from the pose, square ties to 1° and beams on seen
    faces only; every other field is the default, so the guide's figures (default config +
    these three) are its."""
    path = Path(__file__).resolve().parents[2] / "configs" / "real_building.yaml"
    config = resolve_config(str(path))
    want = SlamConfig().replace(shape_shift="pose", wall_squareness_deg=1.0, seen_faces=True)
    assert config.slam == want
    assert config.replace(slam=SlamConfig()) == EnvConfig()
