"""Fixed-interval smoother: speed, tape size and consistency.

    python benchmarks/bench_smoother.py speed [REPEATS]   # forward vs backward, epochs/s, bytes/epoch
    python benchmarks/bench_smoother.py nees [SEEDS]      # smoothed vs forward NEES over default drives
    python benchmarks/bench_smoother.py nees [SEEDS] matched   # the same with the filter's models made true
    python benchmarks/bench_smoother.py nees [SEEDS] imu|fixes # only the IMU's, or only the fixes' model
    python benchmarks/bench_smoother.py segments [SEEDS] [matched|imu|fixes]  # per segment, forward vs smoothed

Speed: the default drive (18 k IMU epochs, output and covariance at every epoch), loose
(18 states with the preset's fix-error states) and tight (29 states with the
signal-in-space slots, the preset's 10 Hz pseudoranges): the forward pass without the
smoother, the forward pass recording for it, and the backward pass, in IMU epochs/s
(thread CPU times measured in C++: the machine may be shared, and wall time then counts
the waits for a core); the tape's bytes per epoch; a run spilled to a temporary file in
1 MiB chunks; the walk data set replayed with --smooth (18 states, chunked forward run,
smoothed blocks streamed to the results files; the time the results writer takes is left
out of the backward figure).

NEES: the 9 navigation states' NEES (from the first known heading on), forward and
smoothed, averaged over SEEDS runs epoch by epoch, against the two-sided 95 % band
of a SEEDS-run average of chi-square(9). The smoothed errors of neighbouring epochs
are more correlated than the forward ones, so the share of epochs inside the band is
the figure to read, with the time average. Also the NEES of the attitude, velocity and
position blocks (3 each, expected 3) averaged over the seeds.

`matched`: the control experiment. A smoother is only as consistent as the models it is
given: the simulated unit has terms the filter does not model (misalignment, quantisation,
bias instability as a sum of Gauss-Markov processes where the filter has a random walk),
and the simulated receiver's fixes come from its own pseudorange errors, which the
filter's white + Gauss-Markov fix-error model only approximates. Here those IMU terms are
switched off and each 3D or 2D fix is replaced by the true antenna position plus an error
drawn from the filter's own fix model (white UERE x DOP and a DOP-scaled first-order
Gauss-Markov error with the configured sigmas and tau), so that the forward filter's models
are the truth; what stays over-confident then is the smoother's doing.

Segments: per segment of the default drive (heading known), the RMS horizontal and vertical
position error, forward and smoothed, for each seed and its mean square over the seeds: how often
the smoothed error is the larger one in a single drive, and whether it is in expectation.

Measured (segments, 20 seeds): the seed-RMS is smaller smoothed in 24 of 24 segments horizontally and
22 vertically (D-E 2.41 vs 1.99 m, S-T 1.68 vs 1.62 m); with fixes drawn from the filter's own model
(`fixes`) 24 and 24, and 24 and 24 `matched`. In single drives the smoothed error is the larger one
in 13.5 % of the segments horizontally and 33 % vertically; 6.9 % and 17 % with `fixes`, 5.2 % and
19 % `matched`: even a smoother whose models are true does not beat the forward pass in every
segment of every drive, only in expectation.

Measured (nees, 20 seeds, band 7.24..10.95): 9-state NEES, the attitude / velocity / position
blocks (3 expected), the position's north / east / down (error / sigma)^2 (1 expected):
                                    forward                          smoothed
  simulated unit and receiver        9.20  2.92 2.03 3.34  1.58 0.74 1.02   10.77  2.46 2.49 5.58  2.42 1.19 1.98
  unit's unmodelled terms off        9.67  3.25 2.01 3.37  1.62 0.75 1.01   11.06  2.56 2.55 5.68  2.47 1.21 2.00
  fixes from the filter's model      7.39  2.46 2.36 2.59  0.83 0.75 1.01    7.28  2.39 2.40 2.52  0.84 0.83 0.85
  both (matched)                     7.79  2.69 2.35 2.57  0.80 0.77 1.00    8.04  3.02 2.49 2.50  0.82 0.81 0.87
(The drawn fixes leave out the preset's slow part, fix_error_fast_sigma_m, which the filter still
adds to R: under-confident there, NEES below 9. With the simulated receiver the smoothed time average
is inside the band, 66.5 % of its epochs, the forward one 88.6 %.)
The smoother is consistent whenever the forward pass's fix model is true, whatever the IMU:
its error-state bookkeeping (resets, the first heading's transition, standstill updates,
the fix-error states; the backward pass needs no Q, the forward covariances carry it) is
not what makes the default drive over-confident. The simulated receiver's fixes are, above
all in north: already 1.6 x over-confident forward, and smoothing, which weighs fixes from
both sides, exposes it more (2.4 x). Not the cause: north being the weaker axis (NDOP / EDOP
has median 1.37, upper quartile 2.2 on the drive's 3D fixes, while the filter splits one
HDOP evenly): errors drawn from the filter's model but scaled by each fix's NDOP and EDOP
leave north consistent (forward 1.02, smoothed 1.06; 16 seeds, unmodelled IMU terms off).
A lead (measured with the fix-error model before the signal-in-space refit, tau 20 s): the
receiver's north error stays correlated longer than the model's 20 s (per unit
of DOP squared, lag 60 s 0.29 against the model's 0.10, 90 s 0.14 against 0.02; 20 seeds),
and slow errors hurt the smoother most: a constant error of 0.5 / 0.4 / 0.7 m (north, east,
down, 1 sigma per drive) added to fixes from the model takes the position block from about 2.9 to
3.07 forward but 3.72 smoothed (16 seeds).
Tried and not kept: restarting the fix-error states where the DOPs step (a new satellite
set; detected without a miss or false alarm on the simulated receiver): forward 10.48
(attitude 3.12), smoothed 12.67 (position 5.90): the receiver's correlated error seems to carry
over a change of satellites in part, which a restart has the smoother average as if not.
"""

