"""The IMU lab workflow against a simulated lab day with known errors (seed 004, chapter 5)."""

import json
import math
import tomllib

import numpy as np
import pytest

from gpsins import cli
from gpsins.imu import allan, lab, noise_fit, records
from gpsins.imu import lab_calibration
from gpsins.imu import lab_plan
from gpsins.sim import imu as sim_imu
from gpsins.sim import lab as sim_lab
from gpsins.devices import lab as lab_mod


@pytest.fixture(scope="module")
def lab_day(tmp_path_factory):
    day = sim_lab.simulate_lab_day(sim_lab.LabDayConfig.quick(), seed=3)
    root = tmp_path_factory.mktemp("lab")
    plan = sim_lab.write_lab_day(day, root / "day")
    out = root / "out"
    assert cli.main(["lab", str(plan), "--out", str(out)]) == 0
    res = json.loads((out / "lab.json").read_text())
    return day, res, out


def _session(day, name):
    return next(s for s in day.sessions if s.name == name)


def _day_range(day, session, window_s):
    return session.i0 + int(round(window_s[0] * day.rate_hz)), session.i0 + int(round(window_s[1] * day.rate_hz))


def test_accelerometer_up_down_recovers_bias_and_scale_factor_within_3_sigma(lab_day):
    day, res, _ = lab_day
    truth = day.truth()
    for i, a in enumerate("xyz"):
        v = res["updown"]["axes"][a]
        s = _session(day, f"updown_{a}")
        up = _day_range(day, s, v["up"]["window_s"])
        dn = _day_range(day, s, v["down"]["window_s"])
        b_true = 0.5 * (day.true_bias("accel", *up)[i] + day.true_bias("accel", *dn)[i])
        assert abs(v["bias_mps2"] - b_true) <= 3 * v["bias_sigma_mps2"], (a, v["bias_mps2"], b_true)
        assert v["bias_sigma_mps2"] < 2e-3  # against biases of 0.2-0.3 m/s^2
        s_true = truth["accel_scale_factor"][i]
        assert abs(v["scale_factor"] - s_true) <= 3 * v["scale_factor_sigma"], (a, v["scale_factor"], s_true)
        assert v["scale_factor_sigma"] < 1e-3  # the report's alpha_ii are 5e-4 ... 3e-3


def test_gyro_rate_table_and_drift_test_recover_scale_factor_and_bias_within_3_sigma(lab_day):
    day, res, _ = lab_day
    truth = day.truth()
    drift = _session(day, "drift")
    for i, a in enumerate("xyz"):
        v = res["rate_table"]["axes"][a]
        s_true = truth["gyro_scale_factor"][i]
        assert abs(v["scale_factor"] - s_true) <= 3 * v["scale_factor_sigma"], (a, v["scale_factor"], s_true)
        assert v["scale_factor_sigma"] < 1e-3  # Table 5.5's beta_ii are 1.7e-3 ... 4.2e-3
        d = res["drift"][a]
        b_true = day.true_bias("gyro", *_day_range(day, drift, d["window_s"]))[i]
        assert abs(d["bias_rad_per_s"] - b_true) <= 3 * d["bias_sigma_rad_per_s"], (a, d["bias_rad_per_s"], b_true)
        assert d["bias_sigma_rad_per_s"] < 1e-4
        # The rate-table line's bias: the mean bias over the axis's runs.
        runs = [s for s in day.sessions if s.kind == "rate_table" and s.axis == a]
        b_runs = day.true_bias("gyro", runs[0].i0, runs[-1].i1)[i]
        assert abs(v["bias_rad_per_s"] - b_runs) <= 3 * v["bias_sigma_rad_per_s"]


