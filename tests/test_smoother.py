"""The fixed-interval smoother (C++ rts.hpp): its backward pass against an independent
textbook RTS, its error-state bookkeeping, and smoothed against forward on simulated truth."""

import numpy as np
import pytest

from gpsins import _core, evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario
from gpsins.replay import results as results_mod

# Bytes the smoother's tape holds, from the layout rts.hpp and the README document (not from the code's
# own counters): every record is its payload of doubles plus one trailer double (its kind and length).
F8 = np.dtype(np.float64).itemsize
N_LOOSE = 18  # the preset's loose filter: 15 navigation and IMU error states, 3 of the fixes' correlated error
# Output payload: t, r (3), v (3), q (4), gyro and accel bias (3 + 3), fix error (3), flags, then P's upper triangle.
NOMINAL_LOOSE = 1 + 3 + 3 + 4 + 3 + 3 + 3 + 1
OUTPUT_BYTES_LOOSE = F8 * (NOMINAL_LOOSE + N_LOOSE * (N_LOOSE + 1) // 2 + 1)
# A transition record: one mask per column of the N x N matrix, its non-zeros, the trailer. A step's Phi =
# I + F dt + F^2 dt^2/2 + F^3 dt^3/6 with F's non-zero 3 x 3 blocks (rts.hpp, eskf.hpp; states attitude 0,
# velocity 1, position 2, gyro bias 3, accelerometer bias 4): F_00 F_03 F_10 F_11 F_12 F_14 F_21 and the
# bias blocks' diagonals. Its powers fill the attitude row at blocks 0 and 3 (9 + 9), the velocity and
# position rows at blocks 0-4 (2 x 45), the bias rows on their diagonals (6), then the fix error's 3:
# 117 non-zeros (any product of such steps has the same pattern).
PHI_NONZEROS_LOOSE = 9 + 9 + 2 * 45 + 6 + 3
PROPAGATION_BYTES_LOOSE = F8 * (N_LOOSE + PHI_NONZEROS_LOOSE + 1)
# Turning the attitude error across the vertical while the heading is unknown: I with a dense attitude block.
DECOUPLING_BYTES_LOOSE = F8 * (N_LOOSE + N_LOOSE + 6 + 1)


def update_bytes(m: int, n: int) -> int:
    """An accepted update of dimension m: m, H (m x n), K (n x m), S^-1 (m x m), the innovation (m), g (3 x 3)."""
    return F8 * (1 + 2 * m * n + m * m + m + 9 + 1)


# ------------------------------------------------------------ an independent smoother

def run_linear(ops, x0, p0, chunk_bytes):
    f = _core.LinearRts(x0, p0, chunk_bytes)
    for op in ops:
        if op[0] == "predict":
            f.predict(op[1], op[2])
        elif op[0] == "transition":
            f.transition(op[1], op[2])
        elif op[0] == "update":
            f.update(op[1], op[2], op[3])
        else:
            f.output()
    xs, ps = f.smooth()
    return xs, ps, f.spilled_bytes


def linear_problem(seed):
    """2-D constant velocity, position fixes every other step, a restart of the position
    states in the middle (new error independent of the old one), one speed-only update."""
    rng = np.random.default_rng(seed)
    dt = 0.2
    phi = np.eye(4)
    phi[0, 2] = phi[1, 3] = dt
    q = np.diag([1e-3, 2e-3, 5e-2, 4e-2])
    h = np.eye(4)[:2]
    r = np.diag([0.5, 0.3])
    truth = np.array([0.0, 0.0, 2.0, -1.0])
    ops = []
    for k in range(400):
        truth = phi @ truth + rng.normal(size=4) * np.sqrt(np.diag(q))
        ops.append(("predict", phi, q))
        if k == 200:
            a = np.diag([0.0, 0.0, 1.0, 1.0])
            ops.append(("transition", a, np.diag([25.0, 25.0, 0.0, 0.0])))
        if k % 2 == 0 and not 120 <= k < 180:
            ops.append(("update", h, r, h @ truth + rng.normal(size=2) * np.sqrt(np.diag(r))))
        if k == 300:
            hv = np.array([[0.0, 0.0, 1.0, 0.0]])
            ops.append(("update", hv, np.array([[0.01]]), hv @ truth + 0.1 * rng.normal(size=1)))
        ops.append(("output",))
    return ops, np.zeros(4), np.diag([4.0, 4.0, 9.0, 9.0])


@pytest.mark.parametrize("chunk_bytes", [64 << 20, 4096])
def test_backward_pass_equals_a_textbook_rts_smoother(chunk_bytes):
    ops, x0, p0 = linear_problem(3)
    # Textbook: the prior at each output is the one just before its updates.
    x, p = x0.copy(), p0.copy()
    xf, pf, xpr, ppr, phis = [], [], [], [], []
    phi_acc, have_prior = np.eye(4), False
    for op in ops:
        if op[0] in ("predict", "transition"):
            x, p = op[1] @ x, op[1] @ p @ op[1].T + op[2]
            phi_acc = op[1] @ phi_acc
        elif op[0] == "update":
            if not have_prior:
                xpr.append(x.copy())
                ppr.append(p.copy())
                have_prior = True
            _, h, r, z = op
            k = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
            ikh = np.eye(4) - k @ h
            x, p = x + k @ (z - h @ x), ikh @ p @ ikh.T + k @ r @ k.T
        else:
            if not have_prior:
                xpr.append(x.copy())
                ppr.append(p.copy())
            have_prior = False
            phis.append(phi_acc)
            phi_acc = np.eye(4)
            xf.append(x.copy())
            pf.append(p.copy())
    n = len(xf)
    xs, ps = [None] * n, [None] * n
    xs[-1], ps[-1] = xf[-1], pf[-1]
    for k in range(n - 2, -1, -1):
        c = pf[k] @ phis[k + 1].T @ np.linalg.inv(ppr[k + 1])
        xs[k] = xf[k] + c @ (xs[k + 1] - xpr[k + 1])
        ps[k] = pf[k] + c @ (ps[k + 1] - ppr[k + 1]) @ c.T
    bx, bp, spilled = run_linear(ops, x0, p0, chunk_bytes)
    assert (spilled > 0) == (chunk_bytes == 4096)
    np.testing.assert_allclose(bx, np.array(xs), rtol=0, atol=1e-9)
    np.testing.assert_allclose(bp, np.array(ps), rtol=0, atol=1e-9)
    # Not trivially equal to the forward pass: smoothing changed the states by far more than rounding.
    assert np.abs(np.array(xs) - np.array(xf)).max() > 0.1
    # Across the restart (step 200) the position is a break, the velocity carries.
    assert np.all(np.diagonal(bp, axis1=1, axis2=2) <= np.diagonal(np.array(pf), axis1=1, axis2=2) + 1e-12)


# ------------------------------------------------------------ the navigation filter

def truth_of(s):
    return evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)


