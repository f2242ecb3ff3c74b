"""Fixed-interval smoother: speed, tape size and consistency.

    python benchmarks/bench_smoother.py speed [REPEATS]   # forward vs backward, epochs/s, bytes/epoch
    python benchmarks/bench_smoother.py nees [SEEDS]      # smoothed vs forward NEES over default drives

Speed: the default drive (18 k IMU epochs, output and covariance at every epoch),
loose (18 states with the preset's fix-error states) and tight (17 states, the preset's 10 Hz pseudoranges): the forward pass without
the smoother, the forward pass recording for it, and the backward pass, in IMU epochs/s
(thread CPU times measured in C++: the machine may be
shared, and wall time then counts the waits for a core); the tape's bytes per epoch; a run spilled to a
temporary file in 1 MiB chunks; the walk data set replayed with --smooth (18 states,
chunked forward run, smoothed blocks streamed to the results files; the time the results
writer takes is left out of the backward figure).

NEES: the 9 navigation states' NEES (from the first known heading on), forward and
smoothed, averaged over SEEDS runs epoch by epoch, against the two-sided 95 % band
of a SEEDS-run average of chi-square(9). The smoothed errors of neighbouring epochs
are more correlated than the forward ones, so the share of epochs inside the band is
the figure to read, with the time average.
"""

import sys
import time

import numpy as np

from gpsins import _core, evaluate, filter as flt, sim


def speed(repeats: int) -> None:
    from gpsins.sim import ephemeris as sim_eph

    s = sim.simulate(sim.load("default"), 0)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, s.scenario.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    offset = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    tight = dict(pseudoranges=sim.pseudorange_table(s), ephemerides=ephs,
                 klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta), gps_time_offset_s=offset)
    for mode, kw in (("loose", {}), ("tight", tight)):
        cfg = flt.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": mode})
        t0 = time.process_time()
        for _ in range(repeats):
            flt.run(imu, fixes, cfg, covariance=True, **kw)
        plain = (time.process_time() - t0) / repeats
        fwd = bwd = 0.0
        for _ in range(repeats):
            sol = flt.run(imu, fixes, cfg, covariance=True, smooth=True, **kw)
            info = sol.extra["smooth_info"]
            fwd += info["forward_cpu_s"] / repeats
            bwd += info["backward_cpu_s"] / repeats
        n = len(imu)
        print(f"{mode} ({sol.n_states} states), {n} IMU epochs: forward alone {n / plain:,.0f} epochs/s "
              f"(whole flt.run, CPU), forward recording {n / fwd:,.0f} epochs/s, backward {n / bwd:,.0f} epochs/s "
              f"(backward/forward time {bwd / fwd:.2f}); tape {info['tape_bytes'] / info['outputs']:,.0f} "
              f"bytes per output epoch, {info['tape_bytes'] / 2**20:.1f} MiB")
    cfg = flt.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    sol = flt.run(imu, fixes, cfg, covariance=True, smooth=True, smooth_chunk_mb=1.0)
    info = sol.extra["smooth_info"]
    print(f"loose, spilled in 1 MiB chunks: {info['chunks_spilled']} chunks, {info['spilled_bytes'] / 2**20:.1f} MiB "
          f"to the temporary file; forward {len(imu) / info['forward_cpu_s']:,.0f} epochs/s, "
          f"backward {len(imu) / info['backward_cpu_s']:,.0f} epochs/s (CPU)")
    import tempfile
    from pathlib import Path

    from gpsins import replay
    toml = Path(__file__).resolve().parent.parent / "tests" / "data" / "walk_0827" / "walk_0827_ubx.toml"
    fwd = bwd = 0.0
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as d:
            info = replay.replay(toml, Path(d) / "r", smooth=True).summary["smoothed"]["info"]
        fwd += info["forward_cpu_s"] / repeats
        bwd += info["backward_cpu_s"] / repeats
    n = info["outputs"]
    print(f"walk replay --smooth, {n} epochs: forward {n / fwd:,.0f} epochs/s, backward {n / bwd:,.0f} epochs/s "
          f"(backward/forward time {bwd / fwd:.2f}, CPU); tape {info['tape_bytes'] / n:,.0f} bytes per output epoch")


def nees(seeds: int) -> None:
    sc = sim.load("default")
    runs = {"forward": [], "smoothed": []}
    for seed in range(seeds):
        s = sim.simulate(sc, seed)
        cfg = flt.load_config(None, sim.imu_noise_truth(sc.imu))
        sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, smooth=True)
        tr = evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)
        t0 = sol.t[np.argmax(sol.heading_known)]
        line = f"seed {seed:2d}:"
        for name, x in (("forward", sol), ("smoothed", sol.extra["smoothed"])):
            err = evaluate.nav_errors(x, tr)
            sel = (x.t >= t0) & (x.t <= tr.t[-1])
            e = evaluate.nees(err.e9[sel], x.covariance[sel][:, :9, :9])
            inside = (np.abs(err.e9[sel]) <= 3 * x.sigma[sel, :9]).mean()
            h = np.hypot(err.r_ned[sel, 0], err.r_ned[sel, 1])
            runs[name].append(e)
            line += (f"  {name} NEES {e.mean():5.2f}, inside 3 sigma {100 * inside:5.1f} %, "
                     f"H RMS {np.sqrt(np.mean(h ** 2)):.2f} m")
        print(line, flush=True)
    lo, hi = evaluate.nees_band(9, seeds)
    for name, r in runs.items():
        n = min(len(x) for x in r)
        avg = np.mean([x[:n] for x in r], axis=0)
        print(f"{name}: {seeds} seeds, time-averaged NEES {avg.mean():.2f} (expected 9; 95 % band of a "
              f"{seeds}-run average {lo:.2f}..{hi:.2f}); epochs with the run-average inside the band "
              f"{100 * np.mean((avg >= lo) & (avg <= hi)):.1f} %, below {100 * np.mean(avg < lo):.1f} %, "
              f"above {100 * np.mean(avg > hi):.1f} %")


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "speed"
    arg = int(sys.argv[2]) if len(sys.argv) > 2 else None
    if what == "speed":
        speed(arg or 3)
    elif what == "nees":
        nees(arg or 20)
    else:
        sys.exit(__doc__)
