"""The outlier defence cannot lock the filter out (a run of rejections turns into down-weighted
updates), wild fixes cost no more than an outage as long, and a GNSS reset gives the attitude an
honest covariance. Truth from the simulator; every comparison is against a second run of the same
filter on the same data with the faulty fixes simply left out, which is what the defence should
reduce them to."""

import numpy as np
import pytest

from gpsins import evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario


@pytest.fixture(scope="module")
def drive():
    return sim.simulate(scenario.load("default"), seed=0)


def truth_of(s):
    tr = s.truth
    return evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb)


def config(s, **over):
    return nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), **over})


def horizontal_error(s, sol) -> np.ndarray:
    return np.linalg.norm(evaluate.nav_errors(sol, truth_of(s)).r_ned[:, :2], axis=1)


def longest_rejected_run(sol, kind: int) -> int:
    u = sol.updates
    acc = np.asarray(u["accepted"])[np.asarray(u["kind"]) == kind]
    run = best = 0
    for a in acc:
        run = 0 if a else run + 1
        best = max(best, run)
    return best


def rtk_fixes(s, sigma_m: float = 0.02, sigma_mps: float = 0.03, seed: int = 7) -> np.ndarray:
    """Centimetre fixes of the true trajectory at the receiver's epochs, white at the sigmas they state
    (16 columns: filter.run's stated-sigma layout)."""
    t = sim.fix_table(s)[:, 0]
    t = t[(t >= s.truth.t[0]) & (t <= s.truth.t[-1])]
    g = np.random.default_rng(seed)
    i = np.clip(np.searchsorted(s.truth.t, t), 0, len(s.truth.t) - 1)
    r = s.truth.position_at(t) + g.normal(0.0, sigma_m, (len(t), 3))
    v = s.truth.v_ecef[i] + g.normal(0.0, sigma_mps, (len(t), 3))
    n = len(t)
    return np.column_stack([t, r, v, np.ones((n, 2)), np.full(n, 2.0), np.full((n, 3), sigma_m),
                            np.full((n, 3), sigma_mps)])


def test_an_over_confident_filter_is_pulled_back_instead_of_locked_out(drive):
    """Told a tenth of the IMU's true noise and given centimetre fixes, the filter's covariance is far
    too small for them: the hard gate then refuses good fixes in runs, and only the 5 s GNSS reset brings
    it back. With the defence no more than robust_after_rejections fixes in a row are refused, the
    down-weighted ones pull the filter back, and it is closer to the truth."""
    s = drive
    noise = sim.imu_noise_truth(s.scenario.imu)
    quiet = {k: (np.asarray(v) / 10.0).tolist() for k, v in noise["imu_noise"].items()}
    imu, fixes = sim.imu_table(s), rtk_fixes(s)
    base = nav_config.load_config(None, {**noise, "imu_noise": quiet, "use_fix_velocity": True,
                                         "fix_error_gm_sigma_m": [0.0, 0.0, 0.0], "gyro_misalignment_sigma_rad": 0.0})
    hard = flt.run(imu, fixes, {**base, "robust_after_rejections": 0})
    robust = flt.run(imu, fixes, base)
    limit = int(base["robust_after_rejections"])
    assert longest_rejected_run(hard, 1) > limit  # the case the defence is for
    assert longest_rejected_run(robust, 1) <= limit
    assert robust.counters["updates_downweighted"] > 0
    assert robust.counters["gnss_resets"] <= hard.counters["gnss_resets"]
    rms = {k: float(np.sqrt(np.mean(horizontal_error(s, r) ** 2))) for k, r in (("hard", hard), ("robust", robust))}
    print(rms)
    assert rms["robust"] < 0.5 * rms["hard"]


def test_thirty_wild_fixes_cost_no_more_than_an_outage_as_long(drive):
    """30 consecutive 3D fixes 1e7 m off (thousands of km up): they outlasted the reset's timeout and
    the filter was reset onto them. A fix off the Earth is not used at all, so the filter coasts
    through them as through an outage of the same length."""
    s = drive
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    cfg = config(s)
    usable = (fixes[:, 9] == 2) & (fixes[:, 7:9] <= cfg["fix_max_dop"]).all(1)  # the DOP mask comes first
    k = np.flatnonzero((fixes[:, 0] > 150.0) & usable)[:30]
    wild = fixes.copy()
    wild[k, 1:4] += 1e7 / np.sqrt(3.0)
    sol = flt.run(imu, wild, cfg)
    gap = flt.run(imu, np.delete(fixes, k, axis=0), cfg)
    e_wild, e_gap = horizontal_error(s, sol), horizontal_error(s, gap)
    assert not sol.counters["diverged"] and sol.counters["fixes_implausible"] == len(k)
    # Over the stretch and the minute after it the error stays at the outage run's, to a few cm.
    near = (sol.t >= fixes[k[0], 0]) & (sol.t < fixes[k[-1], 0] + 60.0)
    assert e_wild[near].max() <= e_gap[near].max() * 1.05 + 0.05


