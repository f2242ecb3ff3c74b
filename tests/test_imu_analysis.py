"""IMU characterisation against Stable32, allantools, the seeds' numbers and
simulated data with known coefficients."""

import json
import math
from pathlib import Path

import allantools
import numpy as np
import pytest

from gpsins import cli
from gpsins.imu import allan, calibration, noise_fit, psd


@pytest.fixture
def allan_data(shared_data) -> Path:
    return shared_data / "allan"


def stable32(d, name):
    return np.loadtxt(d / name, comments="#")


def test_phase_dat_matches_stable32(allan_data):
    DATA = allan_data
    x = np.loadtxt(DATA / "PHASE.DAT", comments="#")
    ref = stable32(DATA, "PHASE_oadev_octave_stable32.txt")
    r = allan.oadev(x, 1.0, taus="octave", data_type="phase")
    k = len(ref)
    assert np.allclose(r.tau[:k], ref[:, 1])
    assert np.all(r.n_phase - 2 * r.m[:k] == ref[:, 2])  # Stable32's "#" column
    assert np.max(np.abs(r.adev[:k] / ref[:, 5] - 1)) < 1e-4
    assert np.array_equal(r.alpha[:k], ref[:, 3])  # noise type identified as Stable32 did
    assert np.max(np.abs(r.lo[:k] / ref[:, 4] - 1)) < 0.005 and np.max(np.abs(r.hi[:k] / ref[:, 6] - 1)) < 0.005


def test_ocxo_frequency_data_matches_stable32(allan_data):
    y = np.loadtxt(allan_data / "ocxo_frequency.txt", comments="#") / 1e7
    ref = stable32(allan_data, "ocxo_oadev_octave_stable32.txt")
    r = allan.oadev(y, 1.0, taus="octave")
    k = len(ref)
    assert np.max(np.abs(r.adev[:k] / ref[:, 5] - 1)) < 2e-3
    same = r.alpha[:k] == ref[:, 3]
    assert same[:10].all()
    assert np.max(np.abs(r.lo[:k][same] / ref[same, 4] - 1)) < 0.005


def test_equals_allantools_on_random_data():
    y = np.random.default_rng(3).normal(0.01, 1.0, (200_000, 2))
    r = allan.oadev(y, 64.0)
    for k in range(2):
        t, d, _, _ = allantools.oadev(y[:, k], rate=64.0, data_type="freq", taus=r.tau)
        sel = np.isin(np.round(r.tau, 9), np.round(t, 9))
        assert sel.sum() == len(t) >= len(r.tau) - 1
        assert np.max(np.abs(d / r.adev[sel, k] - 1)) < 1e-9


def test_seed_numbers():
    # 0.15 deg/sqrt(h) = 4.36e-5 rad/sqrt(s) (seed 000).
    assert 0.15 / noise_fit.RAD_PER_SQRT_S_TO_DEG_PER_SQRT_H == pytest.approx(4.36e-5, rel=1e-3)
    # The Gauss-Markov Allan deviation peaks at tau = 1.89 T with 0.617 of the stationary sigma (ERRATA).
    T = 50.0
    tau = np.logspace(0, 3, 20001)
    g = np.sqrt(noise_fit.basis(tau, (), (T,))[:, 0])
    assert tau[np.argmax(g)] / T == pytest.approx(1.89, abs=0.01)
    assert g.max() == pytest.approx(0.617, abs=0.001)
    # Bias instability floor: sqrt(2 ln 2 / pi) = 0.664.
    assert noise_fit.FLAT == pytest.approx(0.664, abs=5e-4)


def synthetic_imu(seed=0, rate=64.0, hours=3.0, n=1e-3, b=2e-4, k=3e-5, q=2e-6):
    """Rate samples with known white noise N, flicker-like bias instability B (a weighted sum of
    Gauss-Markov processes whose ADEV is flat at 0.664 B), rate random walk K and quantisation Q."""
    from gpsins.sim.imu import bias_instability_weights

    rng = np.random.default_rng(seed)
    count = int(hours * 3600 * rate)
    dt = 1.0 / rate
    y = rng.normal(0, n / math.sqrt(dt), count)
    taus = (3.0, 10.0, 30.0, 100.0, 300.0, 1000.0)
    for T, v in zip(taus, bias_instability_weights(taus)):
        phi = math.exp(-dt / T)
        s = math.sqrt(v) * b
        e = rng.normal(0, s * math.sqrt(1 - phi * phi), count)
        from scipy.signal import lfilter
        y += lfilter([1.0], [1.0, -phi], e)
    y += np.cumsum(rng.normal(0, k * math.sqrt(dt), count))
    # Quantisation of the integrated output (an angle LSB q): white phase noise of Q = q / sqrt(12).
    phase = np.cumsum(y * dt)
    qphase = np.round(phase / q) * q
    return np.diff(np.concatenate([[0.0], qphase])) / dt, dict(Q=q / math.sqrt(12), N=n, B=b, K=k)


