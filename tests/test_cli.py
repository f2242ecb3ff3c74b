"""The command line as a person uses it: every expected failure is one line
`gpsins CMD: <file or key>: <what, and what to do>` on stderr with exit status 2,
never a traceback; `--debug` shows the traceback."""

import subprocess
import sys

import numpy as np
import pytest

from gpsins import cli, sim
from gpsins.session import logs
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 6 s standing session (enough for the readers; the filter is not needed here)."""
    d = tmp_path_factory.mktemp("cli") / "session"
    s = sim.simulate(parse({"name": "stand", "start": START, "segment": [{"label": "s", "duration_s": 6}]}), seed=1)
    write_session(s, d)
    return d


@pytest.fixture(scope="module")
def stepped_session(session, tmp_path_factory):
    """The same session with every GPS stamp frozen at the first one (a stuck clock): no map from
    system time to GPS time exists, so it cannot be aligned."""
    d = tmp_path_factory.mktemp("cli") / "stepped"
    d.mkdir()
    for f in session.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    data = bytearray((d / "gps-000.bin").read_bytes())
    first = scan.stamps[0]
    for start in scan.starts:
        at = int(start) + scan.layout.header_len
        data[at:at + 8] = np.float64(first).tobytes()
    (d / "gps-000.bin").write_bytes(bytes(data))
    return d


def _one_line(capsys, argv, *expect):
    rc = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2, (argv, rc, err)
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"gpsins {argv[0]}: "), lines[0]
    for text in expect:
        assert text in lines[0], (text, lines[0])
    return lines[0]


def test_missing_session(capsys, tmp_path):
    for cmd in (["replay", tmp_path / "nosuch", "--out", tmp_path / "o"], ["spp", tmp_path / "nosuch"],
                ["dump", tmp_path / "nosuch"]):
        _one_line(capsys, cmd, "nosuch: no such directory", "give a session directory")


def test_a_file_instead_of_the_session_directory(capsys, session, tmp_path):
    _one_line(capsys, ["replay", session / "gps-000.bin", "--out", tmp_path / "o"], "gps-000.bin: is a file")


def test_a_directory_that_is_not_a_session(capsys, tmp_path):
    _one_line(capsys, ["replay", tmp_path, "--out", tmp_path / "o"], "session.json: missing")


def test_allan_missing_and_empty_files(capsys, tmp_path):
    _one_line(capsys, ["allan", tmp_path / "missing.csv", "--rate", "64"], "missing.csv: no such file")
    (tmp_path / "empty.csv").write_text("")
    _one_line(capsys, ["allan", tmp_path / "empty.csv", "--rate", "64"], "empty.csv: no samples")
    (tmp_path / "words.csv").write_text("a,b\nc,d\n")
    _one_line(capsys, ["allan", tmp_path / "words.csv", "--rate", "64"], "words.csv: not a table of numbers")


@pytest.mark.parametrize("setting, expect", [
    ("no_such_key=1", "--set: unknown key no_such_key"),
    ("fix_uere=1", "did you mean fix_uere_2d_m, fix_uere_m?"),
    ("fix_uere_m=abc", "--set fix_uere_m: expected a number, got 'abc'"),
    ("fix_uere_m=-5", "--set fix_uere_m: must be positive"),
    ("position_sigma_m=-1", "--set position_sigma_m: must not be negative"),
    ("gate_probability=1.5", "--set gate_probability: 1.5 is outside [0, 1]"),
    ("zero_velocity_updates=1", "expected true or false"),
    ("pseudorange_decimation=2.5", "expected an integer"),
    ("lever_arm_body_m=[1, 2]", "expected one number or three"),
    ("imu_noise.gyro_arw=1e-3", "--set: unknown key imu_noise.gyro_arw (did you mean gyro_arw_rad_per_sqrt_s?)"),
    ("imu_noise.bias_tau_s=-3", "--set imu_noise.bias_tau_s: must be positive"),
    ("gyro_bias.model=white", "one of random_walk, gauss_markov, constant"),
    ("mode=loosely", "one of loose, tight"),
    ("fix_uere_m", "expected KEY=VALUE"),
])
def test_bad_set_values(capsys, session, tmp_path, setting, expect):
    _one_line(capsys, ["replay", session, "--out", tmp_path / "o", "--set", setting], expect)
    assert not (tmp_path / "o").exists()  # nothing written before the check


def test_unknown_key_points_at_the_list(capsys, session, tmp_path):
    line = _one_line(capsys, ["replay", session, "--out", tmp_path / "o", "--set", "no_such_key=1"])
    assert "--set help" in line and "default, report2005" in line


def test_set_help_lists_keys_nested_keys_and_presets(capsys, session, tmp_path):
    assert cli.main(["replay", str(session), "--out", str(tmp_path / "o"), "--set", "help"]) == 0
    out = capsys.readouterr().out
    assert "presets: default, report2005" in out
    assert "  fix_uere_m = 1.3" in out  # the default preset's value
    assert "  imu_noise.gyro_arw_rad_per_sqrt_s = [0.00088, 0.00087, 0.00081]" in out


def test_set_reaches_nested_keys_and_radians_replace_degrees():
    from gpsins.nav import config as nav_config

    cfg = nav_config.load_config(None, nav_config.parse_overrides(["imu_noise.gyro_arw_rad_per_sqrt_s=2e-3",
                                                                   "heading_sigma_rad=0.1",
                                                                   "lever_arm_body_m=[0.1, 0, -0.5]"]))
    assert cfg["imu_noise"]["gyro_arw_rad_per_sqrt_s"] == 2e-3
    assert cfg["imu_noise"]["bias_tau_s"] == 100.0  # the rest of the table stays
    assert "heading_sigma_deg" not in cfg  # the preset's degrees would otherwise win
    core = nav_config.core_config(cfg)
    assert np.allclose(core.gyro_arw_rad_per_sqrt_s, 2e-3) and core.heading_sigma_rad == 0.1
    assert np.allclose(core.lever_arm_body_m, [0.1, 0, -0.5])


def test_config_file_missing_or_broken(capsys, session, tmp_path):
    _one_line(capsys, ["replay", session, "--out", tmp_path / "o", "--config", "nosuch"],
              "nosuch: no such file; give a TOML file or a preset name (default, report2005)")
    bad = tmp_path / "bad.toml"
    bad.write_text("fix_uere_m = \n")
    _one_line(capsys, ["replay", session, "--out", tmp_path / "o", "--config", bad], "bad.toml: not valid TOML")
    bad.write_text("fix_uere_m = -1.0\n")
    _one_line(capsys, ["replay", session, "--out", tmp_path / "o", "--config", bad],
              "bad.toml: fix_uere_m: must be positive")


def test_alignment_error_names_the_session(capsys, stepped_session, tmp_path):
    _one_line(capsys, ["replay", stepped_session, "--out", tmp_path / "o"],
              f"{stepped_session}: ", "do not advance", "gpsins dump")


def test_debug_shows_the_traceback(stepped_session, tmp_path):
    from gpsins.timing import AlignmentError

    with pytest.raises(AlignmentError):
        cli.main(["replay", str(stepped_session), "--out", str(tmp_path / "o"), "--debug"])


def test_spp_without_epochs_fails(capsys, tmp_path):
    (tmp_path / "empty.bin").write_bytes(b"")
    _one_line(capsys, ["spp", "--raw", tmp_path / "empty.bin"], "empty.bin: no pseudorange epochs")


def test_spp_compares_with_the_truth_next_to_the_session(capsys, session):
    from gpsins.gnss import spp

    assert cli.main(["spp", str(session)]) == 0
    out = capsys.readouterr().out
    assert "vs the simulator's truth: horizontal RMS" in out
    # The same figure from the truth file directly: truth interpolated to the solved epochs.
    run = spp.solve(spp.from_session(session))
    z = np.load(session / "truth.npz")
    t_truth = z["tow_s"] + int(z["gps_week"]) * 604800.0
    t = run.t_abs[run.ok]
    inside = (t >= t_truth[0]) & (t <= t_truth[-1])  # no truth before the first truth epoch
    t = t[inside]
    ref = np.column_stack([np.interp(t, t_truth, z["r_ecef"][:, i]) for i in range(3)])
    lat, lon = np.radians(START["lat_deg"]), np.radians(START["lon_deg"])
    north = np.array([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    d = run.r_ecef[run.ok][inside] - ref
    expect = np.sqrt(np.mean((d @ north) ** 2 + (d @ east) ** 2))
    got = float(out.split("vs the simulator's truth: horizontal RMS ")[1].split(" m")[0])
    assert abs(got - expect) < 2e-3


def test_report_on_a_missing_results_directory(capsys, tmp_path):
    _one_line(capsys, ["report", tmp_path / "nope"],
              "nope: no solution.parquet, results.npz and run.json; give a directory written by")


def test_calibrate_missing_table(capsys, tmp_path):
    _one_line(capsys, ["calibrate", "accel-updown", tmp_path / "t.csv"], "t.csv: no such file")


def test_dump_explains_stamps_going_backwards(capsys, session, tmp_path):
    d = tmp_path / "back"
    d.mkdir()
    for f in session.iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    data = bytearray((d / "gps-000.bin").read_bytes())
    for start in scan.starts[5:]:  # the clock stepped back by 0.5 s before record 5
        at = int(start) + scan.layout.header_len
        earlier = np.frombuffer(bytes(data[at:at + 8]), "<f8")[0] - 0.5
        data[at:at + 8] = np.float64(earlier).tobytes()
    (d / "gps-000.bin").write_bytes(bytes(data))
    assert cli.main(["dump", str(d)]) == 0
    out = capsys.readouterr().out
    assert "stamps backwards 1 (records stamped earlier than the one before: the system clock was stepped back" in out


def _run(*argv, **kw):
    return subprocess.run([sys.executable, "-m", "gpsins.cli", *map(str, argv)], capture_output=True, text=True,
                          timeout=120, **kw)


def test_as_a_process_one_line_and_status_2(tmp_path):
    p = _run("replay", tmp_path / "nosuch", "--out", tmp_path / "o")
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "Traceback" not in p.stderr, p.stderr


def test_output_into_a_closed_pipe_is_quiet(session):
    # `gpsins dump --csv SESSION | head -1`: the reader leaves after one line.
    p = subprocess.Popen([sys.executable, "-m", "gpsins.cli", "dump", str(session), "--csv"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0 and err == "", err


def test_log_forwards_to_the_logger_parser(tmp_path):
    p = _run("log", "--help")
    assert p.returncode == 0 and "--config" in p.stdout and "--session-dir" in p.stdout
    p = _run("log", "--config", tmp_path / "nosuch.toml")
    assert p.returncode == 2 and "nosuch.toml" in p.stderr and "Traceback" not in p.stderr
    cfg = tmp_path / "logger.toml"  # read by the daemon: it checks the ports
    cfg.write_text(f'[session]\nroot = "{tmp_path}"\n[gps]\nport = "{tmp_path / "nodev"}"\n'
                   f'[imu]\nport = "{tmp_path}"\n')
    p = _run("log", "--config", cfg)
    assert p.returncode == 2 and "gps.port" in p.stderr and "nodev" in p.stderr, p.stderr


@pytest.mark.parametrize("speed", ["0", "-2", "1000"])
def test_the_main_job_refuses_a_speed_it_cannot_serve(capsys, tmp_path, speed):
    """Before: a ZeroDivisionError traceback (0), "no GPS records" (-2), "no IMU records" (1000)."""
    _one_line(capsys, ["run", "--speed", speed, "--out", tmp_path / "o"], "--speed", "times real time")
    assert not (tmp_path / "o" / "session").exists()


def test_the_main_job_reruns_into_the_same_out(tmp_path):
    """Before: "out/session exists; give another --out" (exit 2) on the second run."""
    drive = tmp_path / "short.toml"
    drive.write_text('name = "short"\ndescription = "20 s"\n[start]\ngps_week = 1590\ngps_tow_s = 419400.0\n'
                     'lat_deg = 59.37\nlon_deg = 17.95\nheight_m = 30.0\nheading_deg = 160.0\n'
                     '[[segment]]\nlabel = "stand"\nduration_s = 12\nspeed_mps = 0\n'
                     '[[segment]]\nlabel = "go"\nduration_s = 10\nspeed_mps = 5\n')
    argv = ["run", "--scenario", drive, "--speed", "8", "--out", tmp_path / "o"]
    assert cli.main([str(a) for a in argv]) == 0
    assert cli.main([str(a) for a in argv]) == 0
    assert (tmp_path / "o" / "session").is_dir() and (tmp_path / "o" / "session-2").is_dir()
    assert "session-2" in (tmp_path / "o" / "run.json").read_text()
    # gpsins live navigated beside the logger during the drive (issue 39): its solution is there.
    from gpsins.live import outputs

    assert len(outputs.read_epochs(tmp_path / "o" / "live" / "live.f64")["t"]) > 500


def test_set_help_on_a_data_set_shows_the_values_it_runs_with(capsys):
    """Before: the preset's values. The facts-only walk runs as a hand-held device with the generic MEMS
    priors (dataset.GENERIC_MEMS), which the default preset does not hold."""
    from pathlib import Path

    from gpsins.dataset import load

    walk = Path(__file__).parent / "data" / "walk_0827" / "walk_0827_facts.toml"
    assert cli.main(["replay", str(walk), "--out", "unused", "--set", "help"]) == 0
    out = capsys.readouterr().out
    assert "platform = handheld" in out
    want = load.GENERIC_MEMS["gyro_bias_residual_rad_per_s"]
    assert f"gyro_bias_residual_rad_per_s = {want}" in out
    assert cli.main(["replay", "x", "--out", "unused", "--set", "help"]) == 0
    assert f"gyro_bias_residual_rad_per_s = {want}" not in capsys.readouterr().out


def test_a_full_disk_during_replay_is_one_line_and_leaves_nothing_partial(capsys, tmp_path, monkeypatch):
    """Before: the input's name, a pyarrow traceback at exit, and the partial files left behind."""
    import errno as errno_mod
    import gc
    from pathlib import Path

    from gpsins.replay import solution

    def full(self, *a, **k):
        raise OSError(errno_mod.ENOSPC, "No space left on device")

    monkeypatch.setattr(solution.PosWriter, "add", full)
    walk = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"
    out = tmp_path / "o"
    rc = cli.main(["replay", str(walk), "--out", str(out)])
    gc.collect()  # the failed run's writers are collected: nothing may print then
    err = capsys.readouterr().err
    assert rc == 2 and err.strip() == f"gpsins replay: {out}: no space left on the device", err
    assert not out.exists()
