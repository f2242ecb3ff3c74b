"""The report's roller coaster (seed 004 section 6.1) through both filters:
`python benchmarks/bench_roller_coaster.py [seed]`.

Simulates the `roller-coaster` scenario (5 min at rest, 11 laps), runs the loose
and the tight filter with the simulated unit's noise figures, and prints per
segment (initialisation, each lap, stop) the horizontal and vertical RMS error,
the yaw error and the time-averaged NEES of the 9 navigation states against the
truth; then what the reference system (the session's reference.csv, dual-antenna
RTK) could have scored: the share of its epochs with a position or attitude.
"""

import sys
import time

import numpy as np

from gpsins import _core, evaluate, sim
from gpsins import filter as flt
from gpsins.sim import ephemeris as sim_eph


def main(seed: int = 0) -> None:
    t0 = time.time()
    sc = sim.load("roller-coaster")
    s = sim.simulate(sc, seed=seed)
    tr = s.truth
    truth = evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)
    print(f"simulated {sc.duration_s:.0f} s in {time.time() - t0:.1f} s")
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, sc.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    gps0 = sc.start.gps_week * 604800.0 + sc.start.gps_tow_s
    tight = dict(pseudoranges=sim.pseudorange_table(s), ephemerides=ephs,
                 klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta), gps_time_offset_s=gps0)
    fixes = sim.fix_table(s)
    sats = np.array([f.sats for f in s.gnss.fixes])
    for mode, extra in (("loose", {}), ("tight", tight)):
        t1 = time.time()
        cfg = flt.load_config(None, {**sim.imu_noise_truth(sc.imu), "mode": mode})
        sol = flt.run(sim.imu_table(s), fixes, cfg, covariance=True, **extra)
        err = evaluate.nav_errors(sol, truth)
        print(f"\n{mode}: {time.time() - t1:.1f} s, diverged {sol.counters['diverged']}")
        print(f"{'segment':16s} {'sats':>9s} {'horiz m':>8s} {'vert m':>7s} {'yaw deg':>8s} {'NEES':>7s}")
        for label, a, b in sc.segment_times():
            m = (sol.t >= a) & (sol.t < b)
            fm = (fixes[:, 0] >= a) & (fixes[:, 0] < b)
            h = np.sqrt(np.mean(np.sum(err.r_ned[m, :2] ** 2, axis=1)))
            v = np.sqrt(np.mean(err.r_ned[m, 2] ** 2))
            yaw = np.sqrt(np.mean(err.ypr_deg[m, 0] ** 2))
            nees = evaluate.nees(err.e9[m], sol.covariance[m][:, :9, :9]).mean()
            print(f"{label:16s} {sats[fm].min():>4d}-{sats[fm].max():<4d} {h:8.2f} {v:7.2f} {yaw:8.2f} {nees:7.1f}")
    ref = s.reference  # the simulation's dual-antenna RTK reference
    print("\nreference system (dual-antenna RTK) availability per segment: position / attitude")
    for label, a, b in sc.segment_times():
        m = (ref.t >= a) & (ref.t < b)
        print(f"{label:16s} {ref.position_ok[m].mean():5.0%} / {ref.attitude_ok[m].mean():5.0%}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 0)
