"""The tightly coupled filter against the simulator's truth: better than the loosely
coupled one on the report's drive, consistent where satellites are few, and still
navigating with two or three satellites."""

import numpy as np
import pytest

from gpsins import _core, evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario
from gpsins.sim import ephemeris as sim_eph
from gpsins.sim.scenario import parse

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
# 60 s with three satellites (PRN 16, 18, 21), of which 20 s with two (16, 21).
FEW = {"name": "few", "start": START, "gnss": {"elevation_mask_deg": 12.0},
       "segment": [{"label": "stand", "duration_s": 15, "speed_mps": 0},
                   {"label": "go", "duration_s": 10, "speed_mps": 12},
                   {"label": "run", "duration_s": 85, "turn_deg": 40}],
       "obstruction": [{"t0_s": 35, "t1_s": 95, "azimuth_deg": [160, 140], "below_elevation_deg": 60},
                       {"t0_s": 60, "t1_s": 80, "azimuth_deg": [140, 160], "below_elevation_deg": 30}]}


def both(s, modes=("loose", "tight"), **over):
    noise = sim.imu_noise_truth(s.scenario.imu)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, s.scenario.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    offset = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    out = {}
    for mode in modes:
        cfg = nav_config.load_config(None, {**noise, "mode": mode, **over})
        extra = dict(pseudoranges=sim.pseudorange_table(s), ephemerides=ephs,
                     klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta), gps_time_offset_s=offset) if mode == "tight" else {}
        out[mode] = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **extra)
    return out


def truth_of(s):
    return evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)


@pytest.fixture(scope="module")
def default_runs():
    s = sim.simulate(scenario.load("default"), seed=0)
    return s, both(s)


def test_tight_beats_loose_and_stays_consistent_where_satellites_are_few(default_runs):
    s, sols = default_runs
    tr = truth_of(s)
    rows = {}
    for mode, sol in sols.items():
        e = evaluate.nav_errors(sol, tr)
        hk = sol.heading_known
        h = np.hypot(e.r_ned[hk, 0], e.r_ned[hk, 1])
        rows[mode] = (np.sqrt(np.mean(h ** 2)), h.max(), e, sol)
    print(f"default drive: loose H RMS {rows['loose'][0]:.2f} m (max {rows['loose'][1]:.1f}), "
          f"tight {rows['tight'][0]:.2f} m (max {rows['tight'][1]:.1f})")
    assert rows["tight"][0] <= rows["loose"][0]
    # Segments with fewer than 4 satellites tracked at some time: tight inside its 3 sigma.
    g = s.gnss
    n_tracked = g.tracked.sum(1)
    _, _, e, sol = rows["tight"]
    sigma = evaluate.ned_sigma(sol)
    checked = 0
    for label, (t0, t1) in [(x[0], (x[1], x[2])) for x in s.scenario.segment_times()]:
        k = (g.t >= t0) & (g.t < t1)
        if not k.any() or n_tracked[k].min() >= 4:
            continue
        m = (sol.t >= t0) & (sol.t < t1) & sol.heading_known
        inside = np.abs(e.r_ned[m]) <= 3 * sigma[m]
        print(f"  {label}: {n_tracked[k].min()}-{n_tracked[k].max()} satellites, tight inside 3 sigma "
              f"{100 * inside.mean():.1f} %")
        assert inside.mean() >= 0.99, label
        checked += 1
    assert checked >= 3


