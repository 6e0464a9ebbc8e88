"""Compiled kernels of the mapping metrics the reward recomputes whenever a map changes.

* :func:`wall_distances`: the exact distance of each point to the nearest wall segment, over
  the layout's static :class:`~polyslam_env.world.nearby.WallIndex`. The grid is searched in
  square rings of cells around the point's cell; a segment's nearest point to p lies in a cell
  that lists it, and every cell of ring k+1 or beyond lies outside the block of rings 0…k, so
  once the best distance is within p's distance to that block's edge, no unvisited segment
  can be nearer (most map points, a few cm from a wall, stop after their own cell).
* :func:`covered`: which boundary samples lie strictly within ``tol`` of some map point (the
  completeness), with the map points bucketed in a grid of side ≥ ``tol`` so that only the
  3 × 3 buckets around a sample are searched.
* :func:`parallel_neighbours`: the duplicates metric's samples lying within ``tol`` of, and
  parallel to, a sample of another polynomial, over the same buckets.
* :func:`sample_rows`: many polynomials sampled every ``step`` of arc length in one call, with
  the float operations of :meth:`~polyslam_env.slam.polynomial.Polynomial.sample_arclength`
  in the same order (numpy's ``linspace``, Horner's ``polyval``, ``diff``, the norm as the sum
  of two squares, ``cumsum`` and ``interp``), so the points are bit-identical to it.
* :func:`map_sums`: what the env's map rewards need of a map each time it changes, in one
  call: its samples (:func:`sample_rows`) placed by a pose, the sum of their distances to the
  boundary (:func:`wall_distances` and the pillars) and the weight of the boundary samples
  they cover (:func:`covered_by`), both sums in numpy's order (``sum_like_numpy``);
  :func:`map_quality_sums`: the same for the end-of-episode map-quality metrics (both
  placings, per-polynomial sums, the seen boundary, the duplicates' pairs).
* :func:`record_rows`: one step of a team's history (poses, covariances, SLAM times, the
  beams' true ranges, path length, collisions, divergence flags) written for every recorded
  slot in one call, the
  path length's step with libm's ``hypot`` as ``np.hypot`` computes it.

Oracles: brute force over all segments and all points, ``Polynomial.sample_arclength`` and
the numpy form of the history's record (``tests/metrics/test_kernels.py``); for
:func:`map_sums` and :func:`map_quality_sums`, the mapping metrics' own functions
(``completeness``, ``map_error_length``, ``nu``, ``duplicates``, …), which place, measure and
sum the map in numpy (``tests/metrics/test_map_quality.py``).
"""

from __future__ import annotations

import math

import numpy as np

from polyslam_env.core.jit import njit, sum_like_numpy
from polyslam_env.world.kernels import _segment_distance

__all__ = [
    "buckets",
    "covered",
    "covered_by",
    "map_quality_sums",
    "map_sums",
    "parallel_neighbours",
    "record_rows",
    "sample_rows",
    "wall_distances",
]

#: How far (m) inside the searched block's edge the nearest segment must be for
#: :func:`wall_distances` to stop, and how far past ``tol`` a point may be from another
#: polynomial's box for :func:`parallel_neighbours` to search it: far above the coordinates'
#: round-off.
_REACH_MARGIN = 1e-9
#: Most buckets a side in :func:`covered`.
_MAX_BUCKETS = 256


@njit
def wall_distances(
    points: np.ndarray,
    segments: np.ndarray,
    origin: np.ndarray,
    cell: float,
    rows: int,
    cols: int,
    starts: np.ndarray,
    items: np.ndarray,
) -> np.ndarray:
    """Distance (N,) from each point (N, 2) to the nearest segment of the index (arguments
    in :attr:`WallIndex.arrays` order); inf when the index has no segment."""
    n = points.shape[0]
    out = np.full(n, np.inf)
    if rows == 0:
        return out
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        c = math.floor((px - origin[0]) / cell)
        r = math.floor((py - origin[1]) / cell)
        best = np.inf
        k = 0
        while True:
            for rr in range(r - k, r + k + 1):
                if rr < 0 or rr >= rows:
                    continue
                on_edge = rr == r - k or rr == r + k
                step = 1 if on_edge else 2 * k  # inner rows: only the ring's two ends
                cc = c - k
                while cc <= c + k:
                    if 0 <= cc < cols:
                        flat = rr * cols + cc
                        for j in range(starts[flat], starts[flat + 1]):
                            d = _segment_distance(px, py, segments, items[j])
                            if d < best:
                                best = d
                    cc += step
            # every unvisited cell lies outside the (2k + 1)² block, so no unvisited segment is
            # nearer than the block's edge (less a margin far above the coordinates' round-off)
            reach = min(
                px - (origin[0] + (c - k) * cell),
                origin[0] + (c + k + 1) * cell - px,
                py - (origin[1] + (r - k) * cell),
                origin[1] + (r + k + 1) * cell - py,
            )
            if best <= reach - _REACH_MARGIN:
                break
            if r - k <= 0 and r + k >= rows - 1 and c - k <= 0 and c + k >= cols - 1:
                break  # every cell of the grid visited
            k += 1
        out[i] = best
    return out


