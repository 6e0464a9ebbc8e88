"""``polyslam maps import``: a ROS map_server map (made here from a generated layout, its walls
grown like a costmap's) becomes a map file that loads; narrow doors are reported with the
shrink that opens them; bad input is a one-line error."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from polyslam_env.cli.main import main
from polyslam_env.world.generators import RoomsGenerator
from polyslam_env.world.grid import free_space_grid
from polyslam_env.world.maps import load_map
from tests.world.test_occupancy import write_map

RES = 0.05  # m per pixel


def _costmap(folder: Path, grown: float) -> Path:
    """A rooms layout rasterised (free 254, occupied 0), its walls grown by ``grown`` m."""
    truth = RoomsGenerator(width=8.0, height=6.0)(np.random.default_rng(0))
    free = free_space_grid(truth, RES).mask
    if grown > 0:
        free = ndimage.distance_transform_edt(free) * RES > grown
    pixels = np.where(free, 254, 0)[::-1]  # first image row: the top
    return write_map(folder, pixels, name="costmap", resolution=RES)


def test_maps_import__writes_a_loadable_map_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = _costmap(tmp_path, 0.0)
    out = tmp_path / "floor.yaml"
    assert main(["maps", "import", str(src), "--out", str(out), "--start-separation", "1"]) == 0
    layout = load_map(out)
    assert layout.num_start_poses == 3 and layout.outer_boundary is not None
    text = capsys.readouterr().out
    assert f"{out}: " in text and "warning" not in text


def test_maps_import__grown_walls_warned_and_the_opening_shrink_offered(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Walls grown by 0.2 m narrow the 0.6 m doors below the robot with its margin
    (0.23 m): a warning, and a --shrink of at most 0.2 m (the growth) that opens them."""
    src = _costmap(tmp_path, 0.2)
    out = tmp_path / "floor.yaml"
    args = ["maps", "import", str(src), "--out", str(out), "--start-separation", "0.5"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "warning:" in text and "narrower than the robot" in text
    offered = float(text.split("rerun with --shrink ")[1].split()[0])
    assert 0 < offered <= 0.2
    assert main([*args, "--shrink", str(offered), "--force"]) == 0
    assert "warning" not in capsys.readouterr().out


@pytest.mark.parametrize(
    ("setup", "extra", "message"),
    [
        ("exists", [], "--out: .* exists; pass --force"),
        ("bad_yaml", [], "resolution: must be > 0"),
        ("missing", [], "cannot read the map YAML"),
        ("ok", ["--start-near", "1;2"], "--start-near: expected X,Y"),
        ("ok", ["--tolerance", "-1"], "tolerance"),
    ],
)
def test_maps_import__bad_input_one_line_error(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    setup: str,
    extra: list[str],
    message: str,
) -> None:
    src = _costmap(tmp_path, 0.0)
    out = tmp_path / "floor.yaml"
    if setup == "exists":
        out.write_text("x")
    elif setup == "bad_yaml":
        src.write_text(src.read_text().replace("resolution: 0.05", "resolution: 0"))
    elif setup == "missing":
        src = tmp_path / "nowhere.yaml"
    assert main(["maps", "import", str(src), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("polyslam: error: ") and "\n" not in err
    assert re.search(message, err), err


def test_maps__plot_draws_the_generators_layouts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "layouts.png"
    assert main(["maps", "--plot", str(png), "--only", "loop,rooms", "--seed", "3"]) == 0
    assert png.stat().st_size > 10_000 and f"wrote {png}" in capsys.readouterr().out
    assert main(["maps", "--plot", str(png), "--only", "maze"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--only: 'maze' is not a layout generator" in err and "\n" not in err