def test_noise_fit_recovers_known_coefficients():
    y, truth = synthetic_imu(q=2e-4)  # a coarse angle LSB, so that quantisation shows at short tau
    r = allan.oadev(y, 64.0)
    f = noise_fit.fit(r.tau, r.adev, r.edf, terms=("Q", "N", "B", "K"))
    for term in ("Q", "N", "B", "K"):
        got, want = f.value[term], truth[term]
        assert abs(got - want) < max(3 * f.sigma[term], 0.15 * want), (term, got, want, f.sigma[term])
    ro = f.slope_readouts
    assert ro["N_at_tau_1"] == pytest.approx(truth["N"], rel=0.15)
    # The minimum also holds the white noise and random walk there: the read-out overestimates B.
    assert truth["B"] < ro["B_min_over_0.664"] < 2 * truth["B"]
    # Less the fitted white noise and random walk at that tau, the read-out agrees with B.
    assert ro["B_min_less_other_terms"] == pytest.approx(truth["B"], rel=0.25)


def test_psd_white_level_agrees_with_allan():
    y = np.random.default_rng(5).normal(0, 2e-3 * math.sqrt(64.0), 64 * 3600)  # N = 2e-3 per sqrt(s)
    f, p = psd.psd(y, 64.0)
    n_psd = psd.white_level(f, p)
    r = allan.oadev(y, 64.0)
    n_allan = noise_fit.fit(r.tau, r.adev, r.edf, terms=("N",)).value["N"]
    assert n_psd == pytest.approx(2e-3, rel=0.03)
    assert n_psd == pytest.approx(n_allan, rel=0.03)
    fc, pc = psd.log_average(f, p)
    assert len(fc) < len(f) / 10 and np.all(np.diff(fc) > 0)


TABLE_5_2 = np.array([[-0.0123, -0.0136], [0.0117, 0.0102], [0.0901, 0.0860], [-0.0897, -0.0938],
                      [0.2794, 0.2760], [-0.2768, -0.2798], [-0.4603, -0.4618], [0.4647, 0.4608]])


def test_rate_table_least_squares_gives_table_5_5_for_gyro_x():
    c = calibration.gyro_rate_table(TABLE_5_2[:, 0], TABLE_5_2[:, 1])
    assert round(c.scale_factor, 4) == -0.0020  # Table 5.5 (ERRATA: -0.00205)
    assert c.scale_factor == pytest.approx(-0.00205, abs=5e-5)


def test_rate_table_and_up_down_recover_simulated_truth():
    rng = np.random.default_rng(2)
    lat = math.radians(59.35)
    w_ex = calibration.earth_rate_component(lat, axis_up=True)
    rates = np.array([-0.46, -0.28, -0.09, -0.012, 0.012, 0.09, 0.28, 0.46])
    for s, b in ((-0.0042, 0.0146681), (-0.0017, 0.0195939)):  # gyros y and z of Table 5.5
        out = (1 + s) * (rates + w_ex) + b + rng.normal(0, 2e-5, len(rates))
        c = calibration.gyro_rate_table(rates, out, w_ex)
        assert c.scale_factor == pytest.approx(s, abs=1e-4) and c.bias == pytest.approx(b, abs=3e-5)
    g = calibration.local_gravity_mps2(lat, 0.0)
    assert g == pytest.approx(9.8187, abs=2e-4)  # ERRATA: 59 deg 21' N
    b, s = 0.2312, -0.0014
    c = calibration.accel_up_down(b + (1 + s) * g, b - (1 + s) * g, g)
    assert c.bias == pytest.approx(b, abs=1e-12) and c.scale_factor == pytest.approx(s, abs=1e-12)
    printed = ((b - (1 + s) * g) - (b + (1 + s) * g) - 2 * g) / (2 * g)  # eq. 5.2 as printed
    assert printed == pytest.approx(-2.0, abs=0.01)


