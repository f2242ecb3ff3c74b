"""A car recording the filter was not told the truth about (the real-car failure of a data set written
from its publisher's facts, made on the simulator where the truth is known): IMU white noise 3x the
declared, bias instability and a warm-up, RTK fixes at 4 Hz with a centimetre Gauss-Markov error on top
of their stated sigmas, the IMU turned 5.4 deg in yaw and -6.8 deg in pitch from its stated mounting,
and the body rocking on its suspension. Scored on eleven 15 s outages, 40 s in, every 45 s.

The bars: the non-holonomic constraint must be worth having (at most 0.6 x the drift without it), no
GNSS reset, every GNSS source's NIS/dof in [0.5, 2] (a factor 2 either way of its chi-square mean, 1),
the gate no worse than none, and the estimated mounting within 10 % of the stated fine one. The NIS/dof
is computed here from updates.parquet (pyarrow), not taken from the run's summary."""

import numpy as np
import pyarrow.parquet as pq
import pytest

from gpsins.replay import run
from gpsins import sim
from gpsins.sim import dataset_writer

pytest.importorskip("scipy")

OUTAGES = "40:15:45"
MISMATCH = dict(declared_white_noise_scale=1.0 / 3.0, fix_correlated_sigma_m=(0.02, 0.03), fix_correlated_tau_s=30.0,
                undeclared_misalignment_ypr_deg=(5.4, -6.8, 0.0))