def run(s, fixes=None, **over):
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **over})
    return flt.run(sim.imu_table(s), sim.fix_table(s) if fixes is None else fixes, cfg, covariance=True, smooth=True)


def errors(sol, tr):
    inside = (sol.t >= tr.t[0]) & (sol.t <= tr.t[-1]) & sol.heading_known
    e = evaluate.nav_errors(_subset(sol, inside), tr)
    return sol.t[inside], e, sol.sigma[inside]


def _subset(sol, m):
    return flt.Solution(sol.mode, sol.n_states, sol.t[m], sol.r_ecef[m], sol.v_ecef[m], sol.q_eb[m], sol.gyro_bias[m],
                        sol.accel_bias[m], sol.sigma[m], sol.standstill[m], sol.heading_known[m], sol.updates,
                        sol.counters, covariance=None if sol.covariance is None else sol.covariance[m])


@pytest.fixture(scope="module")
def default_drive():
    s = sim.simulate(scenario.load("default"), seed=0)
    return s, run(s)


def _segment_rms(s, fwd):
    """Per truth segment (heading known): RMS horizontal and vertical position error, forward and smoothed."""
    tr = truth_of(s)
    t, ef, _ = errors(fwd, tr)
    _, es, _ = errors(fwd.extra["smoothed"], tr)
    rms = lambda x: float(np.sqrt(np.mean(x ** 2)))  # noqa: E731
    rows = {}
    for label, a, b in s.scenario.segment_times():
        m = (t >= tr.t[0] + a) & (t < tr.t[0] + b)
        if m.sum() >= 10:
            rows[label] = (rms(np.hypot(ef.r_ned[m, 0], ef.r_ned[m, 1])), rms(np.hypot(es.r_ned[m, 0], es.r_ned[m, 1])),
                           rms(ef.r_ned[m, 2]), rms(es.r_ned[m, 2]))
    return rows