import sys
import time

import numpy as np

from gpsins import _core, evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario


def speed(repeats: int) -> None:
    from gpsins.sim import ephemeris as sim_eph

    s = sim.simulate(scenario.load("default"), 0)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, s.scenario.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    offset = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    tight = dict(pseudoranges=sim.pseudorange_table(s), ephemerides=ephs,
                 klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta), gps_time_offset_s=offset)
    for mode, kw in (("loose", {}), ("tight", tight)):
        cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": mode})
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
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    sol = flt.run(imu, fixes, cfg, covariance=True, smooth=True, smooth_chunk_mb=1.0)
    info = sol.extra["smooth_info"]
    print(f"loose, spilled in 1 MiB chunks: {info['chunks_spilled']} chunks, {info['spilled_bytes'] / 2**20:.1f} MiB "
          f"to the temporary file; forward {len(imu) / info['forward_cpu_s']:,.0f} epochs/s, "
          f"backward {len(imu) / info['backward_cpu_s']:,.0f} epochs/s (CPU)")
    import tempfile
    from pathlib import Path

    from gpsins.replay import run
    toml = Path(__file__).resolve().parent.parent / "tests" / "data" / "walk_0827" / "walk_0827_ubx.toml"
    fwd = bwd = 0.0
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as d:
            info = run.replay(toml, Path(d) / "r", smooth=True).summary["smoothed"]["info"]
        fwd += info["forward_cpu_s"] / repeats
        bwd += info["backward_cpu_s"] / repeats
    n = info["outputs"]
    print(f"walk replay --smooth, {n} epochs: forward {n / fwd:,.0f} epochs/s, backward {n / bwd:,.0f} epochs/s "
          f"(backward/forward time {bwd / fwd:.2f}, CPU); tape {info['tape_bytes'] / n:,.0f} bytes per output epoch")


UNMODELLED_IMU_TERMS = ("misalignment", "quantisation", "bias_instability")