def test_allan_cli_writes_json_plots_and_filter_files(tmp_path, capsys, monkeypatch):
    import matplotlib.axes

    y, _ = synthetic_imu(hours=0.5)
    data = np.column_stack([y, 0.5 * y, y, 10 * y, 10 * y, 10 * y])
    np.save(tmp_path / "rates.npy", data)
    labels, set_ylabel = [], matplotlib.axes.Axes.set_ylabel
    monkeypatch.setattr(matplotlib.axes.Axes, "set_ylabel",
                        lambda self, label, *a, **k: (labels.append(label), set_ylabel(self, label, *a, **k))[1])
    assert cli.main(["allan", str(tmp_path / "rates.npy"), "--rate", "64", "--json", str(tmp_path / "a.json"),
                     "--out", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "a.json").read_text())
    assert set(doc["axes"]) == {"gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"}
    gx, gy = doc["axes"]["gyro_x"], doc["axes"]["gyro_y"]
    assert gy["fit"]["N"] == pytest.approx(0.5 * gx["fit"]["N"], rel=1e-6)
    assert (tmp_path / "out" / "allan_gyro.png").stat().st_size > 10_000
    assert labels == ["Allan deviation (rad/s)", "one-sided PSD ((rad/s)^2/Hz)",
                      "Allan deviation (m/s^2)", "one-sided PSD ((m/s^2)^2/Hz)"]  # the sensors' units, not "SI"
    import tomllib
    noise = tomllib.loads((tmp_path / "out" / "imu_noise.toml").read_text())["imu_noise"]
    assert noise["gyro_arw_rad_per_sqrt_s"][0] == pytest.approx(gx["fit"]["N"])
    from gpsins.nav import config as nav_config
    c = nav_config.core_config(nav_config.load_config(None, {"imu_noise": noise}))
    assert c.gyro_arw_rad_per_sqrt_s[1] == pytest.approx(gy["fit"]["N"])
    assert "gyroscope_noise_density" in (tmp_path / "out" / "imu.yaml").read_text()


def test_calibrate_cli_table(tmp_path, capsys):
    np.savetxt(tmp_path / "gx.csv", TABLE_5_2, delimiter=",")
    assert cli.main(["calibrate", "gyro-rate-table", str(tmp_path / "gx.csv")]) == 0
    assert "scale factor -0.002" in capsys.readouterr().out


def _plain_lag1_alpha(x, m):
    """The noise identification as first written (NumPy, one series at a time): the reference."""
    out = []
    for mm in m:
        y, d = x[mm::mm] - x[:-mm:mm], 0
        while True:
            z = y - y.mean()
            if len(z) < 30:
                out.append(out[-1] if out else 0)
                break
            r1 = np.dot(z[:-1], z[1:]) / np.dot(z, z)
            delta = r1 / (1 + r1)
            if delta < 0.25 or d >= 2:
                out.append(int(np.clip(-np.round(2 * delta) - 2 * d, -2, 2)))
                break
            y, d = np.diff(y), d + 1
    return np.array(out)


def test_blocked_kernels_match_plain_numpy(tmp_path):
    """The core's blocked sums (second differences; the noise identification's lag-1 sums) against
    the plain formulas: record lengths with every tail, all cluster sizes, several noise types."""
    rng = np.random.default_rng(11)
    for n in (10, 11, 12, 13, 1001, 200_003):
        x = np.cumsum(rng.normal(size=n))
        m = allan.cluster_sizes(n, "all" if n < 2000 else 20)
        plain = np.array([np.sum((x[2 * k:] - 2 * x[k:n - k] + x[:n - 2 * k]) ** 2) for k in m])
        assert np.allclose(allan._core.allan_second_difference_sums(x, m), plain, rtol=1e-12, atol=0)
    for y in (rng.normal(size=150_000), np.cumsum(rng.normal(size=150_000)),
              np.diff(rng.normal(size=150_001)), rng.normal(size=150_000) + np.cumsum(rng.normal(size=150_000)) / 20):
        x = allan.phase_from_rate(y, 0.01)
        assert np.array_equal(x, np.concatenate([[0.0], np.cumsum((y - y.mean()) * 0.01)]))
        m = allan.cluster_sizes(len(x), 20)
        assert np.array_equal(allan.noise_type_lag1(x, m), _plain_lag1_alpha(x, m))
    # A one-column NPY read into a buffer with a free element in front: the same samples, and the
    # phase made in place of them is the phase.
    from gpsins.imu import records

    y = rng.normal(size=5000)
    np.save(tmp_path / "y.npy", y)
    rec = records.load(tmp_path / "y.npy", 100.0, "gyro_x:deg/s", spare_front=True)
    assert rec.front is not None and np.array_equal(rec.rates[:, 0], y * (np.pi / 180))
    expected = allan.phase_from_rate(rec.rates[:, 0].copy(), 0.01)
    assert np.array_equal(allan.phase_from_rate(rec.rates[:, 0], 0.01, out=rec.front), expected)