def test_smoothed_beats_forward_overall_and_stays_inside_its_3_sigma(default_drive):
    s, fwd = default_drive
    sm = fwd.extra["smoothed"]
    tr = truth_of(s)
    _, ef, sf = errors(fwd, tr)
    _, es, ss = errors(sm, tr)
    hf, hs = np.hypot(ef.r_ned[:, 0], ef.r_ned[:, 1]), np.hypot(es.r_ned[:, 0], es.r_ned[:, 1])
    rms = lambda x: float(np.sqrt(np.mean(x ** 2)))  # noqa: E731
    assert rms(hs) < 0.5 * rms(hf) and rms(es.r_ned[:, 2]) < rms(ef.r_ned[:, 2])
    assert rms(np.linalg.norm(es.e9[:, 3:6], axis=1)) < 0.5 * rms(np.linalg.norm(ef.e9[:, 3:6], axis=1))
    # Smoothed covariance never exceeds the forward one (rounding aside) once the heading is known...
    assert np.all(ss <= sf * (1 + 1e-6) + 1e-12)
    # ...and it is honest: the smoothed errors lie inside 3 sigma nearly everywhere.
    assert np.mean(np.abs(es.e9) <= 3 * ss[:, :9]) > 0.98
    # Horizontal error better in most segments (seeds 0-3: 20, 19, 22, 21 of 24; white fixes 23, 21, 20, 21).
    rows = _segment_rms(s, fwd)
    assert sum(r[1] <= r[0] for r in rows.values()) >= 0.75 * len(rows)


@pytest.mark.xfail(strict=True, reason="issue 18's every-segment criterion holds in expectation, not in every drive: "
                   "seed 0 has the smoothed error the larger one in 3 of 24 segments horizontally and 10 vertically. "
                   "Over 20 seeds (bench_smoother.py segments 20) the seed-RMS is smaller smoothed in 24 of 24 "
                   "segments horizontally and 22 vertically (D-E 2.41 vs 1.99 m, S-T 1.68 vs 1.62 m); with fixes "
                   "drawn from the filter's own model in 24 and 24, yet even then 7 % (horizontal) and 17 % "
                   "(vertical) of the single drives' segments are worse smoothed: no smoother meets it per drive")
def test_smoothed_beats_forward_in_every_segment(default_drive):
    s, fwd = default_drive
    bad = {k: r for k, r in _segment_rms(s, fwd).items() if r[1] > r[0] or r[3] > r[2]}
    assert not bad, bad


def test_smoothed_sigma_inside_forward_before_the_heading_is_known(default_drive):
    """Before the first heading the attitude error about the vertical is unknown (sigma pi) in both passes. The
    smoothed state's injection and reset leave it alone: turned through the smoothed tilt correction, pi^2 leaked
    into the tilt and made its smoothed sigma up to 1.4x the forward's."""
    _, fwd = default_drive
    assert np.all(fwd.extra["smoothed"].sigma <= fwd.sigma * (1 + 1e-6) + 1e-12)


