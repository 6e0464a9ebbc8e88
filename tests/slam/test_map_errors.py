"""How the state's errors move a robot's map (``PolySlam.map_error_jacobian``), checked
against brute force: the curve moved by a small change of one landmark's c0 or turn α (a
shift along η, a rotation about its pivot), and each sample point's distance to the moved
curve along the normal found by a root search, not by any formula of the code under test."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import scipy.optimize

from polyslam_env.slam.config import SlamConfig
from polyslam_env.slam.polynomial import Polynomial
from polyslam_env.slam.robot import PolySlam
from tests.slam.finite_differences import FD_STEP
from tests.slam.test_shape_rotation import WALLS, _fit


def _slam(shape_rotation: str) -> PolySlam:
    slam = PolySlam(SlamConfig(shape_rotation=shape_rotation), np.linspace(-1.5, 1.5, 9), 4.0)
    for poly in WALLS:
        slam.insert_landmark(_fit(poly, slam.mean.size), merge=False)
    return slam


def _moved(
    poly: Polynomial, pivot: float, shift: float, angle: float
) -> Callable[[float], np.ndarray]:
    """The curve as a function ξ → point, shifted by ``shift`` along η and then turned by
    ``angle`` counter-clockwise about its (shifted) point at ξ = ``pivot``."""
    moved = poly.with_c0(poly.c0 + shift)
    centre = moved.points_at(np.array([pivot]))[0]
    c, s = math.cos(angle), math.sin(angle)

    def point(xi: float) -> np.ndarray:
        p = moved.points_at(np.array([xi]))[0] - centre
        return centre + np.array([c * p[0] - s * p[1], s * p[0] + c * p[1]])

    return point


def _normal_offset(
    point_on: Callable[[float], np.ndarray], q: np.ndarray, normal: np.ndarray, xi0: float
) -> float:
    """t such that q + t·normal lies on the curve ``point_on`` (ξ near ``xi0``)."""

    def gap(v: np.ndarray) -> np.ndarray:
        return point_on(v[0]) - (q + v[1] * normal)

    solution = scipy.optimize.root(gap, np.array([xi0, 0.0]), method="lm", tol=1e-15).x
    assert np.linalg.norm(gap(solution)) < 1e-13
    return float(solution[1])


def test_polynomial_normals__unit_and_perpendicular_to_the_tangent_towards_growing_eta() -> None:
    for poly in WALLS:
        xi = np.linspace(poly.lo, poly.hi, 7)
        normals = poly.normals(xi)
        tangents = (poly.points_at(xi + FD_STEP) - poly.points_at(xi - FD_STEP)) / (2 * FD_STEP)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-12)
        np.testing.assert_allclose(np.einsum("ni,ni->n", normals, tangents), 0.0, atol=1e-8)
        _, d_eta = poly.from_xy(normals)
        assert np.all(d_eta > 0)  # the side of growing η


@pytest.mark.parametrize("shape_rotation", ["considered", "heading"])
def test_map_error_jacobian__matches_the_moved_curve(shape_rotation: str) -> None:
    """Each point's row times a small change of one landmark's c0 (or α) is the point's
    offset along the normal to the curve so moved (central differences, 1e-6 relative); the
    rows are zero off the landmark's own c0 and α; without rotation states no α moves it."""
    slam = _slam(shape_rotation)
    lengths, jac = slam.map_error_jacobian(spacing=0.5)
    n = len(WALLS)
    assert jac.shape == (len(lengths), slam.mean.size)
    start = 0
    for i, poly in enumerate(slam.polynomials()):
        k = max(2, math.ceil((poly.hi - poly.lo) / 0.5) + 1)
        rows = jac[start : start + k]
        start += k
        xi = np.linspace(poly.lo, poly.hi, k)
        pivot = float(slam.table.pivot[i])
        columns = [3 + i] + ([3 + n + i] if shape_rotation == "considered" else [])
        others = np.delete(rows, columns, axis=1)
        assert not others.any()
        for column in columns:
            is_turn = column != 3 + i
            for row, x in zip(rows, xi, strict=True):
                q = poly.points_at(np.array([x]))[0]
                normal = poly.normals(np.array([x]))[0]
                moves = [(0.0, d) if is_turn else (d, 0.0) for d in (FD_STEP, -FD_STEP)]
                offsets = [
                    _normal_offset(_moved(poly, pivot, *move), q, normal, x) for move in moves
                ]
                fd = (offsets[0] - offsets[1]) / (2 * FD_STEP)
                # α turns the curve counter-clockwise in (x¹, x²), whichever its variate
                assert row[column] == pytest.approx(fd, rel=1e-5, abs=1e-6)
    assert start == len(lengths)


def test_map_error_jacobian__lengths_add_up_to_each_curves_arc_length() -> None:
    """The points' arc lengths (trapezoid rule on 2 cm of ξ) add up to the map's length
    (``Polynomial.length``, 512 points) within the rule's error, O(h²) of the curvature."""
    slam = _slam("considered")
    lengths, _ = slam.map_error_jacobian()
    total = sum(p.length() for p in slam.polynomials())
    assert lengths.sum() == pytest.approx(total, rel=1e-4)
    empty = PolySlam(SlamConfig(), np.linspace(-1.5, 1.5, 9), 4.0)
    lengths, jac = empty.map_error_jacobian()
    assert lengths.shape == (0,) and jac.shape == (0, 3)
