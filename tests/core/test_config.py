"""Config machinery: strict loading, named errors, overrides, round trips."""

from __future__ import annotations

import pytest

from polyslam_env.core.errors import ConfigError
from polyslam_env.slam.config import SlamConfig, slam_preset
from polyslam_env.world.config import WorldConfig


def test_from_dict__unknown_nested_key_is_named() -> None:
    with pytest.raises(ConfigError, match=r"camera\.rang"):
        WorldConfig.from_dict({"camera": {"rang": 1.0}})


def test_from_dict__unknown_top_level_key_is_named() -> None:
    with pytest.raises(ConfigError, match="substep"):
        WorldConfig.from_dict({"substep": 30})


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        ({"camera": {"range": -1}}, "camera.range"),
        ({"camera": {"range": "far"}}, "camera.range"),
        ({"range_sensor": {"angles_deg": [0, "x"]}}, r"angles_deg\[1\]"),
        ({"robot": {"radius": True}}, "robot.radius"),
        ({"substeps": 1.5}, "substeps"),
        ({"dt": float("nan")}, "dt"),
    ],
)
def test_from_dict__bad_value_is_named(data: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        WorldConfig.from_dict(data)


def test_validate__too_few_substeps_for_speed_is_rejected() -> None:
    with pytest.raises(ConfigError, match="substeps"):
        WorldConfig(substeps=2)


def test_replace__double_underscore_and_dict_reach_nested_fields() -> None:
    base = WorldConfig()
    a = base.replace(camera__range=2.5)
    b = base.replace(camera={"range": 2.5})
    assert a == b
    assert a.camera.range == 2.5
    assert base.camera.range == 1.5  # frozen original untouched
    with pytest.raises(ConfigError, match="camera.nope"):
        base.replace(camera__nope=1)


def test_to_dict__round_trips() -> None:
    cfg = WorldConfig().replace(range_sensor__angles_deg=[10, 20], robot__v_max=0.2)
    assert WorldConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.range_sensor.angles_deg == (10.0, 20.0)


def test_from_yaml__names_file_and_key(tmp_path) -> None:
    path = tmp_path / "world.yaml"
    path.write_text("camera:\n  fov_deg: 400\n")
    with pytest.raises(ConfigError, match=r"world\.yaml.*camera\.fov_deg"):
        WorldConfig.from_yaml(path)
    path.write_text("camera: [1, 2\n")
    with pytest.raises(ConfigError, match=r"world\.yaml: not valid YAML"):
        WorldConfig.from_yaml(path)
    with pytest.raises(ConfigError, match="cannot read"):
        WorldConfig.from_yaml(tmp_path / "missing.yaml")


def test_slam_config__paper_preset_has_paper_values() -> None:
    cfg = slam_preset("paper")
    assert (cfg.rho_min, cfg.rho_max, cfg.sigma_min, cfg.sigma_max) == (0.08, 0.24, 0.1, 0.3)
    assert (cfg.eps_m, cfg.eps_z, cfg.k_divergence) == (5, 10, 150.0)
    assert (cfg.cluster_radius, cfg.gamma_max, cfg.order) == (0.35, 0.35, 3)
    with pytest.raises(ConfigError, match="unknown 'papr'"):
        slam_preset("papr")


def test_slam_config__inconsistent_thresholds_rejected() -> None:
    with pytest.raises(ConfigError, match="rho_max"):
        SlamConfig(rho_min=0.3, rho_max=0.2)
    with pytest.raises(ConfigError, match="eps_z"):
        SlamConfig(eps_z=2)


def test_from_dict__nested_validate_error_names_the_path_once() -> None:
    from polyslam_env.environment.config import EnvConfig

    with pytest.raises(ConfigError) as err:
        EnvConfig.from_dict({"world": {"range_sensor": {"max_range": -1}}})
    assert str(err.value).startswith("world.range_sensor.max_range:")
    assert "range_sensor.range_sensor" not in str(err.value)


def test_from_yaml__binary_file_is_a_config_error_naming_it(tmp_path) -> None:
    path = tmp_path / "binary.yaml"
    path.write_bytes(bytes(range(128, 256)))
    with pytest.raises(ConfigError, match="binary.yaml"):
        WorldConfig.from_yaml(path)


def test_from_yaml__empty_file_means_all_defaults(tmp_path) -> None:
    path = tmp_path / "empty.yaml"
    path.write_text("# nothing set\n")
    assert WorldConfig.from_yaml(path) == WorldConfig()
