"""Named rows of the SLAM's struct-of-arrays buffers (STYLE habit 21).

The landmark table (:class:`~polyslam_env.slam.landmarks.LandmarkTable`) and the stored beam
points (:class:`~polyslam_env.slam.stored.StoredPoints`) keep their columns field-major: one
float64 buffer ``real`` (fields × capacity) and one int64 buffer ``index`` (fields ×
capacity), so ``real[LO]`` is every landmark's lower extent end as one contiguous array. The
compiled step (:mod:`~polyslam_env.slam.map_kernels`) takes these few buffers whole: numba
unpacks a plain array argument in ~0.25 µs, while a NamedTuple of arrays costs ~3 µs per call
however few its fields (its class is fingerprinted on every call; measured on numba 0.68), a
real share of a step budgeted at tens of µs.
"""

from __future__ import annotations

# -- the landmark table: real fields (row i of a field = landmark i, in state order) -----------
LO = 0  # extent on ξ
HI = 1
ETA_LO = 2  # bounds of B over the extent (no c0), for the boxes
ETA_HI = 3
EV_LO = 4  # ξ-interval of the hits that support the landmark
EV_HI = 5
PIVOT = 6  # ξ its shape turns about (and its c0 measures the offset at)
XI_VAR = 7  # pose variance along ξ when it was made
MODEL_VAR = 8  # fit variance beyond the range noise
FIT_HALF = 9  # half the extent it was fitted over
N_REAL = 10

# -- the landmark table: integer fields ----------------------------------------------------------
ID = 0  # stable id
VARIATE = 1  # 1: η = x², 2: η = x¹
ORDER = 2  # its shape's own order (no zero tail, ≥ 1)
SIDE = 3  # face its beams saw: +1 from +η, −1 from −η, 0 unknown
CHANGED_AT = 4  # step it was created, refit or merged
STAMP = 5  # bumped whenever its shape or extent changes (lazy Polynomial views)
N_INDEX = 6

# -- stored beam points: real fields -------------------------------------------------------------
X = 0  # frame-0 position
Y = 1
UX = 2  # unit beam direction (its range noise acts along it)
UY = 3
PX = 4  # pose estimate of the step that measured it
PY = 5
PTH = 6
SIGMA = 7  # range noise σ (m)
WEIGHT = 8  # LMS weight 1/‖P_{k|k−1}‖ of its step
N_POINT_REAL = 9

# -- stored beam points: integer fields ----------------------------------------------------------
BEAM = 0  # beam index at its step
STEP = 1  # step it was measured at
KIND = 2  # what holds it (below)
OWNER = 3  # cluster key, landmark id or request number
RANK = 4  # order within its holder: points of one holder sort by rank
N_POINT_INDEX = 5

# point kinds: the order of the stored-point model's groups (clusters first, oldest first, then
# each landmark's Q_bad in id order), then this step's requests
CLUSTER = 0
QBAD = 1
REFIT = 2  # a landmark's Q_bad past ε_M, to refit (owner: the request's number)
NEW = 3  # a cluster past ε_Z, to fit as a new landmark (owner: the request's number)

# counters of the stored points (a small int64 array beside the buffers)
SIZE = 0  # rows in use
NEXT_RANK = 1
NEXT_CLUSTER = 2  # key of the next cluster (keys grow: cluster order is key order)
N_REFIT = 3  # this step's requests
N_NEW = 4
N_COUNTERS = 5