def test_doppler_sharpens_tight_velocity_heading_and_position(default_runs):
    """The simulator's Doppler (its own carrier's rate over two epochs: about 0.03 m/s) in the preset's tight
    filter, against the same drive with doppler_sigma_mps = 0: the velocity is measured, not inferred from
    metre-level ranges, and the heading and position follow."""
    s, sols = default_runs
    tr = truth_of(s)
    rows = {}
    for name, sol in (("with", sols["tight"]), ("without", both(s, doppler_sigma_mps=0.0)["tight"])):
        e = evaluate.nav_errors(sol, tr)
        hk = sol.heading_known
        rows[name] = (np.sqrt(np.mean(np.sum(e.r_ned[hk, :2] ** 2, 1))), np.sqrt(np.mean(np.sum(e.v_ned[hk] ** 2, 1))),
                      np.sqrt(np.mean(e.ypr_deg[hk, 0] ** 2)), sol)
    print("default drive, tight with / without Doppler: H RMS %.2f / %.2f m, velocity RMS %.3f / %.3f m/s, "
          "yaw RMS %.2f / %.2f deg" % tuple(x for i in range(3) for x in (rows["with"][i], rows["without"][i])))
    up = rows["with"][3].updates
    rr = (up["kind"] == 9) & up["accepted"]
    assert rows["without"][3].counters["range_rates_used"] == 0 and rr.sum() > 10000
    # Measured: 1.05 / 3.35 m, 0.13 / 0.72 m/s, 0.86 / 2.93 deg (white signal-in-space error: 1.26 / 3.50 m).
    assert rows["with"][0] < 0.6 * rows["without"][0]
    assert rows["with"][1] < 0.5 * rows["without"][1] and rows["with"][2] < 0.5 * rows["without"][2]
    # The preset's 0.1 m/s (a real u-blox's) is above the simulator's 0.03: never over-confident.
    assert up["nis"][rr].mean() < 1.0


def test_doppler_is_used_at_every_epoch_when_the_ranges_are_thinned():
    """pseudorange_decimation is for the ranges' correlated errors; the Doppler's are white, so a filter that
    keeps every tenth epoch's ranges still takes every epoch's range rates."""
    s = sim.simulate(parse({**FEW, "segment": FEW["segment"][:2], "obstruction": []}), seed=2)
    c1, c10 = (both(s, pseudorange_decimation=n)["tight"].counters for n in (1, 10))
    print(f"decimation 1 / 10: {c1['pseudoranges_used']} / {c10['pseudoranges_used']} ranges, "
          f"{c1['range_rates_used']} / {c10['range_rates_used']} range rates")
    assert c10["pseudoranges_used"] < 0.15 * c1["pseudoranges_used"]
    assert c10["range_rates_used"] > 0.95 * c1["range_rates_used"] > 0


@pytest.mark.parametrize("clock", ["steered", "unsteered"])
def test_two_or_three_satellites_tight_keeps_navigating(clock):
    s = sim.simulate(parse({**FEW, "gnss": {**FEW["gnss"], "clock": clock}}), seed=1)
    g = s.gnss
    span = (g.t >= 36) & (g.t < 94)
    assert g.tracked[span].sum(1).max() <= 3 and g.tracked[span].sum(1).min() == 2
    sols = both(s)
    tr = truth_of(s)
    end = {}
    for mode, sol in sols.items():
        e = evaluate.nav_errors(sol, tr)
        k = np.searchsorted(sol.t, 94.0)
        end[mode] = (np.hypot(*e.r_ned[k, :2]), evaluate.ned_sigma(sol)[k])
    print(f"{clock} clock, after 60 s with 2-3 satellites: loose horizontal error {end['loose'][0]:.1f} m, "
          f"tight {end['tight'][0]:.1f} m")
    assert end["tight"][0] < end["loose"][0]
    assert end["tight"][0] <= 3 * np.hypot(*end["tight"][1][:2])
    assert sols["tight"].counters["pseudoranges_used"] > 0


def test_tight_nees_is_consistent_over_five_seeds():
    """The band is chi-square's (scipy, not the library's helper): the average over 5 independent runs of the
    9-state NEES is chi2(9 x 5) / 5 at each epoch, 95 % two-sided; averaging over the 60 s as well only narrows
    its spread, so this band is the conservative one for the time average."""
    from scipy.stats import chi2
    from test_filter import nees_over_seeds  # the loose filter's NEES run, on the same drive

    seeds, dof = 5, 9
    avg, _, _ = nees_over_seeds(lambda s: both(s)["tight"], seeds=seeds)
    lo, hi = chi2.ppf([0.025, 0.975], dof * seeds) / seeds
    print(f"tight: time-averaged NEES over {seeds} seeds x 60 s {avg:.2f}, band {lo:.2f}..{hi:.2f}")
    # Measured 7.33 (5.46 before the range rates; 5.0 before the signal-in-space part, 5.6 before
    # filter.flicker_white_var): neither over- nor under-confident.
    assert lo <= avg <= hi