@njit
def buckets(
    points: np.ndarray, tol: float
) -> tuple[float, float, float, int, int, np.ndarray, np.ndarray]:
    """The points (N ≥ 1, 2) bucketed in a grid of side ≥ ``tol`` (at most ``_MAX_BUCKETS``
    a side), so that every point within ``tol`` of a place lies in its 3 × 3 buckets: (x0,
    y0, side, ncols, nrows, order, starts), bucket b's points ``order[starts[b]:starts[b+1]]``
    in ascending index."""
    n = points.shape[0]
    x0, y0 = points[0, 0], points[0, 1]
    x1, y1 = x0, y0
    for i in range(n):
        x0, y0 = min(x0, points[i, 0]), min(y0, points[i, 1])
        x1, y1 = max(x1, points[i, 0]), max(y1, points[i, 1])
    side = max(tol, max(x1 - x0, y1 - y0) / _MAX_BUCKETS)
    ncols = 1
    nrows = 1
    keys = np.empty(n, dtype=np.int64)
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx[i] = math.floor((points[i, 0] - x0) / side)
        cy[i] = math.floor((points[i, 1] - y0) / side)
        ncols = max(ncols, cx[i] + 1)
        nrows = max(nrows, cy[i] + 1)
    for i in range(n):
        keys[i] = cy[i] * ncols + cx[i]
    order = np.argsort(keys, kind="mergesort")
    starts = np.zeros(nrows * ncols + 1, dtype=np.int64)
    for i in range(n):
        starts[keys[i] + 1] += 1
    for b in range(nrows * ncols):
        starts[b + 1] += starts[b]
    return x0, y0, side, ncols, nrows, order, starts


@njit
def _bucket_span(
    px: float, py: float, x0: float, y0: float, side: float, ncols: int, nrows: int
) -> tuple[int, int, int, int]:
    """The rows r0…r1 and columns c0…c1 of the 3 × 3 buckets around (px, py), clipped to
    the grid (empty ranges when the place is far outside it)."""
    c = math.floor((px - x0) / side)
    r = math.floor((py - y0) / side)
    return max(r - 1, 0), min(r + 1, nrows - 1), max(c - 1, 0), min(c + 1, ncols - 1)


