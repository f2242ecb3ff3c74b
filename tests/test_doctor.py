"""The data-set doctor against the mistakes a person makes with their own recording (issue 41):
each one made on the walk's data set (or a simulated car's), refused or warned about, with what
was measured; the data sets as shipped pass with no warning."""

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from gpsins import cli
from gpsins.dataset import load as dataset, doctor
from gpsins.replay import run
from gpsins.replay import inputs as replay_inputs
from gpsins.sim import dataset_writer, simulate
from gpsins.sim.scenario import load

WALK = Path(__file__).parent / "data" / "walk_0827"


def walk_variant(tmp_path, edit=lambda s: s):
    for f in WALK.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    p = tmp_path / "walk_0827.toml"
    p.write_text(edit(p.read_text()))
    return p


def findings(path, modes=("loose",)):
    return {f.check: f for f in doctor.diagnose(dataset.load(path), modes).findings}


def test_the_walk_as_shipped_passes_with_no_warning():
    for name in ("walk_0827.toml", "walk_0827_ubx.toml", "walk_0827_facts.toml"):
        bad = [f.line() for f in findings(WALK / name).values() if f.level in ("warning", "error")]
        assert not bad, (name, bad)


@pytest.mark.parametrize("edit,check,says", [
    (lambda s: s.replace('gyro_unit = "rad/s"', 'gyro_unit = "deg/s"'), "heading", "rad/s declared as deg/s"),
    (lambda s: s.replace('accel_unit = "g"', 'accel_unit = "m/s^2"'), "accelerometer", "g declared as m/s^2"),
    (lambda s: s.replace('time = "gpst_unix"', 'time = "utc_unix"'), "time offset", "UTC against GPS time"),
    (lambda s: s.replace("time_offset_s = 0.0", "time_offset_s = 604800.0"), "spans", "do not overlap"),
    (lambda s: s.replace("[-90.0, 0.0, 180.0]", "[-90.0, 0.0, 0.0]"), "mounting", "check imu_to_body"),
    (lambda s: s.replace('outages = "25:15:45:45"', 'outages = "400:15:45"'), "outages", "0 outage"),
], ids=["gyro deg/s on rad/s", "accel m/s^2 on g", "GPS time declared UTC", "another week", "upside down",
        "outages after the end"])
def test_a_mistake_is_refused_with_what_was_measured(tmp_path, edit, check, says):
    p = walk_variant(tmp_path, edit)
    f = findings(p)[check]
    print(f.line())
    assert f.level == "error" and says in f.text
    with pytest.raises(dataset.DatasetError, match="contradict the declaration"):
        replay_inputs.load_inputs(p)
    assert cli.main(["check", str(p)]) == 2


def test_utc_declared_for_gps_time_is_measured_as_18_s(tmp_path):
    """The IMU's times moved by the 18 leap seconds of 2025: the lag found is those 18 s."""
    p = walk_variant(tmp_path, lambda s: s.replace('time = "gpst_unix"', 'time = "utc_unix"'))
    text = findings(p)["time offset"].text
    lag = float(re.search(r"matches the course rate ([0-9.]+) s", text).group(1))
    assert abs(lag - 18.0) < 1.0, text


def test_tight_without_pseudoranges_is_refused_and_force_replays(tmp_path):
    p = walk_variant(tmp_path)
    assert findings(p, ("tight",))["mode"].level == "error"
    assert cli.main(["replay", str(p), "--mode", "tight", "--out", str(tmp_path / "o")]) == 2
    # --force: a person who knows better gets the replay, and run.json keeps what the doctor said.
    res = run.replay(WALK / "walk_0827.toml", tmp_path / "forced", force=True, mode="loose")
    assert [f["level"] for f in res.summary["doctor"]].count("error") == 0


def test_outages_given_outside_the_data_are_refused(tmp_path):
    p = walk_variant(tmp_path)
    assert cli.main(["replay", str(p), "--outages", "1000:15:45", "--out", str(tmp_path / "o")]) == 2


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """The default drive as a car data set: 5 Hz fixes with velocities, antenna 1.2 m ahead."""
    s = simulate(load("default"), seed=3)
    d = tmp_path_factory.mktemp("car")
    return dataset_writer.write_dataset(s, d, imu_to_body_ypr_deg=[1.0, 2.0, 90.0], antenna_m=[1.2, 0.1, -1.0],
                                        imu_time_offset_s=0.1, imu_format="rates", vehicle_kind="car")


def test_a_simulated_car_as_written_passes_with_no_warning(car):
    bad = [f.line() for f in findings(car).values() if f.level in ("warning", "error")]
    assert not bad, bad


