"""Where each part of one observer's state lives in its arrays (constants, no code).

An observer is a handful of float arrays, views of one buffer
(:class:`mav_observer.core.state.ObserverState` makes it from an
:class:`~mav_observer.core.config.ObserverConfig`; where each array sits and its shape are
written in ``cfg`` from ``O_ARRAYS`` on, so that a kernel takes the buffer alone):

* ``cfg``: its settings (``O_*``), the filter bank's from ``O_BANK`` on
  (:mod:`~mav_observer.core.kernels.bank`'s ``P_*``);
* ``s``: its scalars (``S_*``) and the blocks of the parts it is made of, each laid out by
  its own module: the streams (``OFF_Q``), the bank's run (``OFF_BS``), the latency
  (``OFF_LAT``), its settling (``OFF_SET``), the innovations' correlation (``OFF_WH``), the
  velocity noise (``OFF_VN``) and, last, the hypotheses' log weights (``OFF_LOGW``);
* ``vec`` (rows, n): its vectors (``R_*``), the paper's ``M`` as the rows from ``R_M``;
* ``fs``, ``fp``: the bank's filters; ``vbuf``, ``bbuf``: the sample buffers; ``win``: the
  monitor's window; ``out``: estimates written for the caller (``E_*`` columns); ``wk``:
  scratch.

A time that is not there yet (no committed time, no bearing) is NaN.
"""

from __future__ import annotations

# -- cfg ----------------------------------------------------------------------------------
O_N = 0
O_KIND = 1  # KIND_BANK or KIND_PAPER
O_BIASED = 2  # mode "biased" (else "bias_free")
O_LINEAR = 3  # interpolation "linear" (else "hold")
O_MAX_BEARING_AGE_S = 4
O_MAX_VELOCITY_AGE_S = 5
O_MAX_BUFFER = 6
O_WINDOW_S = 7
O_BUCKET_S = 8
O_WINDOW_FULL_S = 9
O_EXCITATION_MIN = 10
O_CONVERGED_TOL = 11
O_K = 12
O_K_STAR = 13
O_STATIC_HOLD = 14
O_HOLD_SPEED2 = 15
O_HOLD_COS = 16
O_MIN_INTERVAL_S = 17
O_RANGE_GUESS_M = 18
O_INITIAL_RANGE_M = 19  # NaN: not set
O_VELOCITY_NOISE_MPS = 20  # NaN: learnt
O_LATENCY_S = 21  # NaN: learnt
O_COMMITTED = 22  # keep the committed estimate at each bearing
O_MAX_LATENCY_S = 23
O_VELOCITY_NOISE_PRIOR_MPS = 24
O_WK_EST = 25  # where the estimator's scratch starts in wk (after the bank's)
O_WK_OBS = 26  # where the observer step's starts
O_MAX_VELOCITY_WAIT_S = 27
O_ARRAYS = 32  # then, per array A_* of the state, its offset in the buffer and 3 dimensions
O_BANK = 80

KIND_BANK = 0.0
KIND_PAPER = 1.0

# -- the arrays, in one buffer: cfg (A_CFG) first ----------------------------------------
A_CFG = 0
A_S = 1
A_VEC = 2
A_FS = 3
A_FP = 4
A_VBUF = 5
A_BBUF = 6
A_WIN = 7
A_OUT = 8
A_WK = 9
A_COUNT = 10

# -- s ------------------------------------------------------------------------------------
S_T_C = 0  # the committed time (NaN before the start)
S_N_VELOCITY = 1  # samples accepted
S_N_BEARING = 2
S_STATUS = 3  # monitor.STALE ...
S_SINCE = 4  # observable since (NaN: not now)
S_DIAG_T = 5  # the excitation's cache: when (NaN: none) and its value
S_DIAG_EXC = 6
S_COND_OK = 7  # the condition number's cache: valid, for which committed time, value
S_COND_T = 8
S_COND = 9
S_T_BEARING = 10  # the estimator's latest bearing applied (NaN: none)
S_SETTLED = 11  # the latency learnt has settled once
S_STARTED = 12  # the estimator has started
S_HELD = 13  # committed past the latest velocity, held (it was stale), until the next one
S_T_RANGE = 14  # the latest range applied (NaN: none)
OFF_Q = 16
OFF_BS = 24
OFF_LAT = 40
OFF_SET = 56
OFF_WH = 60
OFF_VN = 72
OFF_LOGW = 84

# -- vec rows -------------------------------------------------------------------------------
R_XH1 = 0  # the paper's first filter
R_AHAT = 1  # the paper's bias
R_WH_PREV = 2  # the previous innovation (its correlation)
R_VN = 3  # the velocity noise's latest four samples, rows 3 .. 6
R_M = 7  # the paper's matrix M: n rows from here
R_FIXED = 7

# -- out columns ----------------------------------------------------------------------------
E_T = 0
E_RANGE = 1
E_EXCITATION = 2
E_COND = 3
E_STATUS = 4
E_CORRECTED = 5
E_BEARING_AGE = 6  # NaN: no bearing
E_VELOCITY_AGE = 7
E_CORRECTION_REL = 8
E_RANGE_STD = 9  # NaN: no covariance
E_NIS = 10  # NaN: none
E_HAS_COV = 11
E_X = 12  # then a, x's standard deviations, a's: n each
E_FIXED = 12