def true_adev(day, kind, i, tau):
    m = day.config.imu
    from gpsins_logger import bp3010

    dt = 1.0 / day.rate_hz
    lsb = bp3010.dtheta_lsb_rad(day.rate_hz) if kind == "gyro" else bp3010.dv_lsb_mps(day.rate_hz)
    n = (m.gyro_arw_rad_per_sqrt_s if kind == "gyro" else m.accel_vrw_mps_per_sqrt_s)[i]
    b = (m.gyro_bias_instability_rad_per_s if kind == "gyro" else m.accel_bias_instability_mps2)[i]
    k = (m.gyro_rrw_rad_per_s_sqrt_s if kind == "gyro" else m.accel_rrw_mps2_per_sqrt_s)[i]
    av = (n ** 2 + lsb ** 2 / (12 * dt)) / tau + k ** 2 * tau / 3  # rounding each increment: white rate noise
    for T, w in zip(m.bias_instability_tau_s, sim_imu.bias_instability_weights(m.bias_instability_tau_s)):
        av = av + sim_imu.gm_avar(tau, math.sqrt(w) * b, T)
    return np.sqrt(av)


def test_noise_terms_within_their_confidence_bands(lab_day):
    day, res, _ = lab_day
    for name, v in res["noise"].items():
        kind, a = name.split("_")
        i = "xyz".index(a)
        tau = np.array(v["tau_s"])
        ok = np.array(v["edf"]) >= res["min_edf"]
        want = true_adev(day, kind, i, tau)
        # 68 % chi-square band (1 sigma): neighbouring taus share data, so one record wanders across
        # the band in runs; the truth stays within the 2-sigma band at most usable taus and within the
        # 4-sigma band at all of them.
        hi, adev = (np.array(v[k]) for k in ("chi2_hi", "adev"))
        dev = np.abs(np.log(want[ok] / adev[ok])) / np.log(hi[ok] / adev[ok])
        assert (dev <= 2).mean() > 0.7 and dev.max() <= 4, (name, dev.round(1))
        # The fitted terms' curve follows the truth within the data's 2-sigma band at most taus (the
        # simulated bias instability is a sum of Gauss-Markov processes, flat only from about 10 s to
        # 1000 s, which the flicker term B can only approximate).
        terms = tuple(t for t in ("Q", "N", "B", "K") if t in v["fit"])
        model = np.sqrt(noise_fit.basis(tau, terms) @ np.array([v["fit"][t] ** 2 for t in terms]))
        dev_fit = np.abs(np.log(want[ok] / model[ok])) / np.log(hi[ok] / adev[ok])
        assert (dev_fit <= 2).mean() > 0.75 and dev_fit.max() <= 3.5, (name, dev_fit.round(1))
        # White noise: the fitted N and the PSD level within 3 % of the truth (quantisation included).
        m = day.config.imu
        n_true = (m.gyro_arw_rad_per_sqrt_s if kind == "gyro" else m.accel_vrw_mps_per_sqrt_s)[i]
        assert v["fit"]["N"] == pytest.approx(n_true, rel=0.03)
        assert v["N_psd"] == pytest.approx(n_true, rel=0.05)


def test_outputs_are_a_preset_the_filter_accepts_kalibr_yaml_and_one_report(lab_day):
    _, res, out = lab_day
    from gpsins.nav import config as nav_config

    preset = tomllib.loads((out / "imu_preset.toml").read_text())
    cfg = nav_config.load_config(out / "imu_preset.toml")
    core = nav_config.core_config(cfg)
    assert core.gyro_scale_factor_cal[2] == pytest.approx(res["rate_table"]["axes"]["z"]["scale_factor"])
    assert preset["imu_noise"]["gyro_arw_rad_per_sqrt_s"][0] == pytest.approx(res["noise"]["gyro_x"]["fit"]["N"])
    assert "gyroscope_noise_density" in (out / "imu.yaml").read_text()
    html = (out / "report.html").read_text()
    md = (out / "report.md").read_text()
    for k in range(1, 11):
        assert f"Table 5.{k}:" in md and f"Table 5.{k}:" in html
    assert html.count("data:image/png;base64,") >= 2
    g = res["noise"]["gyro_x"]
    assert len(g["eq59_lo"]) == len(g["tau_s"]) == len(g["chi2_hi"])
    assert any(w.startswith("drift run: 30 min static") for w in res["warnings"])  # short for B and K
    # The preset's turn-on uncertainty covers the bias's wander over the lab day.
    day = lab_day[0]
    span = (day.sessions[-1].i1 - day.sessions[0].i0) / day.rate_hz
    assert res["day_span_s"] == pytest.approx(span, abs=1.0)
    k = max(res["noise"][f"gyro_{a}"]["fit"]["K"] for a in "xyz")
    assert preset["gyro_bias_residual_rad_per_s"] >= k * math.sqrt(span) > 2e-3