def test_streaming_tight_equals_batch():
    s = sim.simulate(parse({**FEW, "segment": FEW["segment"][:2], "obstruction": []}), seed=2)
    sols = both(s)
    noise = sim.imu_noise_truth(s.scenario.imu)
    cfg = nav_config.load_config(None, {**noise, "mode": "tight"})
    core = nav_config.core_config(cfg)
    core.gps_time_offset_s = s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s
    f = _core.InsFilter(core, "tight")
    for e in s.gnss.ephemerides.values():
        f.add_ephemeris(_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, 1590))
    f.set_klobuchar(list(s.gnss.ion_alpha), list(s.gnss.ion_beta))
    imu, fixes, prs = sim.imu_table(s), sim.fix_table(s), sim.pseudorange_table(s)
    epochs = np.unique(prs[:, 0])
    j = q = 0
    for row in imu:
        while j < len(fixes) and fixes[j, 0] <= row[0]:
            x = fixes[j]
            f.push_fix(x[0], x[1:4], x[4:7], x[7], x[8], int(x[9]))
            j += 1
        while q < len(epochs) and epochs[q] <= row[0]:
            p = prs[prs[:, 0] == epochs[q]]
            f.push_pseudoranges(epochs[q], p[:, 1].astype(int).tolist(), p[:, 2].tolist(), p[:, 3].tolist(),
                                p[:, 4].astype(int).tolist(), p[:, 5].tolist())
            q += 1
        f.push_imu(row[0], row[1:4], row[4:7])
    assert np.array_equal(f.r_ecef, sols["tight"].r_ecef[-1])
    assert np.array_equal(f.clock, sols["tight"].clock[-1])
    with pytest.raises(ValueError, match="pseudoranges given to a loosely coupled filter"):
        _core.InsFilter(core, "loose").run(imu[:10], fixes[:0], prs[:5])


def test_receiver_clock_jumps_and_a_drift_beyond_its_prior_reseed_the_clock_states():
    """A free-running receiver clock drifting 1.5 us/s (450 m/s, 4.5 times the drift's prior sigma) and held
    within 0.5 ms by whole-millisecond steps (about 300 km in every pseudorange at once): the filter re-seeds the
    bias at each step (where the simulator stepped it, by what it stepped), keeps the drift, and uses the
    pseudoranges. The drift itself, 4.5 sigma beyond its prior, may cost one re-seed at the start."""
    drive = {**FEW, "segment": FEW["segment"][:2] + [{"label": "run", "duration_s": 45, "turn_deg": 40}],
             "obstruction": [], "gnss": {"clock": "ms_jumps", "clock_drift_s_per_s": 1.5e-6, "clock_bias_s": 4.5e-4}}
    s = sim.simulate(parse(drive), seed=3)
    g = s.gnss
    k = np.flatnonzero(np.abs(np.diff(g.clock.bias_s)) > 0.5e-3) + 1
    assert len(k) == 1  # at about 33 s: the scenario is built to have one
    sol = both(s)["tight"]
    c, ev = sol.counters, sol.events
    print(f"ms-jump clock: re-seeds at {ev['t'][ev['kind'] == 5]} s by {ev['value'][ev['kind'] == 5]} m; "
          f"{c['pseudoranges_used']} pseudoranges used, {c['pseudoranges_rejected']} rejected")
    reseed = ev["kind"] == 5
    step = reseed & (np.abs(ev["value"]) > 1e5)
    assert c["clock_reseeds"] == reseed.sum() and c["gnss_resets"] == 0
    # At the first epoch the filter uses after the step (events carry the IMU time that processed it).
    lag = ev["t"][step] - g.t[k]
    assert len(lag) == len(k) and np.all((lag >= -1.0 / 64) & (lag <= 1.0))
    np.testing.assert_allclose(ev["value"][step], 299792458.0 * (g.clock.bias_s[k] - g.clock.bias_s[k - 1]), atol=50.0)
    assert np.all(ev["t"][reseed & ~step] < 10.0) and (reseed & ~step).sum() <= 1
    assert c["pseudoranges_rejected"] < 0.02 * c["pseudoranges_used"]
    drift_true_mps = 299792458.0 * np.interp(sol.t[-1], g.t, g.clock.drift_s_per_s)
    assert sol.clock[-1, 1] == pytest.approx(drift_true_mps, abs=0.5)
    e = evaluate.nav_errors(sol, truth_of(s))
    hk = sol.heading_known
    assert np.sqrt(np.mean(np.sum(e.r_ned[hk, :2] ** 2, axis=1))) < 5.0


