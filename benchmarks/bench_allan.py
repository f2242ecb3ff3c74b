"""Overlapping ADEV speed: `python benchmarks/bench_allan.py [SAMPLES] [AXES]`.

6 axes x 10^7 rate samples (default) at about 100 log-spaced taus: gpsins
(C++ kernel, axes on both cores) against allantools.oadev at the same taus;
seconds, peak memory, and the largest relative difference. Target: >= 5x.
"""

import resource
import sys
import time

import allantools
import numpy as np

from gpsins.imu import allan


def main() -> None:
    n = int(float(sys.argv[1])) if len(sys.argv) > 1 else 10_000_000
    axes = int(sys.argv[2]) if len(sys.argv) > 2 else 6
    rng = np.random.default_rng(0)
    y = rng.normal(0.0, 1e-3, (n, axes)) + 1e-2  # rate samples with an offset
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    m = allan.cluster_sizes(n + 1, 15)
    t0 = time.perf_counter()
    r = allan.oadev(y, 100.0, taus=15, alpha=0)  # noise ID off: speed of the deviation itself
    ours = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"gpsins: {axes} axes x {n:,} samples, {len(m)} taus in {ours:.2f} s; peak RSS {peak:.0f} MB "
          f"(data {y.nbytes / 2**20:.0f} MB, before {base:.0f} MB)")
    t0 = time.perf_counter()
    worst = 0.0
    for k in range(axes):
        t, d, _, _ = allantools.oadev(y[:, k], rate=100.0, data_type="freq", taus=r.tau)
        sel = np.isin(np.round(r.tau, 9), np.round(t, 9))
        worst = max(worst, float(np.max(np.abs(d / r.adev[sel, k] - 1))))
    theirs = time.perf_counter() - t0
    print(f"allantools.oadev: {theirs:.2f} s; speed-up {theirs / ours:.1f}x; largest relative difference {worst:.1e}")


if __name__ == "__main__":
    main()