def test_motion_warning_fires_on_a_moving_record_and_not_on_a_static_one(tmp_path, capsys):
    from gpsins import sim
    from gpsins.sim import scenario
    from gpsins.sim.session import write_session

    s = sim.simulate(scenario.load("default"), seed=0)
    write_session(s, tmp_path / "drive")
    assert cli.main(["allan", str(tmp_path / "drive"), "--json", str(tmp_path / "a.json")]) == 0
    captured = capsys.readouterr()
    assert "moved" in captured.err and "withheld" in captured.out
    assert json.loads((tmp_path / "a.json").read_text())["axes"]["gyro_x"]["fit"] is None
    # A static record of the same length: no warning.
    day = sim_lab.simulate_lab_day(sim_lab.LabDayConfig.quick(drift_s=300.0, table_rates_rad_per_s=(1.0, -1.0)),
                                   seed=1)
    d = _session(day, "drift")
    rates = np.hstack([day.dtheta[d.i0:d.i1], day.dv[d.i0:d.i1]]) * day.rate_hz
    st = records.steady_windows(rates, day.rate_hz)
    assert not st.moved and records.motion_warning(st, 300.0) is None
    # The up-down session has exactly its two positions.
    u = _session(day, "updown_x")
    st = records.steady_windows(np.hstack([day.dtheta[u.i0:u.i1], day.dv[u.i0:u.i1]]) * day.rate_hz, day.rate_hz)
    assert len(st.windows) == 2 and st.moved


def test_short_files_are_refused_and_column_kinds_declared(tmp_path, capsys):
    np.savetxt(tmp_path / "three.csv", np.ones((3, 6)), delimiter=",")
    assert cli.main(["allan", str(tmp_path / "three.csv"), "--rate", "64"]) == 2
    assert "3 samples" in capsys.readouterr().err
    y = np.random.default_rng(0).normal(0, 1e-3 * 8, (64 * 600, 4))
    np.savetxt(tmp_path / "g.csv", y, delimiter=",")
    assert cli.main(["allan", str(tmp_path / "g.csv"), "--rate", "64"]) == 2
    assert "declare" in capsys.readouterr().err
    assert cli.main(["allan", str(tmp_path / "g.csv"), "--rate", "64", "--columns", "skip,gyro_x,gyro_y,gyro_z",
                     "--json", str(tmp_path / "g.json")]) == 0
    doc = json.loads((tmp_path / "g.json").read_text())
    assert set(doc["axes"]) == {"gyro_x", "gyro_y", "gyro_z"}
    assert doc["axes"]["gyro_y"]["fit"]["N"] == pytest.approx(1e-3, rel=0.05)


def test_slope_readouts_use_only_taus_with_enough_degrees_of_freedom():
    # White noise only: the ADEV falls to the last tau. Unrestricted, the "minimum" sits on a tau with
    # about 2 degrees of freedom (the 3x-too-small B); restricted, it is flagged an upper bound.
    y = np.random.default_rng(7).normal(0, 1e-3 * 8, 64 * 1800)
    r = allan.oadev(y, 64.0)
    assert r.edf[-1] < 5
    ro = noise_fit.slope_readouts(r.tau, r.adev, r.edf, min_edf=10)
    usable = r.tau[r.edf >= 10]
    assert ro["max_tau_used_s"] == pytest.approx(usable.max())
    assert ro["tau_at_min_s"] <= usable.max() and ro["B_is_upper_bound"]
    assert ro["N_at_tau_1"] == pytest.approx(1e-3, rel=0.05)
    few = noise_fit.slope_readouts(r.tau, r.adev, r.edf, min_edf=1e9)
    assert "warning" in few and "N_at_tau_1" not in few


def test_a_low_last_point_does_not_drag_the_fit_down():
    # The failure mode in the fit: white noise and rate random walk, the last tau (about two
    # degrees of freedom) scattered ten times low. Weighted by its own AVAR it used to pull K to zero.
    tau = np.logspace(-1.5, 3.5, 40)
    n, k = 7e-3, 1.3e-3
    adev = np.sqrt(n ** 2 / tau + k ** 2 * tau / 3)
    edf = np.maximum(1000.0 / tau, 1.5)
    adev[-1] /= 10
    f = noise_fit.fit(tau, adev, edf)
    assert f.value["K"] == pytest.approx(k, rel=0.1) and f.value["N"] == pytest.approx(n, rel=0.02)