def test_a_car_imu_offset_left_out_is_found(car):
    """The writer stamps the IMU 0.1 s early and declares it; left out, the doctor must see it and
    say what to declare. Bar: within half the 50 ms it reports from (so a 50 ms offset is seen)."""
    p = car.with_name("no_offset.toml")
    p.write_text(re.sub(r"time_offset_s = .*", "time_offset_s = 0.0", car.read_text()))
    f = findings(p)["time offset"]
    print(f.line())
    suggested = float(re.search(r"time_offset_s about ([-+0-9.]+)", f.text).group(1))
    assert f.level == "warning" and abs(suggested - 0.1) < 0.025


def test_the_template_for_the_walks_files_guesses_what_the_shipped_data_set_declares(tmp_path):
    """`gpsins dataset init` on the walk's two files: its columns, units, time scale and format are the
    ones written by hand in walk_0827.toml; with only the mounting set it passes the doctor and replays."""
    import tomllib

    for f in ("imu_1730_sf.csv", "gnss_1730_sf.pos"):
        shutil.copy(WALK / f, tmp_path / f)
    out = tmp_path / "mine.toml"
    assert cli.main(["dataset", "init", str(tmp_path / "imu_1730_sf.csv"), str(tmp_path / "gnss_1730_sf.pos"),
                     "--out", str(out)]) == 0
    mine, shipped = tomllib.loads(out.read_text()), tomllib.loads((WALK / "walk_0827.toml").read_text())
    for key in ("format", "columns", "time", "accel_unit", "gyro_unit"):
        assert mine["imu"][key] == shipped["imu"][key], key
    assert mine["gnss"]["format"] == shipped["gnss"]["format"]
    assert cli.main(["dataset", "init", str(tmp_path / "imu_1730_sf.csv"), str(tmp_path / "gnss_1730_sf.pos"),
                     "--out", str(out)]) == 2  # not over an existing file without --force
    out.write_text(out.read_text().replace("imu_to_body_ypr_deg = [0.0, 0.0, 0.0]",
                                           "imu_to_body_ypr_deg = [-90.0, 0.0, 180.0]"))
    assert not doctor.diagnose(dataset.load(out)).errors()
    res = run.replay(out, tmp_path / "r", outages="25:15:45:45")
    assert res.summary["imu_samples"] == 20454


def test_the_template_reads_another_layout(tmp_path):
    """The walk's IMU rewritten as a person's own logger might: a header line, whitespace, seconds of
    week, m/s^2 and deg/s, the gyro first."""
    a = np.loadtxt(WALK / "imu_1730_sf.csv", delimiter=",")[:, :7]
    sow = a[:, 0] - 315964800.0 - 2381 * 604800.0  # GPS time in Unix seconds -> seconds of week 2381
    table = np.column_stack([sow, np.degrees(a[:, 4:7]), a[:, 1:4] * 9.80665])
    f = tmp_path / "own.txt"
    np.savetxt(f, table, fmt="%.6f", header="sow gx gy gz ax ay az", comments="")
    shutil.copy(WALK / "gnss_1730_sf.pos", tmp_path / "gnss_1730_sf.pos")
    out = tmp_path / "own.toml"
    assert cli.main(["dataset", "init", str(f), str(tmp_path / "gnss_1730_sf.pos"), "--out", str(out)]) == 0
    import tomllib

    imu = tomllib.loads(out.read_text())["imu"]
    assert imu["columns"] == ["t", "gx", "gy", "gz", "ax", "ay", "az"]
    assert (imu["time"], imu["week"], imu["accel_unit"], imu["gyro_unit"], imu["skip_rows"]) == \
        ("gps_sow", 2381, "m/s^2", "deg/s", 1)
    out.write_text(out.read_text().replace("imu_to_body_ypr_deg = [0.0, 0.0, 0.0]",
                                           "imu_to_body_ypr_deg = [-90.0, 0.0, 180.0]"))
    assert not doctor.diagnose(dataset.load(out)).errors()


def test_a_reference_from_another_time_is_refused(tmp_path):
    """Before: tables of nan. The walk's own .pos, its times moved a week on, as --reference."""
    lines = (WALK / "gnss_1730_sf.pos").read_text().splitlines(keepends=True)
    moved = []
    for x in lines:
        if x.startswith("%") or not x.strip():
            moved.append(x)
            continue
        day = np.datetime64(x[:10].replace("/", "-")) + np.timedelta64(7, "D")
        moved.append(str(day).replace("-", "/") + x[10:])
    ref = tmp_path / "later.pos"
    ref.write_text("".join(moved))
    assert cli.main(["replay", str(WALK / "walk_0827.toml"), "--reference", str(ref), "--out",
                     str(tmp_path / "o")]) == 2