def test_tight_time_offset_state_stays_consistent_though_pseudoranges_barely_see_it():
    """IMU stamps 50 ms early (the sim's truth) with no offset declared. Pseudoranges alone see the offset only
    as the range rate times it (under a metre at 12-20 m/s), which the position states take as well: the sigma
    stayed near its 50 ms prior (48.5 ms on this drive, the estimate 0.1 ms). The range rates see it as the
    acceleration times it, against the INS's velocity: measured 41.4 +- 14.6 ms now. Asserted: consistent with
    the truth, learnt (sigma well below the prior), and costing nothing."""
    from gpsins.sim.scenario import first_seconds

    s = sim.simulate(first_seconds(scenario.load("default"), 150.0), seed=2)
    noise = sim.imu_noise_truth(s.scenario.imu)
    ephs = [_core.gnss.decode_subframes(sim_eph.encode_subframes(e), e.prn, s.scenario.start.gps_week)
            for e in s.gnss.ephemerides.values()]
    extra = dict(pseudoranges=sim.pseudorange_table(s), ephemerides=ephs, klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta),
                 gps_time_offset_s=s.scenario.start.gps_week * 604800.0 + s.scenario.start.gps_tow_s)
    imu = sim.imu_table(s).copy()
    imu[:, 0] -= 0.05  # each sample stamped 50 ms before the instant it measured
    tr = truth_of(s)
    out = {}
    for on in (False, True):
        cfg = nav_config.load_config(None, {**noise, "mode": "tight", "estimate_time_offset": on})
        sol = flt.run(imu, sim.fix_table(s), cfg, covariance=True, **extra)
        e = evaluate.nav_errors(sol, tr)
        k = sol.heading_known & (sol.t > sol.t[np.flatnonzero(sol.heading_known)[0]] + 5.0)
        out[on] = (float(np.sqrt(np.mean(e.r_ned[k, 0] ** 2 + e.r_ned[k, 1] ** 2))), sol)
    sol = out[True][1]
    est, sig = sol.time_offset[-1], sol.time_offset_sigma[-1]
    print(f"tight, IMU 50 ms early: estimate {1e3 * est:.1f} ms (sigma {1e3 * sig:.1f}); H RMS {out[True][0]:.2f} m "
          f"(state off {out[False][0]:.2f} m)")
    assert abs(est - 0.05) < 3 * sig and sig <= 0.025
    assert out[True][0] < 1.05 * out[False][0]
    assert out[False][1].time_offset is None and out[False][1].n_states + 1 == sol.n_states


