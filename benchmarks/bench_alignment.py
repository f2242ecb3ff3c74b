"""Time alignment speed and accuracy on long synthetic streams:
`python benchmarks/bench_alignment.py [hours] [imu_rate_hz] [speed]` (default 1 h at 400 Hz,
served at real time).

Stamps as the logger writes them under load: exponential jitter, host stalls
(Poisson, Pareto lengths, mean 0.3 s) that hold both streams, 1 % of IMU frames
dropped, a 30 ppm IMU clock, a 10 s IMU unplug and a +4 s realtime clock step
(a whole number of counter periods). Served `speed` times faster than real time
(as `gpsins run --speed`), the system clock runs that much faster than GPS time and
0.3 % of the IMU stamps (some two in a row) are early by 0.2-2 ms of system time, as
a host dates frames that came faster than its line; the jitter and stalls keep their
GPS-time lengths (a host that is fast enough), so only the rate and the early stamps
change. Prints the alignment's wall time, peak RSS and its IMU time error against
the synthetic truth.
"""

import resource
import sys
import time

import numpy as np

from gpsins.timing import alignment


def stalled(t: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    k = np.searchsorted(start, t, side="right") - 1
    reach = np.maximum.accumulate(end)[np.maximum(k, 0)]
    return np.where((k >= 0) & (t < reach), reach, t)


def main(hours: float = 1.0, rate_hz: float = 400.0, speed: float = 1.0) -> None:
    rng = np.random.default_rng(1)
    span = hours * 3600.0
    n_stalls = rng.poisson(span)
    start = np.sort(rng.uniform(0, span, n_stalls))
    end = start + 0.3 * 1.5 / 2.5 * (1.0 + rng.pareto(2.5, n_stalls))
    step_at, step = 0.6 * span, 4.0
    system = lambda t: 1.28e9 + t / speed + np.where(t >= step_at, step, 0.0)  # noqa: E731

    tow = np.arange(0.0, span, 0.1)
    gps_first = stalled(tow + rng.exponential(0.002, len(tow)), start, end)
    k = np.arange(int(span * rate_hz))
    t_imu = (k + 1) / (rate_hz * (1 + 30e-6))
    keep = (rng.random(len(k)) > 0.01) & ~((t_imu > 0.3 * span) & (t_imu < 0.3 * span + 10.0))
    k, t_imu = k[keep], t_imu[keep]
    imu_first = stalled(t_imu + rng.exponential(0.002, len(k)), start, end)
    imu_stamps = system(imu_first)
    if speed != 1.0:
        early = np.flatnonzero(rng.random(len(k)) < 0.002)
        early = np.unique(np.concatenate([early, early[::3] + 1]))  # some two in a row
        early = early[early < len(k)]
        imu_stamps[early] -= rng.uniform(0.0002, 0.002, len(early))

    t0 = time.perf_counter()
    al = alignment.align(419400.0 + tow, system(gps_first), 1590, imu_stamps, (k + 1) & 0xFF, rate_hz)
    wall = time.perf_counter() - t0
    err = al.imu_t - (419400.0 + t_imu)
    print(f"{hours:g} h at {rate_hz:g} Hz served at {speed:g}x: {len(k)} IMU frames, {len(tow)} ID 23, "
          f"{n_stalls} stalls")
    print(f"align: {wall:.2f} s, peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    print(f"IMU time error: RMS {1e3 * np.sqrt(np.mean(err ** 2)):.3f} ms, max {1e3 * np.abs(err).max():.3f} ms; "
          f"steps {al.steps_s}; long gaps {al.gap_list(1.0)}; damaged IMU stamps {al.damaged_imu_stamps}")


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:4]))