def fixes_from_the_filter_model(s, cfg: dict, rng: np.random.Generator) -> np.ndarray:
    """The receiver's fix table with each solution's position replaced by the true antenna
    position plus white UERE x DOP noise and a DOP-scaled Gauss-Markov error, as the filter
    models them (fix_uere_m, fix_uere_2d_m for 2D fixes, fix_error_gm_sigma_m per north, east,
    down, fix_error_gm_tau_s); 2D fixes keep their mode (the filter uses their horizontal part)."""
    from gpsins.sim import earth

    fx = sim.fix_table(s).copy()
    gm_sigma = np.broadcast_to(np.asarray(cfg["fix_error_gm_sigma_m"], float), 3)
    tau = float(cfg["fix_error_gm_tau_s"])
    b, t_prev = np.zeros(3), None
    for row in fx:
        if row[9] not in (2, 3):
            continue
        t, hdop, vdop = row[0], row[7], row[8]
        a = 0.0 if t_prev is None else np.exp(-(t - t_prev) / tau)
        b = a * b + np.sqrt(1.0 - a * a) * gm_sigma * rng.normal(size=3)
        t_prev = t
        uere = cfg["fix_uere_2d_m"] if row[9] == 3 else cfg["fix_uere_m"]
        dop = np.array([hdop / np.sqrt(2), hdop / np.sqrt(2), vdop])
        white = uere * dop * rng.normal(size=3)
        gm = b * (np.array([dop[0], dop[1], 1.0 if row[9] == 3 else vdop]) if cfg["fix_error_gm_dop_scaled"] else 1.0)
        r = s.truth.position_at(np.array([t]))[0]
        lat, lon, _ = earth.ecef_to_geodetic(r)
        row[1:4] = r + earth.ecef_to_ned_matrix(lat, lon) @ (white + gm)
    return fx


def smoothed_runs(seeds: int, matched_imu: bool, matched_fixes: bool, covariance: bool):
    """(seed, simulation, forward solution with its smoothed one, truth) of the default drive per seed,
    the unit's unmodelled terms off with matched_imu, the fixes from the filter's model with matched_fixes."""
    sc = scenario.load("default")
    if matched_imu:
        for term in UNMODELLED_IMU_TERMS:
            sc.imu.terms[term] = False
    for seed in range(seeds):
        s = sim.simulate(sc, seed)
        cfg = nav_config.load_config(None, sim.imu_noise_truth(sc.imu))
        fixes = fixes_from_the_filter_model(s, cfg, np.random.default_rng([seed, 18])) if matched_fixes \
            else sim.fix_table(s)
        sol = flt.run(sim.imu_table(s), fixes, cfg, covariance=covariance, smooth=True)
        yield seed, s, sol, evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)


def experiment(matched_imu: bool, matched_fixes: bool) -> str:
    return (("the unit's unmodelled terms off" if matched_imu else "the simulated unit") + ", "
            + ("fixes drawn from the filter's model" if matched_fixes else "the simulated receiver's fixes"))


def nees(seeds: int, matched_imu: bool = False, matched_fixes: bool = False) -> None:
    runs = {"forward": [], "smoothed": []}
    blocks = {"forward": [], "smoothed": []}
    for seed, _, sol, tr in smoothed_runs(seeds, matched_imu, matched_fixes, covariance=True):
        t0 = sol.t[np.argmax(sol.heading_known)]
        line = f"seed {seed:2d}:"
        for name, x in (("forward", sol), ("smoothed", sol.extra["smoothed"])):
            err = evaluate.nav_errors(x, tr)
            sel = (x.t >= t0) & (x.t <= tr.t[-1])
            e = evaluate.nees(err.e9[sel], x.covariance[sel][:, :9, :9])
            ned = (err.r_ned[sel] / evaluate.ned_sigma(x)[sel]) ** 2
            blocks[name].append([evaluate.nees(err.e9[sel, i:i + 3], x.covariance[sel][:, i:i + 3, i:i + 3]).mean()
                                 for i in (0, 3, 6)] + list(ned.mean(axis=0)))
            inside = (np.abs(err.e9[sel]) <= 3 * x.sigma[sel, :9]).mean()
            h = np.hypot(err.r_ned[sel, 0], err.r_ned[sel, 1])
            runs[name].append(e)
            line += (f"  {name} NEES {e.mean():5.2f}, inside 3 sigma {100 * inside:5.1f} %, "
                     f"H RMS {np.sqrt(np.mean(h ** 2)):.2f} m")
        print(line, flush=True)
    lo, hi = evaluate.nees_band(9, seeds)
    print(experiment(matched_imu, matched_fixes))
    for name, r in runs.items():
        n = min(len(x) for x in r)
        avg = np.mean([x[:n] for x in r], axis=0)
        print(f"{name}: {seeds} seeds, time-averaged NEES {avg.mean():.2f} (expected 9; 95 % band of a "
              f"{seeds}-run average {lo:.2f}..{hi:.2f}); epochs with the run-average inside the band "
              f"{100 * np.mean((avg >= lo) & (avg <= hi)):.1f} %, below {100 * np.mean(avg < lo):.1f} %, "
              f"above {100 * np.mean(avg > hi):.1f} %")
        b = np.mean(blocks[name], axis=0)
        print(f"  attitude / velocity / position blocks {b[0]:.2f} / {b[1]:.2f} / {b[2]:.2f} (3 expected each); "
              f"position north / east / down (error / sigma)^2 {b[3]:.2f} / {b[4]:.2f} / {b[5]:.2f} (1 expected)")