def test_signal_in_space_states_keep_tight_with_doppler_consistent():
    """A broadcast orbit/clock error of hours (the simulator's own per-satellite draw, 2.45 m RMS here) with
    Doppler measuring the velocity: carried as white noise it looks averaged away and the position sigma
    shrinks below the error (measured: position NEES median 9.2 over seeds 0-5, 110 at worst); as one state
    per satellite it stays one error (median 3.1, 3 expected)."""
    nees = {True: [], False: []}
    for seed in range(6):
        sc = scenario.load("default")
        sc.gnss.sis_error_m = 2.0  # constant part and the slow swing's amplitude: 2 sqrt(1.5) m RMS
        s = sim.simulate(sc, seed=seed)
        tr = s.truth
        for states in (True, False):
            cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": "tight",
                                                "pseudorange_sis_sigma_m": 2.0 * np.sqrt(1.5),
                                                "pseudorange_sis_states": states})
            sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, **sim.tight_inputs(s))
            assert sol.counters["range_rates_used"] > 0
            err = evaluate.nav_errors(sol, evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb))
            sel = sol.t >= sol.t[np.argmax(sol.heading_known)]
            nees[states].append(float(evaluate.nees(err.e9[sel][:, 6:9], sol.covariance[sel][:, 6:9, 6:9]).mean()))
    print(f"\nposition NEES with states {np.round(nees[True], 2)}, white {np.round(nees[False], 2)}")
    with_states, white = np.median(nees[True]), np.median(nees[False])
    assert 1.0 < with_states < 5.0 and np.mean(nees[True]) < 6.0
    assert white > 2.0 * with_states


def test_each_satellite_takes_one_signal_in_space_slot(default_runs):
    """Fewer satellites than slots, one ephemeris each: every satellite whose pseudorange reached an update
    took a slot once, none was restarted or found none free; with the states off no slot is taken."""
    s, sols = default_runs
    sol = sols["tight"]
    up, c = sol.updates, sol.counters
    sats = np.unique(up["id"][up["kind"] == 6])
    assert 4 <= len(sats) <= _core.SIS_SLOTS
    assert c["sis_slots_taken"] == len(sats)
    assert c["sis_slots_restarted"] == 0 and c["pseudoranges_without_sis_slot"] == 0
    off = both(s, pseudorange_sis_states=False)["tight"].counters
    assert off["sis_slots_taken"] == off["sis_slots_restarted"] == off["pseudoranges_without_sis_slot"] == 0


def test_satellites_beyond_the_slots_give_only_their_doppler():
    """15 satellites above the horizon for 12 signal-in-space slots (the simulator's sky at 23:10 GPST,
    masks at 0 deg; a two-constellation receiver sees more every day). The slots stay with their
    satellites (none taken twice over); the three without one are not ranged (a constant error taken
    as white would average into the position): at most 12 pseudoranges per epoch, their Doppler
    still used. Against the truth: no worse than the same drive with the mask leaving 12 satellites
    (before: 3.07 m H RMS, against 1.74 m)."""
    start = {**START, "gps_tow_s": 429000.0}
    sc = parse({"name": "many", "start": start, "gnss": {"elevation_mask_deg": 0.0},
                "segment": [{"label": "stand", "duration_s": 20, "speed_mps": 0},
                            {"label": "go", "duration_s": 10, "speed_mps": 12},
                            {"label": "run", "duration_s": 90, "turn_deg": 90}]})
    s = sim.simulate(sc, seed=0)
    assert s.gnss.tracked.sum(1).max() > _core.SIS_SLOTS
    rms_h = {}
    for mask in (0.0, 5.0):
        sol = both(s, ("tight",), pseudorange_elevation_mask_deg=mask)["tight"]
        e = evaluate.nav_errors(sol, truth_of(s))
        h = np.hypot(e.r_ned[sol.heading_known, 0], e.r_ned[sol.heading_known, 1])
        rms_h[mask] = float(np.sqrt(np.mean(h ** 2)))
        c, up = sol.counters, sol.updates
        ranged = up["t"][(up["kind"] == 6) & up["accepted"]]
        if mask == 0.0:
            assert _core.SIS_SLOTS <= c["sis_slots_taken"] <= _core.SIS_SLOTS + 3, c["sis_slots_taken"]
            assert c["pseudoranges_without_sis_slot"] > 0
            assert np.unique(ranged, return_counts=True)[1].max() <= _core.SIS_SLOTS
            rates = up["t"][(up["kind"] == 9) & up["accepted"]]
            assert np.unique(rates, return_counts=True)[1].max() > _core.SIS_SLOTS  # Doppler: all of them
    print(f"\n15 satellites, 12 slots: tight H RMS {rms_h[0.0]:.2f} m; mask 5 deg (12): {rms_h[5.0]:.2f} m")
    assert rms_h[0.0] <= 1.15 * rms_h[5.0]