# -- the filter bank: its settings (bp) and a run's scalars (bs) ------------------------
P_SIGMA_RAD = 0  # bearing noise per tangent direction (told, or the learnt one's prior)
P_Q_X = 1  # white noise on x' (m^2/s): the harness's; the observer passes its own
P_Q_A = 2  # the bias's random walk (m^2/s^3) when told
P_HYPOTHESES = 3
P_SPAN = 4  # the hypotheses' ranges: r0 * span**u, u in [-1, 1]
P_RANGE_REL_STD = 5
P_BIAS_STD = 6  # prior std of each component of a (m/s)
P_PRUNE = 7
P_PRUNE_EARLY = 8
P_PRUNE_EARLY_S = 9
P_MERGE_MAHA = 10
P_NIS_GATE = 11
P_NIS_WINDOW_S = 12
P_OUTLIER_NIS = 13  # inf: no robust weighting
P_LEARN_NOISE = 14  # 1.0 or 0.0
P_NOISE_MEMORY_S = 15
P_NOISE_PRIOR_DOF = 16
P_NOISE_MIN_RAD = 17
P_NOISE_MAX_RAD = 18
P_LEARN_WALK = 19
P_WALK_FACTOR = 20
P_WALK_MIN = 21
P_WALK_JUMP = 22
P_WALK_MAX = 23
P_WALK_UP_NATS = 24
P_WALK_LEAVE_NATS = 25
P_WALK_DOWN_NATS = 26
P_WALK_MEMORY_S = 27
P_WALK_WARMUP_S = 28
P_COUNT = 29
B_F = 0  # hypotheses alive
B_R0 = 1  # the range guess: the Riccati observer's weight range
B_NIS_AVG = 2  # the innovations' running mean (NIS, sum over tangent directions)
B_AGE_S = 3  # since the latest seeding
B_RESEEDS = 4
B_NOISE_ALPHA = 5  # the learnt bearing noise's inverse-gamma posterior
B_NOISE_BETA = 6
B_OUTLIERS = 7
B_BEARINGS = 8
B_INLIER_AVG = 9
B_WALK_Q = 10  # the bias walk's level in use (m^2/s^3), when learnt
B_WALK_ON = 11  # 1 while the probes run
B_WALK_LL_LO = 12  # the probes' log-likelihood lead over the filter
B_WALK_LL_HI = 13
B_COUNT = 14

# -- the sample streams: vbuf's columns and their scalars (q) --------------------------
VB_T = 0
VB_HAS_MEAN = 1
VB_V = 2  # then the mean at VB_V + n
Q_NV = 0  # velocity rows in use
Q_NB = 1  # bearing rows in use
Q_VDT = 2  # the velocity's latest sample interval (s, at most 1)
Q_EX_W = 3  # the extrapolation error's forgetting sums: weights and squared drift rates,
Q_EX_S = 4  # of the samples and of the prior
Q_EX_WP = 5
Q_EX_SP = 6
Q_COUNT = 7

# -- the learners' scalars: latency (L_), its settling (T_), velocity noise (V_), the
#    innovations' correlation (W_) --------------------------------------------------------
L_S_ZW = 0
L_S_WW = 1
L_TAU = 2  # the latency in use (s)
L_T = 3  # the latest bearing learnt from (NaN: none)
L_T0 = 4  # the first (NaN: none)
L_TAU_FIT = 5
L_B_T0 = 6  # the open block's start (NaN: none)
L_B_ZW = 7
L_B_WW = 8
L_Q_ZZ = 9
L_Q_ZW = 10
L_Q_WW = 11
L_N_B = 12
L_COUNT = 13
T_REF = 0  # NaN: none yet
T_TAU_REF = 1
T_SETTLED = 2
T_COUNT = 3
V_W = 0
V_S = 1
V_WP = 2
V_SP = 3
V_COUNT_LAST = 4  # samples held (up to 4)
V_T = 5  # their times, 4
V_COUNT = 9
W_HAS_PREV = 0
W_PREV_SQ = 1
W_T_PREV = 2
W_C0 = 3
W_C1 = 4
W_N = 5
W_DT = 6
W_SQ = 7
W_M = 8
W_COUNT = 9

# -- the monitor: statuses and the window's columns --------------------------------------
STALE = 0
NOT_OBSERVABLE = 1
CONVERGING = 2
CONVERGED = 3
C_IDX = 0
C_COVERED = 1
C_VALID = 2
C_YY = 3

# -- what a new state starts from (``mav_observer.core.state.reset``) ---------------------------
#: The velocity's sample interval (s) assumed before two samples have arrived.
DEFAULT_VELOCITY_DT_S = 0.05
#: The prior of a sparse stream's extrapolation error (m/s^2 per axis), and how many
#: intervals it weighs.
EXTRAPOLATION_PRIOR_MPS2 = 1.0
EXTRAPOLATION_PRIOR_WEIGHT = 3.0
#: How many samples the velocity noise's prior weighs.
VN_PRIOR_SAMPLES = 20.0
#: Sample times closer than this to an interval end are not made breakpoints (s), for an
#: estimator that merges them (the paper's, with linear interpolation): a sliver of a few
#: ms costs far less to merge than the sub-step it would take.
MIN_INTERVAL_S = 0.01

# -- return codes of the entry points (>= 0: committed estimates written) --------------------
ERR_VELOCITY_BACKWARDS = -1
ERR_BEARING_BACKWARDS = -2
ERR_BEARING_TOO_OLD = -3
ERR_BUFFER_FULL = -4
ERR_BEFORE_COMMITTED = -5
