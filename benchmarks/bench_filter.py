"""Loosely coupled filter: speed and consistency.

    python benchmarks/bench_filter.py speed [REPEATS]   # IMU epochs/s through the batch API
    python benchmarks/bench_filter.py nees [SEEDS]      # NEES over full default drives
    python benchmarks/bench_filter.py tight [REPEATS]   # tight: 10 Hz pseudorange updates
    python benchmarks/bench_filter.py checks            # chi-square gate vs the report's attitude test
    python benchmarks/bench_filter.py interval [SEEDS]  # covariance_interval_s at 200 Hz: NEES, errors, speed

Checks: the default drive clean and with 10 s of zero delta-v, each with every
update check (chi_square, attitude_correction, both, none) and with the GNSS
reset on (5 s) and off: final and RMS errors, rejections, resets, mean NEES.

Speed: the default drive's 18 k IMU epochs (15 states, covariance propagated
every epoch, 1 Hz fixes, standstill updates), run REPEATS times; also a
million-epoch synthetic stream (constant turn, 1 Hz fixes) for the per-epoch
cost without standstill updates. Target >= 200,000 epochs/s.

NEES: the 9 navigation states' NEES averaged over SEEDS full-length default
drives (from the first known heading on), against its two-sided 95 % band.

Interval: the default drive with a 200 Hz IMU, loose, output at 1 Hz, its covariance propagated at
every increment and once per ``covariance_interval_s`` (0.01, 0.02, 0.05 s: 2, 4, 10 increments),
with the IMU noise the simulator drew: per interval the seeds' mean NEES, its band, the position and
attitude error RMS, the largest position difference to the every-increment run, and the filter's time.
"""

import resource
import sys
import time

import numpy as np

