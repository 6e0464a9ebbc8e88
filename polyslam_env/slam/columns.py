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
# the slope s̄ its c0 moves by when its whole shape shifts along ξ (c0 changes by −s̄·δξ: the
# fit's points' weighted mean slope); nan where no shift of the pose's makes it (received)
SHIFT_SLOPE = 10
N_REAL = 11

# -- the landmark table: integer fields ----------------------------------------------------------
ID = 0  # stable id
VARIATE = 1  # 1: η = x², 2: η = x¹
ORDER = 2  # its shape's own order (no zero tail, ≥ 1)
SIDE = 3  # face its beams saw: +1 from +η, −1 from −η, 0 unknown
CHANGED_AT = 4  # step it was created, refit or merged
STAMP = 5  # bumped whenever its shape or extent changes (lazy Polynomial views)
RECEIVED = 6  # 1: it holds a received landmark (never linked nor tied square)
USES = 7  # updates its beams entered since its shape was fitted (kernels.reuse_factors)
N_INDEX = 8

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

# -- the filter's model: float64 ``params`` and int64 ``switches`` (made once per robot) ----------
P_RANGE_SIGMA = 0  # σ of the range noise the filter assumes (m)
P_RANGE_VAR = 1  # σ²
P_CLUSTER_RADIUS = 2  # R (m)
P_TURN_VAR_PER_STEP = 3  # the odometry's heading variance per step (rad²)
P_SQUARE = 4  # 2.0: the exponent of Python's ``x ** 2`` (``map_kernels`` says why)
P_MAX_RANGE = 5  # the range sensor's r_max (m)
P_REACH = 6  # r_max + a margin: landmarks whose box lies farther cannot be hit
P_MIN_SINE = 7  # sin of the smallest incidence angle a beam's row is used at
P_GATE = 8  # χ²(1) quantile of the beams' gate
P_END_SIGMA = 9  # rows this many σ from their landmark's end are left out (0: none)
P_MIN_UPDATE_EXTENT = 10  # landmarks shorter than this (m) do not update the pose
P_RHO_MIN = 11  # ρ_k and σ_k at f = 0 and f = 1
P_RHO_MAX = 12
P_SIGMA_MIN = 13
P_SIGMA_MAX = 14
P_KP0_NORM = 15  # ‖K P0‖
P_SMALL_POSE = 16  # (λ_min(K P0)/2)²: a pose block of smaller ‖·‖²_F is far below K P0
P_KP0 = 17  # K P0, 9 entries row by row
P_ODOM_COV = 26  # the odometry's noise covariance W, 9 entries row by row
N_PARAMS = 35

S_SQUARED = 0  # the paper's squared approximation error
S_STRETCH_ENDS = 1
S_ROTATION_STATES = 2  # each landmark's turn α is a state (at 3 + n + row)
S_LINK_CLUSTERS = 3
S_EPS_M = 4
S_EPS_Z = 5
S_SHAPE_FOLLOWS_POSE = 6
S_N_FIT = 7  # ε_Z + 1: the points a landmark is born from (its frozen shape's fit model)
S_LINK_AGE = 8  # steps after a landmark changed that its links are sought
S_LINKS = 9  # 1 when links or square ties are on
S_SCREEN_ALARM = 10  # outliers among the screen's window that raise the alarm
S_REUSE_BOUND = 11  # whose own error is bounded over updates: 0 none, 1 curved, 2 all (REUSE_*)
S_SHIFT_WITH_POSE = 12  # 1: a frozen shape's shift along ξ is the current pose's error along ξ
S_SEEN_FACES = 13  # 1: a beam cast onto a landmark's unseen face is left out of the update
N_SWITCHES = 14

# -- per beam (a (2, B) float64 ``beams`` model, an (N_PER_BEAM, B) int64 output) ----------------
B_ANGLE = 0  # the beam's angle in the robot frame
B_UPDATE = 1  # 1.0 when it enters the update (``update_spacing_deg``), else 0.0
N_BEAM_MODEL = 2
G_GOOD = 0  # id of the landmark the beam is good for (−1: none)
G_ROW = 1  # the landmark row it went to the update with (−1: not in the update)
G_REQUEST = 2  # landmark id of refit request k (the first N_REFIT entries)
N_PER_BEAM = 3

# -- one step's outcome (int64 ``status`` and float64 ``values``, kept between steps) ------------
ST_EXTENTS = 0  # extents the association stretched
ST_FRESH = 1  # landmarks changed ``link_age`` steps ago (links to seek)
ST_USED = 2  # rows the update used (−1: no usable row, nothing ran)
ST_OUTLIERS = 3  # outliers among the screen's last SCREEN_WINDOW beams
ST_PAPER_TEST = 4  # 1: the pose block is not far below K P0 (the paper's test must decide)
ST_SCREEN_FILL = 5  # flags in the screen's window
ST_SCREEN_NEXT = 6  # where the next flag goes
ST_SCREEN = 7  # the window's flags (SCREEN_WINDOW entries)
V_RHO = 0  # this step's thresholds
V_SIGMA = 1
V_F = 2  # the divergence ratio f
V_FIRST_X = 3  # x̂_{k|k−1}'s position (first-estimates Jacobian; nan before the first step)
V_FIRST_Y = 4
V_BEFORE = 5  # the pose before the update (3 entries)
N_VALUES = 8