@njit
def covered(samples: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """Whether each sample (M, 2) has a point (N, 2) strictly within ``tol`` (> 0):
    dx² + dy² < tol²."""
    m = samples.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    n = points.shape[0]
    if n == 0 or m == 0 or not tol > 0.0:
        return out
    x0, y0, side, ncols, nrows, order, starts = buckets(points, tol)
    tol2 = tol * tol
    for s in range(m):
        sx, sy = samples[s, 0], samples[s, 1]
        r0, r1, c0, c1 = _bucket_span(sx, sy, x0, y0, side, ncols, nrows)
        found = False
        for rr in range(r0, r1 + 1):
            for cc in range(c0, c1 + 1):
                b = rr * ncols + cc
                for j in range(starts[b], starts[b + 1]):
                    p = order[j]
                    dx, dy = sx - points[p, 0], sy - points[p, 1]
                    if dx * dx + dy * dy < tol2:
                        found = True
                        break
                if found:
                    break
            if found:
                break
        out[s] = found
    return out


@njit
def covered_by(
    samples: np.ndarray,
    x0: float,
    y0: float,
    side: float,
    ncols: int,
    nrows: int,
    order: np.ndarray,
    starts: np.ndarray,
    points: np.ndarray,
    tol: float,
) -> np.ndarray:
    """:func:`covered` the other way round, for samples (M, 2) bucketed once
    (:func:`buckets` of the samples with the same ``tol``: x0 … starts) and many point sets:
    each finite point (N, 2) marks the samples strictly within ``tol`` (> 0) in its 3 × 3
    buckets, a point with a NaN or infinite coordinate none. The same booleans as
    ``covered(samples, finite points, tol)`` (the same test, dx² + dy² < tol², on the same
    differences)."""
    m = samples.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    if points.shape[0] == 0 or m == 0 or not tol > 0.0:
        return out
    any_face = np.zeros(0, dtype=np.int64)
    for i in range(points.shape[0]):
        px, py = points[i, 0], points[i, 1]
        if not (math.isfinite(px) and math.isfinite(py)):
            continue
        span = _bucket_span(px, py, x0, y0, side, ncols, nrows)
        _mark_within(out, samples, any_face, -1, px, py, span, ncols, order, starts, tol * tol)
    return out


@njit
def _mark_within(
    out: np.ndarray,  # (M,) bool, marked in place
    samples: np.ndarray,
    faces: np.ndarray,  # (M,) each sample's face; read only when ``face`` ≥ 0
    face: int,  # −1: any face
    px: float,
    py: float,
    span: tuple[int, int, int, int],  # :func:`_bucket_span` of (px, py)
    ncols: int,
    order: np.ndarray,
    starts: np.ndarray,
    tol2: float,
) -> None:
    """Mark the samples of ``face`` (any with −1) in the 3 × 3 buckets ``span`` strictly
    within √``tol2`` of (px, py)."""
    r0, r1, c0, c1 = span
    for rr in range(r0, r1 + 1):
        for cc in range(c0, c1 + 1):
            b = rr * ncols + cc
            for j in range(starts[b], starts[b + 1]):
                s = order[j]
                if not out[s] and (face < 0 or faces[s] == face):
                    dx, dy = samples[s, 0] - px, samples[s, 1] - py
                    if dx * dx + dy * dy < tol2:
                        out[s] = True


@njit
def covered_on_face(
    samples: np.ndarray,
    faces: np.ndarray,
    x0: float,
    y0: float,
    side: float,
    ncols: int,
    nrows: int,
    order: np.ndarray,
    starts: np.ndarray,
    points: np.ndarray,
    tol: float,
) -> np.ndarray:
    """:func:`covered_by` along each point's own face: a finite point (N, 2) lying on the
    sampled boundary (a beam's hit) takes the face (``faces`` (M,), one id per sample) of the
    sample nearest to it (the first on ties, in bucket order) and marks only the samples of
    that face strictly within ``tol`` (> 0); a point with no sample within ``tol`` marks none.
    Buckets as :func:`covered_by`'s (:func:`buckets` of the samples with the same ``tol``)."""
    m = samples.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    if points.shape[0] == 0 or m == 0 or not tol > 0.0:
        return out
    tol2 = tol * tol
    for i in range(points.shape[0]):
        px, py = points[i, 0], points[i, 1]
        if not (math.isfinite(px) and math.isfinite(py)):
            continue
        span = _bucket_span(px, py, x0, y0, side, ncols, nrows)
        r0, r1, c0, c1 = span
        nearest, best = -1, tol2
        for rr in range(r0, r1 + 1):
            for cc in range(c0, c1 + 1):
                b = rr * ncols + cc
                for j in range(starts[b], starts[b + 1]):
                    s = order[j]
                    dx, dy = samples[s, 0] - px, samples[s, 1] - py
                    d2 = dx * dx + dy * dy
                    if d2 < best:
                        nearest, best = s, d2
        if nearest >= 0:
            _mark_within(
                out, samples, faces, faces[nearest], px, py, span, ncols, order, starts, tol2
            )
    return out


@njit
def parallel_neighbours(
    points: np.ndarray,
    owner: np.ndarray,
    tangent: np.ndarray,
    has_dir: np.ndarray,
    tol: float,
    max_sine: float,
) -> np.ndarray:
    """Whether each point (M, 2) has a point of another ``owner`` (M,) within ``tol``
    (dx² + dy² ≤ tol², as ``cKDTree.query_pairs``) whose unit ``tangent`` (M, 2) is parallel
    to its own: |t_a × t_b| ≤ ``max_sine`` (t_a the lower index's), both with a direction
    (``has_dir`` (M,)). The duplicates metric's pairs.

    A point farther than ``tol`` from every other owner's box (its points with a direction)
    has no such neighbour and is not searched (most of a map's points: polynomials meet only
    at their ends); its pairs with searched points are found from them."""
    m = points.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    if m == 0 or not tol >= 0.0:
        return out
    x0, y0, side, ncols, nrows, order, starts = buckets(points, max(tol, 1e-12))
    first = owner.min()
    boxes = _owner_boxes(points, owner - first, has_dir)  # (owners, 4), or (0, 4): none
    reach = tol + _REACH_MARGIN
    tol2 = tol * tol
    for i in range(m):
        if out[i] or not has_dir[i]:
            continue
        px, py = points[i, 0], points[i, 1]
        if boxes.shape[0] and not _near_other_box(px, py, owner[i] - first, boxes, reach):
            continue
        r0, r1, c0, c1 = _bucket_span(px, py, x0, y0, side, ncols, nrows)
        for rr in range(r0, r1 + 1):
            for cc in range(c0, c1 + 1):
                b = rr * ncols + cc
                for k in range(starts[b], starts[b + 1]):
                    j = order[k]
                    if owner[j] == owner[i] or not has_dir[j]:
                        continue
                    dx, dy = px - points[j, 0], py - points[j, 1]
                    if not dx * dx + dy * dy <= tol2:
                        continue
                    a, o = (i, j) if i < j else (j, i)
                    cross = abs(tangent[a, 0] * tangent[o, 1] - tangent[a, 1] * tangent[o, 0])
                    if cross <= max_sine:
                        out[i] = True
                        out[j] = True
    return out


@njit
def _owner_boxes(points: np.ndarray, label: np.ndarray, has_dir: np.ndarray) -> np.ndarray:
    """The bounding box (x_min, y_min, x_max, y_max) of each owner's points with a direction,
    owner ``label`` (M,) ≥ 0 in row ``label`` (inf, inf, −inf, −inf: none); (0, 4) when the
    labels outnumber the points (no boxes kept)."""
    count = label.max() + 1
    if count > points.shape[0]:
        return np.empty((0, 4))
    boxes = np.empty((count, 4))
    boxes[:, :2] = np.inf
    boxes[:, 2:] = -np.inf
    for j in range(points.shape[0]):
        if has_dir[j]:
            o = label[j]
            boxes[o, 0] = min(boxes[o, 0], points[j, 0])
            boxes[o, 1] = min(boxes[o, 1], points[j, 1])
            boxes[o, 2] = max(boxes[o, 2], points[j, 0])
            boxes[o, 3] = max(boxes[o, 3], points[j, 1])
    return boxes


@njit
def _near_other_box(px: float, py: float, own: int, boxes: np.ndarray, reach: float) -> bool:
    """Whether (px, py) lies within ``reach`` of the box (4,) of an owner other than ``own``."""
    for o in range(boxes.shape[0]):
        if o != own and boxes[o, 0] - reach <= px <= boxes[o, 2] + reach:
            if boxes[o, 1] - reach <= py <= boxes[o, 3] + reach:
                return True
    return False


@njit
def _horner(coeffs: np.ndarray, row: int, x: float) -> float:
    """Σ_j coeffs[row, j] x^j as ``np.polynomial.polynomial.polyval`` computes it (Horner from
    the highest power, started at ``c[-1] + x·0``); zero-padded high powers change nothing."""
    m = coeffs.shape[1]
    value = coeffs[row, m - 1] + x * 0.0
    for i in range(2, m + 1):
        value = coeffs[row, m - i] + value * x
    return value


@njit
def _interp(x: float, xp: np.ndarray, fp: np.ndarray) -> float:
    """``np.interp(x, xp, fp)`` for one ``x`` and a non-decreasing ``xp`` (numpy's C code:
    the last ``j`` with ``xp[j] ≤ x``, the slope form and its NaN fallbacks)."""
    n = xp.shape[0]
    if x != x:
        return x
    if x > xp[n - 1]:
        return fp[n - 1]
    if x < xp[0]:
        return fp[0]
    lo, hi = 0, n  # bisection for the first index with xp > x
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        if x >= xp[mid]:
            lo = mid + 1
        else:
            hi = mid
    j = lo - 1
    if j == n - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    out = slope * (x - xp[j]) + fp[j]
    if out != out:
        out = slope * (x - xp[j + 1]) + fp[j + 1]
        if out != out and fp[j] == fp[j + 1]:
            out = fp[j]
    return out


@njit
def sample_rows(
    variate: np.ndarray,
    coeffs: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    rows: np.ndarray,
    step: float,
    dense: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 2) every ``step`` of arc length along each polynomial ``rows[q]`` (Q,) of
    (``variate`` (n,), ``coeffs`` (n, m+1) = [c0, b_1, …] zero-padded, extent ``lo``–``hi``
    (n,)), both ends included, and where each one's points start, (Q + 1,): ``Polynomial.
    sample_arclength(step, dense)`` of each, bit for bit (module docstring)."""
    q_count = rows.shape[0]
    starts = np.zeros(q_count + 1, dtype=np.int64)
    xi = np.empty(dense)
    arc = np.empty(dense)
    eta = np.empty(dense)
    chunks = []
    for q in range(q_count):
        r = rows[q]
        a, b = lo[r], hi[r]
        if b == a:  # one point
            ts = np.full(1, a)
        else:
            div = dense - 1
            delta = b - a
            stride = delta / div
            for k in range(dense):  # np.linspace(a, b, dense)
                xi[k] = (k / div) * delta + a if stride == 0.0 else k * stride + a
            xi[dense - 1] = b
            for k in range(dense):
                eta[k] = _horner(coeffs, r, xi[k])
            arc[0] = 0.0
            total = 0.0
            for k in range(1, dense):  # cumsum of ‖Δ(ξ, η)‖
                d1, d2 = xi[k] - xi[k - 1], eta[k] - eta[k - 1]
                total += math.sqrt(d1 * d1 + d2 * d2)
                arc[k] = total
            count = max(math.floor(total / step) + 1, 2)
            div2 = count - 1
            stride2 = total / div2
            ts = np.empty(count)
            for k in range(count):  # np.interp(np.linspace(0, total, count), arc, xi)
                t = (k / div2) * total + 0.0 if stride2 == 0.0 else k * stride2 + 0.0
                if k == count - 1:
                    t = total
                ts[k] = _interp(t, arc, xi)
        pts = np.empty((ts.shape[0], 2))
        first = 0 if variate[r] == 1 else 1
        for k in range(ts.shape[0]):
            pts[k, first] = ts[k]
            pts[k, 1 - first] = _horner(coeffs, r, ts[k])
        chunks.append(pts)
        starts[q + 1] = starts[q] + ts.shape[0]
    out = np.empty((starts[q_count], 2))
    for q in range(q_count):
        out[starts[q] : starts[q + 1]] = chunks[q]
    return out, starts


@njit
def map_sums(
    variate: np.ndarray,
    coeffs: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    step: float,
    dense: int,
    pose: np.ndarray,
    c: float,
    s: float,
    index: tuple[np.ndarray, np.ndarray, float, int, int, np.ndarray, np.ndarray],
    pillars: np.ndarray,
    samples: np.ndarray,
    weights: np.ndarray,
    found: tuple[float, float, float, int, int, np.ndarray, np.ndarray],
    tol: float,
) -> tuple[float, float]:
    """(Σ weights of the boundary samples covered, Σ distances to the boundary) of a map
    (``variate`` … ``hi``, every row, as :func:`sample_rows` reads them, sampled every
    ``step``) placed by ``pose`` (3,), (c, s) the cosine and sine of its heading
    (:func:`_placed`). A placed sample's distance is :func:`_boundary_distances`' (the wall
    ``index`` and the ``pillars`` (P, 3)); the boundary ``samples`` (M, 2) of ``weights``
    (M,), bucketed in ``found`` (:func:`buckets` with ``tol``), are covered by the finite
    placed samples strictly within ``tol`` (:func:`covered_by`). Both sums in numpy's order,
    over the distances and over the covered weights in sample order."""
    own = sample_rows(variate, coeffs, lo, hi, np.arange(variate.shape[0]), step, dense)[0]
    placed = _placed(own, pose, c, s)
    dist = _boundary_distances(placed, index, pillars)
    near = covered_by(samples, *found, placed, tol)  # (M,)
    return _weight_sum(weights, near), sum_like_numpy(dist, 0, dist.shape[0])


@njit
def map_quality_sums(
    variate: np.ndarray,
    coeffs: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    step: float,
    dense: int,
    pose: np.ndarray,
    c: float,
    s: float,
    frame: np.ndarray,
    frame_c: float,
    frame_s: float,
    same: bool,
    index: tuple[np.ndarray, np.ndarray, float, int, int, np.ndarray, np.ndarray],
    pillars: np.ndarray,
    samples: np.ndarray,
    weights: np.ndarray,
    found: tuple[float, float, float, int, int, np.ndarray, np.ndarray],
    tol: float,
    seen: np.ndarray,
    duplicate_tol: float,
    max_sine: float,
) -> tuple[float, float, float, float, float, int, int, int]:
    """The sums behind the map-quality metrics of a map (``variate`` … ``hi``, n ≥ 1 rows,
    sampled every ``step`` by :func:`sample_rows`) placed by ``pose`` (3,) and by ``frame``
    (3,) ((c, s) and (``frame_c``, ``frame_s``) their headings' cosines and sines; ``same``:
    the frame is the pose, placed once), in numpy's order: (Σ over the polynomials of the sum
    of their samples' distances to the boundary (:func:`_boundary_distances`), Σ of all
    distances, the same placed by ``frame``, Σ weights of the boundary ``samples`` covered
    within ``tol`` (:func:`covered_by` over the buckets ``found``), the same of those also
    ``seen`` (M,), how many distances are ≤ ``tol``, how many samples lie within
    ``duplicate_tol`` of a parallel sample of another polynomial (:func:`parallel_neighbours`
    of the unit central-difference tangents, |sin| ≤ ``max_sine``), and the samples)."""
    own, starts = sample_rows(variate, coeffs, lo, hi, np.arange(variate.shape[0]), step, dense)
    n = own.shape[0]
    placed = _placed(own, pose, c, s)
    dist = _boundary_distances(placed, index, pillars)
    pieces = np.empty(starts.shape[0] - 1)  # (n_polys,) each polynomial's sum
    for q in range(pieces.shape[0]):
        pieces[q] = sum_like_numpy(dist, starts[q], starts[q + 1] - starts[q])
    total = sum_like_numpy(dist, 0, n)
    total_abs = total
    if not same:
        dist_abs = _boundary_distances(_placed(own, frame, frame_c, frame_s), index, pillars)
        total_abs = sum_like_numpy(dist_abs, 0, n)
    near = covered_by(samples, *found, placed, tol)  # (M,)
    within = 0
    for i in range(n):
        if dist[i] <= tol:
            within += 1
    owner = np.empty(n, dtype=np.int64)
    for q in range(starts.shape[0] - 1):
        owner[starts[q] : starts[q + 1]] = q
    tangent, has_dir = _unit_tangents(own, starts)
    marked = parallel_neighbours(own, owner, tangent, has_dir, duplicate_tol, max_sine)
    return (
        sum_like_numpy(pieces, 0, pieces.shape[0]),
        total,
        total_abs,
        _weight_sum(weights, near),
        _weight_sum(weights, near & seen),
        within,
        int(np.count_nonzero(marked)),
        n,
    )


@njit
def _placed(own: np.ndarray, pose: np.ndarray, c: float, s: float) -> np.ndarray:  # (N, 2)
    """Points (N, 2) of a frame placed by its ``pose`` (3,) ((c, s) its heading's cosine and
    sine): (x + c·p₀ − s·p₁, y + s·p₀ + c·p₁), as ``geometry.transform_points``."""
    placed = np.empty((own.shape[0], 2))
    for i in range(own.shape[0]):
        px, py = own[i, 0], own[i, 1]
        placed[i, 0] = pose[0] + c * px - s * py
        placed[i, 1] = pose[1] + s * px + c * py
    return placed


@njit
def _boundary_distances(
    points: np.ndarray,
    index: tuple[np.ndarray, np.ndarray, float, int, int, np.ndarray, np.ndarray],
    pillars: np.ndarray,
) -> np.ndarray:  # (N,)
    """``boundary.distance_to_boundary``: each point's (N, 2) distance to the wall ``index``
    (:func:`wall_distances`) and to the pillars (P, 3), |‖p − centre‖ − r|, the least, NaN if
    any is NaN (``np.minimum``'s rule)."""
    dist = wall_distances(points, *index)
    for i in range(points.shape[0] if pillars.shape[0] else 0):
        least = np.inf
        for k in range(pillars.shape[0]):
            dx, dy = points[i, 0] - pillars[k, 0], points[i, 1] - pillars[k, 1]
            d = abs(math.hypot(dx, dy) - pillars[k, 2])
            least = d if k == 0 else _minimum(least, d)
        dist[i] = _minimum(dist[i], least)
    return dist


@njit
def _minimum(a: float, b: float) -> float:
    """``np.minimum(a, b)``: the lesser, NaN if either is."""
    return a if a != a or a < b else b


@njit
def _weight_sum(weights: np.ndarray, mask: np.ndarray) -> float:
    """``weights[mask].sum()`` (M,): the weights picked, in order, summed in numpy's order."""
    kept = np.empty(weights.shape[0])
    k = 0
    for j in range(weights.shape[0]):
        if mask[j]:
            kept[k] = weights[j]
            k += 1
    return sum_like_numpy(kept, 0, k)


@njit
def _unit_tangents(points: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unit tangents (N, 2) of each polynomial's samples (rows ``starts[q]:starts[q+1]``
    of ``points`` (N, 2)) and which have a direction (N,): ``np.gradient`` along each
    (central differences / 2 inside, one-sided at the ends, zero for a single point) over
    its norm √(x² + y²), zero where the norm is not > 0 (``mapping._tangents`` and the
    normalising of ``mapping._duplicates``)."""
    n = points.shape[0]
    tangent = np.zeros((n, 2))
    has_dir = np.zeros(n, dtype=np.bool_)
    for q in range(starts.shape[0] - 1):
        first, last = starts[q], starts[q + 1] - 1
        if last <= first:
            continue  # a single point (or none): no direction
        for i in range(first, last + 1):
            if i == first:
                dx, dy = points[i + 1, 0] - points[i, 0], points[i + 1, 1] - points[i, 1]
            elif i == last:
                dx, dy = points[i, 0] - points[i - 1, 0], points[i, 1] - points[i - 1, 1]
            else:
                dx = (points[i + 1, 0] - points[i - 1, 0]) / 2.0
                dy = (points[i + 1, 1] - points[i - 1, 1]) / 2.0
            norm = math.sqrt(dx * dx + dy * dy)
            if norm > 0:
                tangent[i, 0], tangent[i, 1] = dx / norm, dy / norm
                has_dir[i] = True
    return tangent, has_dir


@njit
def record_rows(
    slots: np.ndarray,
    true_poses: np.ndarray,
    est_poses: np.ndarray,
    est_covs: np.ndarray,
    slam_times: np.ndarray,
    ranges: np.ndarray,
    collided: np.ndarray,
    diverging: np.ndarray,
    lengths: np.ndarray,
    true: np.ndarray,
    est: np.ndarray,
    cov: np.ndarray,
    times: np.ndarray,
    beams: np.ndarray,
    path_length: np.ndarray,
    collisions: np.ndarray,
    diverged: np.ndarray,
    diverged_at: np.ndarray,
) -> None:
    """Append one step to slots ``slots`` (K,) of a team history (changes its arrays): slot
    ``j = slots[k]`` writes row ``lengths[j]`` of ``true``, ``est`` (capacity, J, 3), ``cov``
    (capacity, J, 3, 3), ``times`` (capacity, J) and ``beams`` (capacity, J, B) from row k of
    ``true_poses``, ``est_poses`` (K, 3), ``est_covs`` (K, 3, 3), ``slam_times`` (K,) and
    ``ranges`` (K, B); adds the true step's
    length to ``path_length[j]``, ``collided[k]`` to ``collisions[j]``; ``diverging[k]`` sets
    ``diverged[j]`` and, the first time, ``diverged_at[j]`` to the row; then counts the row
    in ``lengths``. The caller makes room first (capacity > every ``lengths[j]``)."""
    for k in range(slots.shape[0]):
        j = slots[k]
        row = lengths[j]
        dx = true_poses[k, 0] - true[row - 1, j, 0]
        dy = true_poses[k, 1] - true[row - 1, j, 1]
        path_length[j] += math.hypot(dx, dy)
        for a in range(3):
            true[row, j, a] = true_poses[k, a]
            est[row, j, a] = est_poses[k, a]
            for b in range(3):
                cov[row, j, a, b] = est_covs[k, a, b]
        times[row, j] = slam_times[k]
        for b in range(ranges.shape[1]):
            beams[row, j, b] = ranges[k, b]
        if collided[k]:
            collisions[j] += 1
        if diverging[k] and not diverged[j]:
            diverged[j] = True
            diverged_at[j] = row
        lengths[j] = row + 1