from gpsins import _core, evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def synthetic(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle turning at 0.05 rad/s, 10 m/s, level, at 59 N: increments and fixes."""
    dt = 1.0 / 64.0
    t = np.arange(1, n + 1) * dt
    w = np.array([0.0, 0.0, 0.05])
    f = np.array([0.0, 0.5, -9.82])
    imu = np.column_stack([t, np.tile(w * dt, (n, 1)), np.tile(f * dt, (n, 1))])
    r0 = _core.geodetic_to_ecef(np.radians([59.37, 17.95, 30.0]))
    tf = np.arange(1.0, t[-1], 1.0)
    fixes = np.column_stack([tf, np.tile(r0, (len(tf), 1)), np.full((len(tf), 3), np.nan),
                             np.ones(len(tf)), np.ones(len(tf)), np.full(len(tf), 2.0)])
    return imu, fixes


def speed(repeats: int) -> None:
    s = sim.simulate(scenario.load("default"), 0)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    flt.run(imu, fixes, cfg)  # warm up
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        sol = flt.run(imu, fixes, cfg)
    el, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"default drive: {len(imu)} epochs x {repeats} in {el:.2f} s = {len(imu) * repeats / el:,.0f} epochs/s "
          f"(per CPU second {len(imu) * repeats / cpu:,.0f}: the figure to compare on a loaded machine; "
          f"{sol.counters['zero_velocity_updates']} ZUPT, {sol.counters['fixes_accepted']} fixes per run)")
    n = 1_000_000
    imu, fixes = synthetic(n)
    cfg2 = nav_config.load_config(None, {"initial_yaw_deg": 0.0, "zero_velocity_updates": False,
                                         "gate_probability": 0.0})
    before = peak_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    sol = flt.run(imu, fixes, cfg2, output_every=64)
    el, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"synthetic: {n:,} epochs, {len(fixes)} fixes in {el:.2f} s = {n / el:,.0f} epochs/s "
          f"({n / cpu:,.0f} per CPU second); "
          f"peak RSS {peak_mb():.0f} MB (before the run {before:.0f} MB); diverged={sol.counters['diverged']}")


def nees(seeds: int) -> None:
    sc = scenario.load("default")
    runs = []
    for seed in range(seeds):
        s = sim.simulate(sc, seed)
        cfg = nav_config.load_config(None, sim.imu_noise_truth(sc.imu))
        sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True)
        tr = s.truth
        err = evaluate.nav_errors(sol, evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb))
        t0 = sol.t[np.argmax(sol.heading_known)]
        sel = sol.t >= t0
        e = evaluate.nees(err.e9[sel], sol.covariance[sel][:, :9, :9])
        inside = (np.abs(err.e9[sel]) <= 3 * sol.sigma[sel, :9]).mean()
        runs.append(e)
        print(f"seed {seed:2d}: heading from t = {t0:5.1f} s, mean NEES {e.mean():5.2f}, "
              f"inside 3 sigma {100 * inside:5.1f} %, rejected {sol.counters['updates_rejected']}")
    n = min(len(r) for r in runs)
    avg = np.mean([r[:n] for r in runs], axis=0)
    lo, hi = evaluate.nees_band(9, seeds)
    print(f"{seeds} seeds: time-averaged NEES {avg.mean():.2f} (expected 9; 95 % band of a {seeds}-run "
          f"average {lo:.2f}..{hi:.2f}); epochs with the run-average inside the band: "
          f"{100 * np.mean((avg >= lo) & (avg <= hi)):.1f} %")


def tight(repeats: int) -> None:
    """The default drive's pseudoranges at the receiver's full 10 Hz (decimation 1, the preset) and
    at 1 Hz, through the batch API (29 states: 12 signal-in-space slots and the clock)."""
    from gpsins.sim import ephemeris as sim_eph

    s = sim.simulate(scenario.load("default"), 0)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, 1590) for e in s.gnss.ephemerides.values()]
    prs = sim.pseudorange_table(s)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    offset = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    for dec in (1, 10):
        cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": "tight",
                                            "pseudorange_decimation": dec})
        kw = dict(pseudoranges=prs, ephemerides=ephs, klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta),
                  gps_time_offset_s=offset)
        flt.run(imu, fixes, cfg, **kw)
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(repeats):
            sol = flt.run(imu, fixes, cfg, **kw)
        el, cpu = time.perf_counter() - t0, time.process_time() - c0
        c = sol.counters
        print(f"tight, pseudorange epochs at {10 // dec} Hz: {len(imu) * repeats / el:,.0f} IMU epochs/s "
              f"({len(imu) * repeats / cpu:,.0f} per CPU second; "
              f"{c['pseudoranges_used'] / max(1, c['pseudorange_epochs'] // dec):.1f} satellites per update epoch, "
              f"{c['pseudoranges_used']} scalar updates per run)")


def checks() -> None:
    s = sim.simulate(scenario.load("default"), 0)
    tr = evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)
    clean = sim.imu_table(s)
    dead = clean.copy()
    dead[(dead[:, 0] >= 100) & (dead[:, 0] < 110), 4:7] = 0.0
    for name, imu in (("default drive", clean), ("10 s zero dv", dead)):
        for check in nav_config.UPDATE_CHECKS:
            for reset in (5.0, 0.0):
                cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "update_check": check,
                                                    "gnss_reset_timeout_s": reset})
                sol = flt.run(imu, sim.fix_table(s), cfg, covariance=True)
                err = evaluate.nav_errors(sol, tr)
                e = evaluate.nees(err.e9, sol.covariance[:, :9, :9])
                h = np.hypot(err.r_ned[:, 0], err.r_ned[:, 1])
                c = sol.counters
                print(f"{name:14s} {check:20s} reset {reset:3.0f} s: final {np.linalg.norm(err.r_ned[-1]):9.2f} m, "
                      f"H RMS {np.sqrt(np.mean(h ** 2)):8.2f} m, fixes rejected {c['fixes_rejected']:3d}, "
                      f"attitude refused {c['updates_attitude_refused']:3d}, resets {c['gnss_resets']}, "
                      f"diverged {c['diverged']}, mean NEES {e.mean():.1f}")


def interval(seeds: int) -> None:
    sc = scenario.with_imu_rate(scenario.load("default"), 200)
    intervals = (0.0, 0.01, 0.02, 0.05)
    stats = {i: {"nees": [], "pos": [], "att": [], "diff": [], "s": 0.0} for i in intervals}
    for seed in range(seeds):
        s = sim.simulate(sc, seed)
        imu, fixes = sim.imu_table(s), sim.fix_table(s)
        tr = s.truth
        truth = evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)
        first = None
        for i in intervals:
            cfg = nav_config.load_config(None, dict(sim.imu_noise_truth(sc.imu), imu_rate_hz=200.0,
                                                    covariance_interval_s=i))
            t0 = time.perf_counter()
            # Output at 1 Hz: every output brings the covariance up to date, as an update does.
            sol = flt.run(imu, fixes, cfg, covariance=True, output_every=200)
            stats[i]["s"] += time.perf_counter() - t0
            err = evaluate.nav_errors(sol, truth)
            sel = sol.t >= sol.t[np.argmax(sol.heading_known)]
            st = stats[i]
            st["nees"].append(evaluate.nees(err.e9[sel], sol.covariance[sel][:, :9, :9]).mean())
            st["pos"].append(np.sqrt(np.mean(np.sum(err.e9[sel, 6:9] ** 2, axis=1))))
            st["att"].append(np.degrees(np.sqrt(np.mean(np.sum(err.e9[sel, 0:3] ** 2, axis=1)))))
            first = sol.r_ecef if first is None else first
            st["diff"].append(np.max(np.linalg.norm(sol.r_ecef - first, axis=1)))
    lo, hi = evaluate.nees_band(9, seeds)
    print(f"default drive at 200 Hz ({len(imu)} IMU epochs), {seeds} seeds, loose, noise as drawn; "
          f"NEES band of a {seeds}-run mean of means: about {lo:.2f}..{hi:.2f} per epoch")
    for i in intervals:
        st = stats[i]
        print(f"covariance_interval_s {i:4.2f}: mean NEES {np.mean(st['nees']):5.2f}, position RMS "
              f"{np.mean(st['pos']):.3f} m, attitude RMS {np.mean(st['att']):.4f} deg, largest position "
              f"difference to every increment {np.max(st['diff']) * 1e3:7.3f} mm, filter {st['s'] / seeds:.3f} s")


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "speed"
    arg = int(sys.argv[2]) if len(sys.argv) > 2 else None
    if what == "speed":
        speed(arg or 20)
    elif what == "nees":
        nees(arg or 20)
    elif what == "tight":
        tight(arg or 20)
    elif what == "checks":
        checks()
    elif what == "interval":
        interval(arg or 10)
    else:
        sys.exit(__doc__)
