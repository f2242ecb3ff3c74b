"""The main job's chain on a short drive: emulated devices on real ptys, the real
logger daemon, replay, report; and replay of a damaged session."""

import json
import re

import matplotlib.pyplot as plt
import numpy as np
from figcheck import check_figure

from gpsins import mainjob, sim
from gpsins.report import page as report_page
from gpsins.report import figures as report_figures
from gpsins.replay import run
from gpsins.replay import results as results_mod
from gpsins.sim.messages import MEASUREMENT_DELAY_S
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session
from gpsins.formats.truth import write_truth

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
SHORT = [{"label": "stand", "duration_s": 8, "speed_mps": 0},
         {"label": "go", "duration_s": 6, "speed_mps": 8},
         {"label": "curve", "duration_s": 10, "turn_deg": 70},
         {"label": "on", "duration_s": 8, "speed_mps": 11}]


def test_drive_through_ptys_logger_replay_and_report(tmp_path):
    s = sim.simulate(parse({"name": "short", "start": START, "segment": SHORT}), seed=7)
    write_truth(s, tmp_path / "truth.npz")
    speed = 2.0
    session = mainjob.record_drive(s, tmp_path, speed=speed)
    outs = []
    for mode in ("loose", "tight"):
        res = run.replay(session, tmp_path / mode, mode=mode, gps_latency_s=MEASUREMENT_DELAY_S / speed + 5e-4)
        summary = json.loads((tmp_path / mode / "run.json").read_text())
        assert summary["counters"]["imu_samples"] == len(s.imu_t)
        assert summary["alignment"]["imu_frames_missing"] == 0
        assert summary["errors"]["inside_3_sigma"] >= 0.95, (mode, summary["errors"])
        outs.append(res.out)
    assert summary["counters"]["pseudoranges_used"] > 0  # the tight run used the logged pseudoranges
    summary = json.loads((tmp_path / "loose" / "run.json").read_text())
    e = summary["errors"]
    page = report_page.make_report(outs, tmp_path / "report")
    # What a reader relies on: every panel shows data from each mode it names (figure
    # content is tested in detail, against recomputed numbers, in test_report.py).
    figs = report_figures.build_figures(outs)
    for name, fig in figs.items():
        found = check_figure(name, fig)
        assert (tmp_path / "report" / name).exists()
        if name in ("trajectory.png", "position_error.png", "attitude.png", "sigma.png"):
            assert {m for _, m in found} == {"loose", "tight"}, name
        plt.close(fig)
    assert {"pseudorange.png", "clock.png", "visibility.png", "skyplot.png"} <= set(figs)
    assert (tmp_path / "report" / "report.html").read_text().count("data:image/png;base64,") == len(figs)
    # The summary's numbers are the results file's.
    z = results_mod.load(tmp_path / "loose")
    hk = z["heading_known"] & np.isfinite(z["err_ned_m"][:, 0])
    h = np.hypot(z["err_ned_m"][hk, 0], z["err_ned_m"][hk, 1])
    assert np.isclose(np.sqrt(np.mean(h ** 2)), e["horizontal_rms_m"])
    assert np.isclose(np.sqrt(np.mean(z["err_ned_m"][hk, 2] ** 2)), e["vertical_rms_m"])
    text = page.read_text()
    m = re.search(r"horizontal RMS ([0-9.]+) m", text)
    assert m and float(m.group(1)) == round(e["horizontal_rms_m"], 2)
    pos = (tmp_path / "loose" / "solution.pos").read_text().splitlines()
    assert pos[3].startswith("%  GPST") and len(pos) == 4 + len(z["t"])
    assert pos[4].startswith("2010/07/01 20:30:")


def test_a_damaged_session_still_replays_and_says_what_was_skipped(tmp_path):
    s = sim.simulate(parse({"name": "short", "start": START, "segment": SHORT}), seed=8)
    d = tmp_path / "session"
    write_session(s, d)
    rng = np.random.default_rng(0)
    for name, cut in (("imu-000.bin", 7), ("gps-000.bin", 30)):
        data = bytearray((d / name).read_bytes())
        for at in rng.integers(1000, len(data) - 1000, 5):
            data[at:at + 40] = rng.integers(0, 256, 40, dtype=np.uint8).tobytes()
        (d / name).write_bytes(bytes(data[:-cut]))
    res = run.replay(d, tmp_path / "out", gps_latency_s=MEASUREMENT_DELAY_S)
    sk = res.summary["skipped"]
    assert any("imu: bytes between frames" in k for k in sk) and any("gps: bytes between frames" in k for k in sk)
    assert any("imu: truncated" in k for k in sk) and any("gps: truncated" in k for k in sk)
    assert res.summary["alignment"]["imu_frames_missing"] > 0
    assert res.summary["counters"]["imu_gaps_bridged"] > 0
    assert res.summary["errors"]["inside_3_sigma"] > 0.9