def test_a_fix_with_a_vanishing_dop_is_not_absolute(drive):
    """An HDOP and VDOP of 1e-9 made the fix's R vanish: the filter took the fix as exact and refused
    the good fixes after it. Its DOP counts as at least fix_min_dop."""
    s = drive
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    cfg = config(s)
    k = np.flatnonzero((fixes[:, 0] > 150.0) & (fixes[:, 9] == 2))[0]
    tiny = fixes.copy()
    tiny[k, 7:9] = 1e-9
    sol = flt.run(imu, tiny, cfg)
    without = flt.run(imu, np.delete(fixes, k, axis=0), cfg)
    after = sol.t > fixes[k, 0]
    assert horizontal_error(s, sol)[after].max() <= horizontal_error(s, without)[after].max() + 0.5
    assert not sol.counters["diverged"]


def test_a_gnss_reset_makes_the_attitude_uncertain_again(drive):
    """Ten seconds of zero velocity increments drive the filter off and reset it onto GNSS. The reset
    used to keep the attitude's old confidence, which is what let a car's pitch stay 2-3 deg wrong;
    now its tilt sigma right after is at least the initial levelling's."""
    s = drive
    imu = sim.imu_table(s)
    imu[(imu[:, 0] >= 100) & (imu[:, 0] < 110), 4:7] = 0.0
    cfg = config(s)
    sol = flt.run(imu, sim.fix_table(s), cfg)
    resets = [e["t"] for e in sol.event_list() if e["kind"] == "gnss_reset"]
    assert resets
    i = np.searchsorted(sol.t, resets[0])
    tilt_sigma = sol.sigma[i, :2].min()  # ECEF attitude error axes: the tilt shows in all three
    assert tilt_sigma >= np.radians(cfg["attitude_sigma_deg"][0]) * 0.5
    err = evaluate.nav_errors(sol, truth_of(s))
    later = sol.t > resets[-1] + 30.0
    assert np.mean(np.abs(err.e9[later, :3]) <= 3 * sol.sigma[later, :3]) > 0.95


def test_the_fits_gate_uses_every_fix_and_still_ends_a_false_standstill(drive):
    """`gate_standstill_only` (the likelihood fits' runs): a fix 16 m off at rest is used, where the gate
    refuses it, while a zero-velocity update after a 0.2 m/s jolt at rest is still refused (ending the
    standstill), where with no gate at all it is taken."""
    imu, fixes = sim.imu_table(drive).copy(), sim.fix_table(drive).copy()  # the module's drive stays clean
    kinds = {name: code for code, name in flt.UPDATE_KINDS.items()}
    k = int(np.argmin(np.abs(fixes[:, 0] - 255.0)))
    fixes[k, 1:4] += [12.0, -9.0, 5.0]
    imu[int(np.argmin(np.abs(imu[:, 0] - 270.3))), 4] += 0.2  # a velocity increment at rest (the last 45 s)
    seen = {}
    for name, over in (("gated", {}), ("standstill only", {"gate_standstill_only": True}),
                       ("no gate", {"gate_probability": 0.0})):
        u = flt.run(imu, fixes, config(drive, **over)).updates
        kind, ok, t = (np.asarray(u[c]) for c in ("kind", "accepted", "t"))
        bad_fix = ok[(kind == kinds["fix_3d"]) & (np.abs(t - fixes[k, 0]) < 1e-6)]
        assert len(bad_fix) == 1, name
        seen[name] = (bool(bad_fix[0]), int((~ok[kind == kinds["zero_velocity"]]).sum()))
    assert seen["gated"][0] is False and seen["gated"][1] >= 1
    assert seen["standstill only"] == (True, seen["gated"][1])
    assert seen["no gate"] == (True, 0)