def segments(seeds: int, matched_imu: bool = False, matched_fixes: bool = False) -> None:
    sums, worse_h, worse_v, labels = None, None, None, None
    for seed, s, sol, tr in smoothed_runs(seeds, matched_imu, matched_fixes, covariance=False):
        rows = {}
        for _name, x in (("forward", sol), ("smoothed", sol.extra["smoothed"])):
            known = x.heading_known & (x.t >= tr.t[0]) & (x.t <= tr.t[-1])
            e = evaluate.nav_errors(x, tr).r_ned
            for label, a, b in s.scenario.segment_times():
                m = known & (x.t >= tr.t[0] + a) & (x.t < tr.t[0] + b)
                if m.sum() >= 10:
                    rows.setdefault(label, []).extend([np.mean(e[m, 0] ** 2 + e[m, 1] ** 2), np.mean(e[m, 2] ** 2)])
        if labels is None:
            labels = list(rows)
            sums = np.zeros((len(labels), 4))
            worse_h, worse_v = np.zeros(len(labels), int), np.zeros(len(labels), int)
        ms = np.array([rows[k] for k in labels])  # forward h, v, smoothed h, v (mean squares)
        sums += ms
        worse_h += ms[:, 2] > ms[:, 0]
        worse_v += ms[:, 3] > ms[:, 1]
        print(f"seed {seed:2d}: smoothed worse than forward in {int((ms[:, 2] > ms[:, 0]).sum())} of {len(labels)} "
              f"segments horizontally, {int((ms[:, 3] > ms[:, 1]).sum())} vertically", flush=True)
    print(experiment(matched_imu, matched_fixes)
          + f", {seeds} seeds; RMS over the seeds (m), forward / smoothed, and in how many seeds smoothed was worse:")
    rms = np.sqrt(sums / seeds)
    for k, label in enumerate(labels):
        print(f"  {label:>6}: horizontal {rms[k, 0]:5.2f} / {rms[k, 2]:5.2f} ({worse_h[k]:2d}), "
              f"vertical {rms[k, 1]:5.2f} / {rms[k, 3]:5.2f} ({worse_v[k]:2d})")
    print(f"segments whose seed-RMS is worse smoothed: horizontal {int((rms[:, 2] > rms[:, 0]).sum())}, vertical "
          f"{int((rms[:, 3] > rms[:, 1]).sum())} of {len(labels)}; single drives: horizontal "
          f"{100 * worse_h.sum() / (seeds * len(labels)):.1f} %, "
          f"vertical {100 * worse_v.sum() / (seeds * len(labels)):.1f} %")


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "speed"
    arg = int(sys.argv[2]) if len(sys.argv) > 2 else None
    if what == "speed":
        speed(arg or 3)
    elif what == "nees":
        rest = sys.argv[3:]
        nees(arg or 20, matched_imu=bool({"matched", "imu"} & set(rest)),
             matched_fixes=bool({"matched", "fixes"} & set(rest)))
    elif what == "segments":
        rest = sys.argv[3:]
        segments(arg or 20, matched_imu=bool({"matched", "imu"} & set(rest)),
                 matched_fixes=bool({"matched", "fixes"} & set(rest)))
    else:
        sys.exit(__doc__)
