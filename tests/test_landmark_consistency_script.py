"""scripts/landmark_consistency.py: a landmark's offset and turn read against a true wall."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
import pytest

from polyslam_env.slam.polynomial import Polynomial
from tests.scripts_module import load_script


def _script() -> ModuleType:
    return load_script("landmark_consistency")


@pytest.mark.parametrize("variate", [1, 2])
@pytest.mark.parametrize("slope", [0.0, 0.3])
def test_wall_errors__offset_and_turn_of_a_shifted_turned_line(variate: int, slope: float) -> None:
    """A true wall η = 1 + slope·ξ on ξ ∈ [0, 4] sampled every 2.5 mm (as boundary points),
    and the mapped line turned from it by 0.5° about ξ = 2 and shifted by 3 cm along η: the
    offset is 3 cm (true − mapped: −0.03) and the turn −0.5° (true − mapped), to the
    sampling's resolution."""
    script = _script()
    xi = np.arange(0.0, 4.0, 0.0025)
    eta = 1.0 + slope * xi
    true = np.column_stack([xi, eta] if variate == 1 else [eta, xi])
    turn = math.radians(0.5)
    mapped_slope = math.tan(math.atan(slope) + turn)
    c0 = 1.0 + 0.03 + 2.0 * (slope - mapped_slope)  # through (2, η(2) + 0.03)
    poly = Polynomial(variate, np.array([c0, mapped_slope]), 0.2, 3.8)
    offset, got_turn, matched = script.wall_errors(poly, true)
    assert matched >= script.SAMPLES // 2
    assert offset == pytest.approx(-0.03, abs=2e-3)  # the ξ match is within 5 mm
    assert got_turn == pytest.approx(-turn, rel=0.02)


def test_wall_errors__none_without_a_wall_near() -> None:
    script = _script()
    far = np.column_stack([np.arange(0.0, 4.0, 0.0025), np.full(1600, 3.0)])
    assert script.wall_errors(Polynomial(1, np.array([1.0, 0.0]), 0.0, 4.0), far) is None


def test_main__a_bad_set_field_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert _script().main(["--seeds", "1", "--set", "slam.square_wall=false"]) == 2
    out = capsys.readouterr().out.strip()
    assert len(out.splitlines()) == 1 and "slam.square_wall" in out


def test_square_turn_error__is_the_distance_from_the_nearest_axis_in_the_world() -> None:
    """A line 0.3° off its frame's x axis, in a frame turned 90° in the world, is 0.3° off the
    world's y axis; a variate-2 line at 90.2° in an unturned frame is 0.2° off."""
    script = _script()
    along_x = Polynomial(1, np.array([0.5, math.tan(math.radians(0.3))]), 0.0, 2.0)
    got = script.square_turn_error(along_x, math.pi / 2)
    assert math.isclose(math.degrees(got), 0.3, abs_tol=1e-9)
    along_y = Polynomial(2, np.array([0.5, math.tan(math.radians(-0.2))]), 0.0, 2.0)
    assert math.isclose(math.degrees(script.square_turn_error(along_y, 0.0)), 0.2, abs_tol=1e-9)