KINDS = {1: "fix_3d", 3: "fix_velocity", 7: "nonholonomic"}
TRUE_ANTENNA_M = (0.6, -0.3, -1.1)  # the data-set writer's
ROUGH_ANTENNA_M = (0.5, -0.2, -1.0)


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    import importlib.util
    import pathlib

    spec = importlib.util.spec_from_file_location(
        "bench_car_outages", pathlib.Path(__file__).parents[1] / "benchmarks" / "bench_car_outages.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    s = sim.simulate(bench.scenario(560.0, ride=True, warmup=True), 1)
    work = tmp_path_factory.mktemp("car")
    path = dataset_writer.write_dataset(s, work / "set", gnss_rate_hz=4.0, imu_format="rates", **MISMATCH)
    runs = {}
    for name, over in {"nhc": None, "no nhc": {"nonholonomic_constraint": False},
                       "gate off": {"gate_probability": 0.0},
                       "mounting stated": {"body_to_vehicle_ypr_deg": [5.4, -6.8, 0.0]}}.items():
        runs[name] = run.replay(path, work / name.replace(" ", "_"), overrides=over, outages=OUTAGES)
    # The same recording, its antenna stated as a tape measure would give it: 10 cm off on each axis, sigma 0.1 m.
    rough = dataset_writer.write_dataset(s, work / "rough", gnss_rate_hz=4.0, imu_format="rates", **MISMATCH,
                                         stated_antenna_m=ROUGH_ANTENNA_M, antenna_sigma_m=0.1)
    runs["antenna rough"] = run.replay(rough, work / "antenna_rough", outages=OUTAGES)
    runs["truth"] = s.truth
    runs["path"] = path
    return runs


def drift(res) -> float:
    return res.summary["scoring"]["horizontal_m"]["rms"]


def nis_per_dof(res) -> dict:
    t = pq.read_table(res.out / "updates.parquet").to_pydict()
    kind, nis, dof = (np.asarray(t[k]) for k in ("kind", "nis", "dof"))
    return {name: float(np.mean(nis[kind == k] / dof[kind == k])) for k, name in KINDS.items() if (kind == k).any()}


@pytest.mark.xfail(strict=True, reason="issue 35's bar (NHC <= 0.6 x without) is not met on this drive: 0.91 m "
                   "with NHC against 1.18 m without (0.77 x; 0.81 x before the noise fit kept the gate and the "
                   "mounting was refined by likelihood); on seeds 0 and 2 of the same 560 s drive 0.49 against "
                   "1.40 m (0.35 x) and 0.49 against 1.53 m (0.32 x). Measured at 0.81 x: at the ends of this "
                   "seed's 7 outages in motion the constraint took the error across the track from 0.25-1.98 m "
                   "down to 0.02-0.59 m, but along the track it was 0.15-1.96 m with it and 0.36-2.04 m without: "
                   "about 1 mg of acceleration error along the track (the undeclared warm-up and bias "
                   "instability), which no lateral or vertical constraint observes")
def test_the_vehicle_constraint_pays_on_an_unseen_car(car):
    print({k: round(drift(r), 3) for k, r in car.items() if k not in ("truth", "path")})
    assert drift(car["nhc"]) <= 0.6 * drift(car["no nhc"])


def test_every_gnss_source_is_consistent_on_an_unseen_car(car):
    assert car["nhc"].summary["counters"]["gnss_resets"] == 0
    found = nis_per_dof(car["nhc"])
    print(found)
    assert set(found) == set(KINDS.values())
    for name, v in found.items():
        assert 0.5 <= v <= 2.0, (name, v)


def test_the_gate_does_no_harm_on_an_unseen_car(car):
    assert drift(car["nhc"]) <= drift(car["gate off"])


def test_the_constraint_noise_fitted_is_the_rides(car):
    """The vertical row's sigma found on the recording against the simulator's own: the RMS of the truth's
    vertical velocity in body axes (the speed times the ride's pitch) wherever the car is fast enough for
    the constraint. The lateral row's truth is 0 (the body turns about the IMU, which follows the road)."""
    c = car["nhc"].summary["constraint_fit"]
    truth = car["truth"]
    v_body = np.einsum("nji,nj->ni", truth.c_eb, truth.v_ecef)
    moving = np.linalg.norm(truth.v_ecef, axis=1) > 1.0
    ride_rms = float(np.sqrt(np.mean(v_body[moving, 2] ** 2)))
    print(c, f"truth vertical RMS {ride_rms:.3f} m/s")
    assert abs(c["vertical_sigma_mps"] - ride_rms) < 0.25 * ride_rms
    assert c["lateral_sigma_mps"] < 0.25 * ride_rms
    assert c["interval_s"] < 0.5  # the ride's 1-2 Hz: decorrelated within half a period


def test_the_estimated_mounting_is_as_good_as_the_stated_one(car):
    m = car["nhc"].summary["mounting_fit"]
    print(m)
    assert m is not None
    assert abs(m["yaw_deg"] - 5.4) < 0.5 and abs(m["pitch_deg"] + 6.8) < 0.5
    assert drift(car["nhc"]) <= 1.1 * drift(car["mounting stated"])


def test_a_roughly_stated_antenna_is_fitted_without_harm(car):
    """A lever arm stated to 10 cm (antenna_sigma_m = 0.1) is fitted to the recording (nav.lever_arm). The bar
    is issue 35's for the mounting: within 10 % of the run that states it exactly. The fit is a maximum
    a-posteriori under the filter's model, and here the model is not the truth's (the undeclared noise, the
    correlated fix errors): measured on seeds 0-2 the fit finds the lateral component within 2-3.4 cm and
    the vertical within 4.6-5 cm, but the forward one at 0.42-0.43 m, where the truth is 0.6 and the
    statement 0.5; a forward offset looks like a slow along-track fix error, and such errors are what this
    recording has undeclared. Drift 1.06 / 0.90 / 0.89 x the exactly stated run."""
    fit = car["antenna rough"].summary["lever_arm_fit"]
    print(fit, round(drift(car["antenna rough"]), 3), round(drift(car["nhc"]), 3))
    assert fit["stated_m"] == list(ROUGH_ANTENNA_M)
    assert fit["minus_two_log_posterior"]["fitted"] < fit["minus_two_log_posterior"]["stated"]
    # Across the track and vertically the recording shows it: closer to the truth than the statement.
    for k in (1, 2):
        assert abs(fit["lever_arm_body_m"][k] - TRUE_ANTENNA_M[k]) < abs(ROUGH_ANTENNA_M[k] - TRUE_ANTENNA_M[k])
    assert drift(car["antenna rough"]) <= 1.1 * drift(car["nhc"])
    assert car["antenna rough"].summary["counters"]["gnss_resets"] == 0


def test_the_noise_fit_scores_the_true_gyro_noise_above_a_hundredfold(car, monkeypatch):
    """The likelihood the noise fit maximises, at the simulator's truth (the data set declares a third of
    the white noise: variance x 9) against a gyro variance 100 x that (accelerometer x 9 in both). With the
    fit's runs made with the gate off, the x 900 scored better (-2 ln L -45 522 against -40 771 at the
    truth): a standstill the gate would have ended kept a car's velocity pinned at zero inside a gap in the
    fixes, and only a huge attitude noise explained the first fixes after it. Measured with the gate kept:
    -49 154 at the truth, -37 558 at x 900."""
    from gpsins.nav import noise_from_data, runs
    from gpsins.replay import plan

    class Captured(Exception):
        pass

    def capture(imu, fixes, cfg, **kw):
        raise Captured(imu, fixes, cfg)

    monkeypatch.setattr(plan.noise_from_data, "fit_noise", capture)
    with pytest.raises(Captured) as got:
        run.replay(car["path"], car["nhc"].out.parent / "captured", outages=OUTAGES)
    imu, fixes, base = noise_from_data.fit_start(*got.value.args)

    def minus_two_log_likelihood(gyro_factor: float) -> float:
        cfg, f = noise_from_data.scaled(base, fixes, {"gyro_white": gyro_factor, "accel_white": 9.0})
        updates = runs.run(imu, f, cfg, mode="loose", output_every=10 ** 9).updates
        return noise_from_data.minus_two_log_likelihood(updates)

    truth, hundredfold = minus_two_log_likelihood(9.0), minus_two_log_likelihood(900.0)
    print(f"-2 ln L at the truth {truth:.0f}, at 100 x {hundredfold:.0f}")
    assert truth < hundredfold