def test_first_heading_keeps_the_tilt_and_its_accelerometer_bias_correlation(default_drive):
    """The first heading (from the course) restarts velocity, position and yaw; the tilt
    learnt while levelling carries over with its correlation to the accelerometer biases, as
    the transition the smoother is told says (a restart there would cut the smoothed tilt off
    from the standstill before it)."""
    _, fwd = default_drive
    k = int(np.argmax(fwd.heading_known))

    def tilt_bias_corr(p):
        sd = np.sqrt(np.diag(p))
        return np.abs(p[0:3, 12:15] / np.outer(sd[0:3], sd[12:15])).max()

    before, after = tilt_bias_corr(fwd.covariance[k - 1]), tilt_bias_corr(fwd.covariance[k])
    assert before > 0.2  # levelling did couple them
    assert after > 0.5 * before


def test_tape_size_per_epoch_as_documented(default_drive):
    """The tape's bytes counted record by record from the documented layout and recording rule, against the
    size the core reports. Propagation is multiplied into one Phi until another record comes, so one per
    output epoch (output at every IMU sample), one more for each update time between two samples (the
    interval is split there); while the heading is unknown a yaw-decoupling transition at each sample and
    at each update; and the two re-initialisations (start-up, the first heading), whose non-zeros are
    only bounded here (none to all N^2)."""
    s, fwd = default_drive
    info = fwd.extra["smooth_info"]
    n = info["outputs"]
    assert n == len(fwd.t) and info["spilled_bytes"] == 0
    upd = fwd.updates
    acc = upd["accepted"]
    assert acc.all()  # a rejected update leaves no record but may still split an interval: keep the count exact
    t_imu = sim.imu_table(s)[:, 0]
    t_known = fwd.t[np.argmax(fwd.heading_known)]
    splits = len(np.unique(upd["t"][~np.isin(upd["t"], t_imu)]))
    decouplings = int((~fwd.heading_known).sum()) + int((upd["t"] <= t_known).sum())
    want = (n * OUTPUT_BYTES_LOOSE + (n + splits) * PROPAGATION_BYTES_LOOSE + decouplings * DECOUPLING_BYTES_LOOSE
            + sum(update_bytes(int(m), N_LOOSE) for m in upd["dof"]))
    reinit_least, reinit_most = 2 * F8 * (N_LOOSE + 1), 2 * F8 * (N_LOOSE + N_LOOSE ** 2 + 1)
    print(f"\ntape {info['tape_bytes']} bytes ({info['tape_bytes'] / n:.0f} per epoch), counted {want} + 2 "
          f"re-initialisations: {n} outputs, {splits} split intervals, {decouplings} decouplings, {len(acc)} updates")
    assert want + reinit_least <= info["tape_bytes"] <= want + reinit_most
    # The figures docs/replay.md gives for this filter: 1544 + 1088 = 2632 bytes per epoch, 1048 per 3-D fix.
    assert (OUTPUT_BYTES_LOOSE, PROPAGATION_BYTES_LOOSE, update_bytes(3, N_LOOSE)) == (1544, 1088, 1048)


def test_spilled_tape_gives_the_same_smoothed_run():
    s = sim.simulate(scenario.load("default"), seed=1)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    imu, fixes = sim.imu_table(s)[:6000], sim.fix_table(s)
    a = flt.run(imu, fixes, cfg, covariance=True, smooth=True)
    b = flt.run(imu, fixes, cfg, covariance=True, smooth=True, smooth_chunk_mb=0.25)
    assert b.extra["smooth_info"]["chunks_spilled"] > 3 and a.extra["smooth_info"]["spilled_bytes"] == 0
    np.testing.assert_array_equal(a.extra["smoothed"].r_ecef, b.extra["smoothed"].r_ecef)
    np.testing.assert_array_equal(a.extra["smoothed"].covariance, b.extra["smoothed"].covariance)


@pytest.mark.parametrize("start_s", [60.0, 150.0, pytest.param(40.0, marks=pytest.mark.xfail(
    strict=True, reason="6 s after the first heading: smoothed drift 1.79 m vs forward 6.15 m (1/3.4); with every fix "
    "the smoothed error there is already 1.38 m, more than a fifth of the forward drift (1.23 m): the receiver's "
    "correlated errors, not the outage, set that floor (at 60 s 0.86 m, at 150 s 2.11 m, both met)"))])
