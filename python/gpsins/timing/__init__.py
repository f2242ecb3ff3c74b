"""Time alignment: GPS time for every IMU sample from the logger's system-time stamps.

Stamps follow `stamp = system clock at the frame's first byte + a constant
latency per device + a non-negative delay`. The delay is usually a fraction of
a millisecond, but a loaded host holds frames for hundreds of milliseconds and
then stamps them all at once. The latencies cannot be seen in the stamps, so
they are configuration (for the GPS stream: the receiver's delay from its
measurement epoch to the first byte of ID 23, plus the logger's).

Two methods:

- ``report`` (the FOI report, 4.3.2): IMU start = GPS time of the first GPS sample
  minus the difference of the two sensors' first system stamps; sample k at
  start + k / 64 s. Every dropped frame shifts all later samples by 1/64 s.
- ``robust`` (default), in four stages:

  1. GPS clock: system time against every ID 23's time of week. The system
     clock's rate against GPS time is estimated first (a median of slopes, so a
     recording served faster than real time or a drifting clock is no special
     case) and removed; what is left is a clock offset that is constant between
     realtime clock steps, plus delays that are never negative. A stamp far
     below the floors of the stamps on both sides cannot be a delay: it is a
     damaged stamp and is left out (a few in a row or close together too: each
     floor is a low order statistic, not the minimum). "Far" is GPS time, what
     a damaged stamp left in would cost: served S times faster, S times fewer
     system seconds. A step is a change of the running minimum that lasts (the
     minimum over a window is blind to delays shorter than the window; the
     threshold grows with the delays). A step up undone by one down of the same
     size within 10 s is a host stall longer than the window, not two steps.
     The segments between steps share the rate and are fitted along their
     joint lower envelope, each with its own offset.
  2. Which IMU frames precede each step: the frames are in arrival order, so
     each step is one cut in the IMU stream. A coarse cut from the GPS time at
     which the GPS stream brackets the step (and, for a step over a second, the
     jump or drop it makes on the old map); then, over every frame that could
     lie on either side, the cut that makes the IMU clock's floor tightest
     (the lower envelope's objective with the cut as a free variable). Stamps
     alone cannot do it: a step of a whole number of counter periods, 4 s at
     64 Hz, looks exactly like a gap.
  3. The IMU's sample index from its 8-bit frame counter; across a gap of 256
     frames or more, the number of whole counter periods comes from the mapped
     times: the floors over 10 s on each side (a host stall outlasts a 400 Hz
     counter's 0.64 s period). The frame period is the configured rate's unless
     the stamps disagree by more than 1 %.
  4. The IMU's own clock: t = t0 + P n along the lower envelope of the mapped
     times, per stretch between gaps longer than ``PIECE_GAP_S`` (an unplugged
     or restarted IMU may resume with another phase); stretches too short to
     give a rate use the others' P. Dropped frames leave gaps; the IMU's clock
     drift is P against the GPS-disciplined time.

The lower envelope is the line under all points that minimises the summed
residual (a linear programme). With one slope and an offset per group, each
offset is the group's minimum of y - b x for a given slope b, so the objective
is convex and piecewise linear in b and its optimum lies at the slope of an
edge of a group's lower convex hull (Qhull).
"""

from __future__ import annotations


METHODS = ("robust", "report")
GPS_WINDOW = 30  # ID 23 blocks (3 s at 10 Hz) for running minima: longer than a host stall
IMU_WINDOW_S = 3.0
MIN_SIDE = 15  # blocks on each side before a step can be told from delays
OUTLIER_TOL_S = 0.0005  # GPS seconds: a stamp this far below the floors on both sides is damaged
DAMAGE_SHARE = 64  # a floor is the (1 + w // 64)-th smallest of w stamps: one damaged in 64 does not lower it
UNWRAP_WINDOW_S = 10.0  # longer than host stalls: the floor on each side of a gap
MEDIAN_FRAMES = 5  # frames whose median stands for one frame's time in the coarse cut
PIECE_GAP_S = 1.0  # an IMU gap this long may restart its clock: fit each side on its own
MARGIN_S = 2.0  # delays and stalls allowed for around a step's GPS bracket
RATE_MISMATCH = 0.01  # configured IMU rate this far from what the stamps show: use the stamps
LATE_S = 60.0  # a stamp this late is damaged, not delayed
STALL_MAX_S = 10.0  # an apparent step up and back down within this is a host stall
MIN_RATE_SPAN_S = 20.0  # an IMU stretch shorter than this takes the IMU period from the others
OVERLAP_SLACK_S = 600.0  # IMU stamps this far outside the GPS stamps cannot share their clock map


class AlignmentError(ValueError):
    pass