def test_non_overlapping_estimator_is_eq_5_7():
    y = np.random.default_rng(1).normal(size=12)
    r = allan.adev_nonoverlapping(y, 1.0, taus="all")
    for n, got in zip(r.m, r.avar):
        x = y[: (12 // n) * n].reshape(-1, n).mean(1)  # eq. 5.6
        want = np.sum(np.diff(x) ** 2) / (2 * (12 // n - 1))  # eq. 5.7
        assert got == pytest.approx(want, rel=1e-12)
    assert r.rel_sigma_eq59[0] == pytest.approx(1 / math.sqrt(2 * (12 - 1)))  # eq. 5.9 at n = 1


def test_window_difference_variance_is_twice_the_allan_variance_for_adjacent_windows():
    for term, c in (("N", 1e-3), ("B", 1e-3), ("K", 1e-4)):
        for T in (2.0, 60.0):
            v = noise_fit.window_combination_variance({term: c}, 1 / 64, [(0.0, T, -1.0), (T, T, 1.0)])
            assert v == pytest.approx(2 * c ** 2 * noise_fit.basis(np.array([T]), (term,))[0, 0], rel=0.01)
    # Random walk, two windows of T with a gap G: var = K^2 (2 T / 3 + G) (integrating the increments).
    k, T, G = 1e-3, 30.0, 8.0
    v = noise_fit.window_combination_variance({"K": k}, 1 / 64, [(0.0, T, 1.0), (T + G, T, -1.0)])
    assert v == pytest.approx(k ** 2 * (2 * T / 3 + G), rel=0.01)
    # Covariances: var(c1 + c2) = var c1 + var c2 + 2 cov(c1, c2).
    c1 = [(0.0, 20.0, 1.0), (0.0, 200.0, -1.0)]
    c2 = [(150.0, 50.0, 1.0), (0.0, 200.0, -1.0)]
    value = {"N": 1e-3, "B": 2e-4, "K": 1e-4}
    cov = noise_fit.window_combination_covariance(value, 1 / 64, [c1, c2])
    both = noise_fit.window_combination_variance(value, 1 / 64, c1 + c2)
    assert both == pytest.approx(cov[0, 0] + cov[1, 1] + 2 * cov[0, 1], rel=0.01) and cov[0, 1] == cov[1, 0]


def test_gauss_markov_bump_gives_its_time_constant_and_sigma():
    from scipy.signal import lfilter

    rng = np.random.default_rng(4)
    rate, T, sigma = 16.0, 20.0, 2e-3
    n = int(rate * 4 * 3600)
    phi = math.exp(-1 / (rate * T))
    gm = lfilter([1.0], [1.0, -phi], rng.normal(0, sigma * math.sqrt(1 - phi * phi), n))
    y = gm + rng.normal(0, 1e-4 * math.sqrt(rate), n)
    r = allan.oadev(y, rate, taus=20)
    bump = noise_fit.gauss_markov_bump(r.tau, r.adev, r.lo, r.hi, r.edf)
    assert bump is not None
    assert bump["T_s"] == pytest.approx(T, rel=0.25) and bump["sigma"] == pytest.approx(sigma, rel=0.15)
    assert noise_fit.gauss_markov_bump(r.tau, np.sqrt(1e-8 / r.tau), r.lo * 0 + np.sqrt(1e-8 / r.tau) * 0.9,
                                       np.sqrt(1e-8 / r.tau) * 1.1, r.edf) is None


def test_plan_errors_name_the_file_and_key(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text('[site]\nlat_deg = 59.3\n[[rate_table]]\nsession = "a"\naxis = "x"\n')
    with pytest.raises(lab_plan.PlanError, match=r"plan.toml: \[\[rate_table\]\] 1: give rate_rad_per_s"):
        lab_plan.load_plan(p)
    p.write_text('[site]\nlat_deg = 59.3\n[drift]\nsession = "a"\nheading = 3\n')
    with pytest.raises(lab_plan.PlanError, match="unknown key"):
        lab_plan.load_plan(p)
    p.write_text('[drift]\nsession = "nowhere"\n[site]\nlat_deg = 1.0\n')
    with pytest.raises(records.RecordError, match="nowhere"):
        lab.run_plan(lab_plan.load_plan(p))


def test_a_real_handheld_walk_gets_the_motion_warning_and_no_noise_terms(shared_data, tmp_path, capsys):
    csv = shared_data / "walk_0827" / "imu_1730_sf.csv"  # accelerometer in g, gyro in rad/s
    cols = "time,accel_x:g,accel_y:g,accel_z:g,gyro_x,gyro_y,gyro_z,skip,skip,skip,skip"
    assert cli.main(["allan", str(csv), "--rate", "152", "--columns", cols, "--json", str(tmp_path / "w.json")]) == 0
    assert "moved" in capsys.readouterr().err
    doc = json.loads((tmp_path / "w.json").read_text())
    assert doc["moved"] and doc["axes"]["accel_z"]["fit"] is None
    rec = records.load(csv, 152.0, cols)
    acc = np.column_stack([rec.column(f"accel_{a}")[:152] for a in "xyz"])
    assert np.linalg.norm(acc.mean(0)) == pytest.approx(9.8, abs=0.3)  # g converted to m/s^2


def test_a_lab_recording_goes_through_the_emulator_and_the_logger(tmp_path):
    from gpsins.session import logs

    day = sim_lab.simulate_lab_day(sim_lab.LabDayConfig.quick(position_s=4.0, drift_s=20.0,
                                                              table_rates_rad_per_s=(2.0,)), seed=2)
    plan = lab_mod.record_through_logger(day, tmp_path / "pty", speed=4.0, sessions=["updown_x"])
    sim_lab.write_lab_day(day, tmp_path / "direct")
    got = logs.read_session(tmp_path / "pty" / "updown_x")
    assert got.sidecar["sensors"]["imu"]["device"] == "bp3010"
    a, b = got.imu(), logs.read_session(tmp_path / "direct" / "updown_x").imu()
    # The logger starts the IMU with its rate command: the first frames go by before it (more of them
    # on a busy machine); the rest are the directly written frames, sample for sample.
    assert 0.5 * len(b) <= len(a) <= len(b)
    ca, cb = (np.hstack([x.dtheta_rad, x.dv_mps]) for x in (a, b))
    assert np.array_equal(ca, cb[len(b) - len(a):])
    assert lab_plan.load_plan(plan).updown == [{"session": "updown_x"}]


def test_the_example_plan_parses():
    from importlib import resources

    text = resources.files("gpsins.imu").joinpath("lab_plan.example.toml").read_text()
    data = tomllib.loads(text)
    assert {e["session"] for e in data["updown"]} == {"updown_x", "updown_y", "updown_z"}
    w, sig = lab_calibration._table_rate(data["rate_table"][1])
    assert w == pytest.approx(-0.5, rel=1e-3) and sig == pytest.approx(abs(w) * 0.2 / 125.7, rel=1e-9)


def test_calibrate_takes_an_up_down_recording(lab_day, capsys):
    day, res, out = lab_day
    session = out.parent / "day" / "updown_y"
    assert cli.main(["calibrate", "accel-updown", str(session), "--lat-deg", "59.35"]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("y "))
    assert float(line.split()[1]) == pytest.approx(res["updown"]["axes"]["y"]["bias_mps2"], abs=1e-5)


def test_non_overlapping_estimator_in_the_lab_noise_analysis():
    rng = np.random.default_rng(9)
    y = rng.normal(0, 1e-3 * 8, (64 * 600, 6)) + [0.01, 0.02, 0.0, 0.1, 0.2, -9.8]
    rec = records.Record("static", y, 64.0, records.AXES)
    out = lab_plan.noise_analysis(rec, {"estimator": "non-overlapping"})
    r = out["gyro_x"]["allan"]
    assert r.estimator == "non-overlapping" and out["gyro_x"]["fit"].value["N"] == pytest.approx(1e-3, rel=0.05)
    assert np.all(r.edf == 38400 // r.m - 1)