def test_15_s_outage_smoothed_drift_at_most_a_fifth_of_forward(start_s):
    # Without the satellites' orbit and clock errors: their slow bias in the fixes (the smoothed error
    # with every fix is 2.2 m there with it, 0.9 m without) is no drift, and would hide a fifth of it.
    sc = scenario.load("default")
    sc.gnss.sis_error_m = 0.0
    s = sim.simulate(sc, seed=0)
    tr = truth_of(s)
    fixes = sim.fix_table(s)
    t0 = tr.t[0] + start_s
    out = (fixes[:, 0] >= t0) & (fixes[:, 0] < t0 + 15.0)
    fwd = run(s, fixes[~out])
    sm = fwd.extra["smoothed"]
    drift = []
    for sol in (fwd, sm):
        m = (sol.t >= t0) & (sol.t < t0 + 15.0)
        e = evaluate.nav_errors(_subset(sol, m), tr)
        drift.append(np.hypot(e.r_ned[:, 0], e.r_ned[:, 1]).max())
    assert drift[0] > 0.5  # the outage does hurt the forward pass
    assert drift[1] <= drift[0] / 5, drift


def test_large_injected_corrections_are_smoothed_in_the_same_error_definition():
    """Start with the heading 20 degrees off (told as known, 25 degrees sigma): the forward pass
    injects large attitude corrections. The smoothed attitude at the start is then right to the
    accuracy the rest of the run allows (the smoothed yaw of the same run started at the true
    heading), inside its own 3 sigma."""
    s = sim.simulate(scenario.load("default"), seed=2)
    tr = truth_of(s)
    euler = _core.euler_from_body_to_ecef(tr.q_eb[:1], _core.ecef_to_geodetic(tr.r_ecef[:1]))
    true_yaw = float(np.degrees(euler[0, 0]))
    fwd = run(s, initial_yaw_deg=true_yaw + 20.0, attitude_sigma_deg=[1.0, 1.0, 25.0])
    sm = fwd.extra["smoothed"]
    m = fwd.t < fwd.t[0] + 20.0
    ef = evaluate.nav_errors(_subset(fwd, m), tr)
    es = evaluate.nav_errors(_subset(sm, m), tr)
    yaw_f = np.abs(ef.ypr_deg[:, 0])
    assert yaw_f[0] > 15.0  # the forward pass starts far off
    yaw_s = np.abs(es.ypr_deg[:, 0])
    # Standing, the yaw is seen only once the car moves: the smoothed start is as good as the gyros carry
    # it back from the drive (seed 2: about 2 deg, sigma 1.3-1.5 deg), and as good as a run started at the
    # true heading: 95 % of the 20 degrees is taken out.
    assert yaw_s.max() < 3.0 and np.all(np.radians(yaw_s) <= 3 * sm.sigma[m, 2])
    known = run(s, initial_yaw_deg=true_yaw, attitude_sigma_deg=[1.0, 1.0, 25.0]).extra["smoothed"]
    es0 = evaluate.nav_errors(_subset(known, m), tr)
    assert np.abs(es.ypr_deg[:, 0] - es0.ypr_deg[:, 0]).max() < 1.0
    # within 3 sigma of the smoothed covariance (attitude errors, rad)
    assert np.mean(np.abs(es.e9[:, :3]) <= 3 * sm.sigma[m, :3]) > 0.95
    h_f = np.hypot(ef.r_ned[:, 0], ef.r_ned[:, 1])
    h_s = np.hypot(es.r_ned[:, 0], es.r_ned[:, 1])
    assert np.sqrt(np.mean(h_s ** 2)) < np.sqrt(np.mean(h_f ** 2))


def test_replay_smooth_writes_smoothed_results_next_to_the_forward_ones(tmp_path):
    from pathlib import Path

    from gpsins.replay import run as replay
    toml = Path(__file__).parent / "data" / "walk_0827" / "walk_0827_ubx.toml"
    res = replay.replay(toml, tmp_path / "r", outages="25:15:45:45", smooth=True)
    z = results_mod.load(tmp_path / "r")
    assert (tmp_path / "r" / "smoothed.pos").exists()
    for k in ("r_ecef", "sigma", "sigma_ned_m", "drift_h_m", "ref_err_ned_m"):
        assert z["smooth_" + k].shape[0] == (z["t"].shape[0] if k in ("r_ecef", "sigma", "sigma_ned_m")
                                             else z[k].shape[0])
    fwd, sm = res.summary["scoring"], res.summary["smoothed"]["scoring"]
    # Both outages are bridged far better than by the forward pass, and within issue 18's goal of 0.3 m
    # RMS of per-outage maxima (the open peer's best, back-correcting each outage with the next fix: 0.42 m).
    # Measured 0.206 m (forward 2.82 m); pooled over seven shifted schedules 0.250 m (bench_walk.py).
    assert sm["horizontal_m"]["worst"] < 0.2 * fwd["horizontal_m"]["worst"]
    assert sm["horizontal_m"]["rms"] < 0.3
    # Outside the outages the reference is the forward filter's own input (the receiver's RTK fixes), scored at
    # their epochs, where the forward pass has just taken them: the smoothed solution there is within the
    # issue's 0.05 m goal but not closer than the forward one (measured 0.0472 vs 0.0465 m; with the velocity
    # taken as instantaneous 0.0504 vs 0.0524 m).
    assert sm["outside"]["rms_h_m"] < 0.05


def test_tight_smoothed_clock_and_position():
    from gpsins.sim import ephemeris as sim_eph
    s = sim.simulate(scenario.load("default"), seed=0)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, s.scenario.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    offset = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": "tight"})
    fwd = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, smooth=True,
                  pseudoranges=sim.pseudorange_table(s), ephemerides=ephs,
                  klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta), gps_time_offset_s=offset)
    sm = fwd.extra["smoothed"]
    assert sm.clock is not None and sm.sigma.shape[1] == 15 + _core.SIS_SLOTS + 2  # slots, then the clock
    tr = truth_of(s)
    _, ef, sf = errors(fwd, tr)
    _, es, ss = errors(sm, tr)
    h = lambda e: float(np.sqrt(np.mean(e.r_ned[:, 0] ** 2 + e.r_ned[:, 1] ** 2)))  # noqa: E731
    assert h(es) < h(ef)
    assert np.all(ss <= sf * (1 + 1e-6) + 1e-12)


@pytest.mark.xfail(strict=True, reason="issue 35, the walk's model, not the smoother: smoothed vertical RMS 0.241 m "
                   "against 0.088 m forward (2.7x, bar 1.1x) over the walk's 339 RTK-fixed epochs; the backward pass "
                   "equals a textbook RTS with the fix-error states and restarts (test_rts.cpp) and every covariance "
                   "change on the walk is one the smoother is told; the forward pass is overconfident (fix NIS 3.97 "
                   "per dof): the published accelerometer bias drive 6.86e-5 m/s^2/sqrt(s) allows 0.8 mg in the "
                   "walk's 134 s, its forward estimate moves 3 mg. At 1e-3: 0.047 vs 0.035 m (1.34x), at 2e-3 0.032 "
                   "vs 0.026 m (1.23x), the smoothed outage drift then 0.30 and 0.32 m pooled (0.26 m now)")
def test_smoothed_height_stays_on_the_walks_rtk_fixes(tmp_path):
    from pathlib import Path

    from gpsins.replay import run as replay
    toml = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"
    res = replay.replay(toml, tmp_path / "r", outages="none", smooth=True)  # every fix, the schedule set aside
    fwd, sm = res.summary["scoring"]["outside"], res.summary["smoothed"]["scoring"]["outside"]
    # Every epoch scored is a fix the filter took: the smoothed solution, which has all of them, is no
    # farther from them than the forward pass right after each update. The bar is the RTS smoother's own
    # property (its error variance at most the forward's at every epoch, Rauch, Tung and Striebel 1965;
    # test_tight_smoothed_clock_and_position checks the sigmas), with 10 % for the spread of an RMS over
    # 339 epochs whose errors are correlated (1 / sqrt(2 n) is 3.8 % for independent ones).
    assert sm["rms_v_m"] <= 1.1 * fwd["rms_v_m"]
