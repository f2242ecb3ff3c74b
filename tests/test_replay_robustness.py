"""Sessions off the clean path: every one aligns to the simulator's true sampling times
and replays. Faults are put into simulated sessions the way they happen: the stamp model's
host stalls and clock steps, or the record files edited afterwards (a flipped stamp bit,
frames lost while the IMU was unplugged, ID 23 missing for a stretch, a recording served
faster than real time)."""

import shutil
import struct

import numpy as np
import pytest
from gpsins_logger import superstar2 as ss2

from gpsins import cli, sim, timing
from gpsins.timing import alignment
from gpsins.session import logs, measurements
from gpsins.session import layouts
from gpsins.replay import run as replay
from gpsins.replay import results as results_mod
from gpsins.sim import messages
from gpsins.sim.scenario import parse
from gpsins.sim.session import STAMP, realtime, write_session
from gpsins.formats.truth import load_truth

from test_timing import GPS_LAT, IMU_LAT, SEGMENTS, START

DEVICES = {"gps": "superstar2", "imu": "bp3010"}


def simulate(tmp_path, name, segments=SEGMENTS, obstructions=(), **timing_opts):
    sc = parse({"name": name, "start": START, "segment": segments, "obstruction": list(obstructions),
                "timing": {"gps_latency_s": GPS_LAT, "imu_latency_s": IMU_LAT, **timing_opts}})
    s = sim.simulate(sc, seed=5)
    d = tmp_path / name
    write_session(s, d)
    return s, d


def sample_index(d):
    """True sample index of every IMU record of an unedited simulated session, from its counter
    alone (the simulator drops single frames only, and its counter counts every sample)."""
    c = measurements.decode_session(d).imu.counter.astype(int)
    step = np.diff(c) % 256
    step[step == 0] = 256
    return (c[0] - 1) + np.concatenate([[0], np.cumsum(step)])


def rewrite(d, sensor, keep=None, stamps=None):
    """Write a record file again, keeping the records in `keep` with the given stamps."""
    scan = logs.read_record_file(d / f"{sensor}-000.bin", DEVICES[sensor])
    h = scan.layout.header_len
    stamps = scan.stamps if stamps is None else stamps
    keep = np.ones(scan.count, bool) if keep is None else keep
    out = []
    for k in np.flatnonzero(keep):
        raw = scan.record(k)
        out.append(raw[:h] + STAMP.pack(stamps[k]) + raw[h + layouts.STAMP_BYTES:])
    (d / f"{sensor}-000.bin").write_bytes(b"".join(out))


def stamps_of(d, sensor):
    return logs.read_record_file(d / f"{sensor}-000.bin", DEVICES[sensor]).stamps


def flip_bit(x: float, bit: int) -> float:
    (u,) = struct.unpack("<Q", struct.pack("<d", x))
    return struct.unpack("<d", struct.pack("<Q", u ^ (1 << bit)))[0]


def align_errors(s, d, k_true, speed=1.0):
    dec = measurements.decode_session(d)
    al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, s.imu_rate_hz,
                         gps_latency_s=(GPS_LAT + messages.MEASUREMENT_DELAY_S) / speed, imu_latency_s=IMU_LAT / speed)
    return al, al.imu_t - (s.scenario.start.gps_tow_s + s.imu_t[k_true])


def check(al, err, label):
    rms, worst = float(np.sqrt(np.mean(err ** 2))), float(np.abs(err).max())
    print(f"{label}: IMU time error RMS {1e3 * rms:.3f} ms, max {1e3 * worst:.3f} ms; steps {al.steps_s}; "
          f"warnings {getattr(al, 'warnings', None)}")
    assert rms < 1e-3 and worst < 5e-3


@pytest.mark.parametrize("step_s", [4.0, -8.0, -30.0])
def test_clock_step_of_whole_counter_periods(tmp_path, step_s):
    """4 s is 256 frames at 64 Hz: in the IMU stamps alone the step looks like a gap."""
    s, d = simulate(tmp_path, "step", jitter_mean_s=0.0005, clock_step_at_s=27.3, clock_step_s=step_s)
    al, err = align_errors(s, d, sample_index(d))
    check(al, err, f"step {step_s:+g} s")
    assert len(al.steps_s) == 1 and abs(al.steps_s[0] - step_s) < 2e-3
    assert al.summary()["imu_frames_missing"] == 0


@pytest.mark.parametrize("sensor,bit", [("gps", 20), ("gps", 48), ("imu", 20), ("imu", 30), ("imu", 51)])
def test_one_flipped_stamp_bit(tmp_path, sensor, bit):
    """One bit of one stamp: -0.25 s (bit 20), -6.7e7 s (48), +256 s (30), +5.4e8 s (51);
    all inside the reader's plausible range, so alignment must cope."""
    s, d = simulate(tmp_path, "flip", jitter_mean_s=0.0005)
    st = stamps_of(d, sensor).copy()
    i = len(st) // 2 + 3
    st[i] = flip_bit(st[i], bit)
    assert layouts.STAMP_MIN < st[i] < layouts.STAMP_MAX
    rewrite(d, sensor, stamps=st)
    # The reader may drop the damaged IMU record: the counter still numbers the others.
    al, err = align_errors(s, d, sample_index(d))
    check(al, err, f"{sensor} stamp bit {bit}")
    # Caught once: by the reader (a record with an impossible stamp) or by the alignment (a damaged stamp).
    dec = measurements.decode_session(d)
    by_reader = dec.skipped.get(f"{sensor}: records with impossible stamps (their bytes are counted above)", 0)
    by_alignment = sum(f"{sensor.upper()} stamp" in w and "damaged" in w for w in al.warnings)
    assert by_reader + by_alignment == 1, (by_reader, al.warnings)
    assert al.summary()["imu_frames_missing"] == (by_reader if sensor == "imu" else 0)


@pytest.mark.parametrize("jitter_s", [0.0, 0.03])
def test_loaded_host_heavy_tailed_stamp_delays(tmp_path, jitter_s):
    """Host stalls (about one a second, Pareto lengths with mean 0.3 s) on top of plain jitter."""
    s, d = simulate(tmp_path, "load", jitter_mean_s=jitter_s, load_stall_rate_hz=1.0, load_stall_mean_s=0.3,
                    imu_clock_ppm=40.0, imu_drop_probability=0.01)
    al, err = align_errors(s, d, sample_index(d))
    delay = al.imu_residual_s
    print(f"IMU stamp delays: median {1e3 * np.median(delay):.1f} ms, p99 {1e3 * np.percentile(delay, 99):.0f} ms, "
          f"max {1e3 * delay.max():.0f} ms")
    assert delay.max() > 0.3  # the tail is there
    check(al, err, f"loaded host, jitter {jitter_s}")
    # 60 s of stamps with 30 ms jitter pin the drift to about 10 ppm (0.6 ms over the run).
    assert al.steps_s == [] and abs(al.imu_clock_ppm - 40.0) < (2.0 if jitter_s == 0 else 15.0)


@pytest.mark.parametrize("speed", [2.0, 4.0])
def test_recording_served_faster_than_real_time(tmp_path, speed):
    """Served at `speed` x real time, system time runs at 1/speed of GPS time."""
    s, d = simulate(tmp_path, "fast", jitter_mean_s=0.0005, clock_step_at_s=31.0, clock_step_s=0.5)
    k = sample_index(d)
    t0 = realtime(s, 0.0)
    for sensor in DEVICES:
        st = stamps_of(d, sensor)
        rewrite(d, sensor, stamps=t0 + (st - t0) / speed)
    al, err = align_errors(s, d, k, speed)
    check(al, err, f"served at {speed:g}x")
    assert len(al.steps_s) == 1 and abs(al.steps_s[0] - 0.5 / speed) < 1e-3


@pytest.mark.parametrize("speed,step_s", [(1.0, -2.0), (2.0, -2.0), (1.0, 0.3), (1.0, 4.0)])
def test_missing_id23_for_a_stretch(tmp_path, speed, step_s):
    """13 s without ID 23 (say a damaged stretch of the file), with a clock step inside it: the
    GPS stream only brackets the step within those 13 s; the IMU stream must place it. Served
    at 2x the stretch is 6.5 s of system time against 13 s of GPS time."""
    s, d = simulate(tmp_path, "noid23", jitter_mean_s=0.0005, clock_step_at_s=28.0, clock_step_s=step_s)
    k = sample_index(d)
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    t0 = realtime(s, 0.0)
    gone = (layouts.message_ids(scan) == 23) & (scan.stamps > t0 + 20) & (scan.stamps < t0 + 33)
    rewrite(d, "gps", keep=~gone)
    for sensor in DEVICES:
        rewrite(d, sensor, stamps=t0 + (stamps_of(d, sensor) - t0) / speed)
    al, err = align_errors(s, d, k, speed)
    check(al, err, f"no ID 23 for 13 s, step {step_s:+g} s, served at {speed:g}x")
    assert len(al.steps_s) == 1 and abs(al.steps_s[0] - step_s / speed) < 2e-3


UNPLUG_SEGMENTS = [{"label": "stand", "duration_s": 30, "speed_mps": 0},
                   {"label": "drive", "duration_s": 60, "speed_mps": 10, "turn_deg": 90}]


def unplugged(tmp_path, name, t_from, t_to, **opts):
    s, d = simulate(tmp_path, name, UNPLUG_SEGMENTS, **opts)
    k = sample_index(d)
    keep = ~((s.imu_t[k] > t_from) & (s.imu_t[k] < t_to))
    rewrite(d, "imu", keep=keep)
    return s, d, k[keep]


@pytest.mark.parametrize("step_s", [None, -30.0])
def test_imu_unplugged_for_8_s_time_map(tmp_path, step_s):
    """The counter wraps twice in the gap; the stamps say how often. With a -30 s clock step
    during the gap as well."""
    opts = {"clock_step_at_s": 54.0, "clock_step_s": step_s} if step_s else {}
    s, d, k = unplugged(tmp_path, "unplug", 50.0, 58.0, jitter_mean_s=0.0005, **opts)
    al, err = align_errors(s, d, k)
    check(al, err, f"IMU unplugged 8 s, step {step_s}")
    long = al.gap_list(1.0)
    assert len(long) == 1 and long[0]["frames_missing"] == int(np.diff(k).max()) - 1
    assert al.pieces == 2


def test_imu_unplugged_for_8_s_replays_inside_3_sigma(tmp_path):
    s, d, _ = unplugged(tmp_path, "unplug", 50.0, 58.0)
    res = replay.replay(d, tmp_path / "out")
    gaps = res.summary["imu_gaps_longer_than_max_gap"]
    assert len(gaps) == 1 and abs(gaps[0]["t_after"] - gaps[0]["t_before"] - 8.0) < 0.05
    z = results_mod.load(tmp_path / "out")
    after = (z["t"] > gaps[0]["t_after"]) & z["heading_known"] & np.isfinite(z["err_ned_m"][:, 0])
    assert after.sum() > 20 * s.imu_rate_hz
    inside = np.abs(z["err_ned_m"][after]) <= 3 * z["sigma_ned_m"][after]
    print(f"after the gap: {after.sum()} samples, inside 3 sigma {inside.mean(axis=0)}, "
          f"max |error| {np.abs(z['err_ned_m'][after]).max(axis=0)} m, run.json {res.summary['reinitialisations']}")
    assert inside.all()


def test_fixes_pair_with_their_id20_by_gps_time_after_a_backward_step(tmp_path):
    """After a -30 s step, an ID 21's stamp is nearest to an ID 20 sent 30 s earlier."""
    obstruction = {"t0_s": 5, "t1_s": 60, "azimuth_deg": [0, 180], "below_elevation_deg": 40, "flicker": 0.3}
    segments = [{"label": "stand", "duration_s": 20, "speed_mps": 0},
                {"label": "drive", "duration_s": 60, "speed_mps": 10, "turn_deg": 90}]
    s, d = simulate(tmp_path, "pair", segments, [obstruction], clock_step_at_s=45.3, clock_step_s=-30.0)
    tr = load_truth(d / "truth.npz")
    assert len(np.unique(tr["fix_sats"])) > 2  # the pairing is visible in the data
    gps = measurements.decode_session(d).gps
    k = np.searchsorted(tr["fix_t"] + START["gps_tow_s"], gps.fixes[:, 0] - 1e-3)
    assert len(gps.fixes) == len(tr["fix_t"])
    assert np.array_equal(gps.fix_sats, tr["fix_sats"][k])
    assert np.allclose(gps.fixes[:, 7], np.maximum(tr["fix_hdop"][k], 0.1), atol=0.051)


def test_everything_at_once(tmp_path):
    """Heavy jitter, host stalls, drops, IMU clock drift, a backward step of a counter period,
    13 s without ID 23, one damaged stamp in each stream and a configured IMU rate 30 % high."""
    s, d = simulate(tmp_path, "mixed", jitter_mean_s=0.03, load_stall_rate_hz=1.0, load_stall_mean_s=0.3,
                    imu_drop_probability=0.01, imu_clock_ppm=50.0, clock_step_at_s=33.3, clock_step_s=-4.0)
    t0 = realtime(s, 0.0)
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    gone = (layouts.message_ids(scan) == 23) & (scan.stamps > t0 + 10) & (scan.stamps < t0 + 23)
    st = scan.stamps.copy()
    st[400] = flip_bit(st[400], 21)
    rewrite(d, "gps", keep=~gone, stamps=st)
    st = stamps_of(d, "imu").copy()
    st[2000] = flip_bit(st[2000], 44)
    rewrite(d, "imu", stamps=st)
    k = sample_index(d)  # the reader may drop the damaged record
    dec = measurements.decode_session(d)
    al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter,
                         1.3 * s.imu_rate_hz, gps_latency_s=GPS_LAT + messages.MEASUREMENT_DELAY_S,
                         imu_latency_s=IMU_LAT)
    check(al, al.imu_t - (s.scenario.start.gps_tow_s + s.imu_t[k]), "everything at once")
    assert len(al.steps_s) == 1 and abs(al.steps_s[0] + 4.0) < 5e-3
    dropped_by_reader = dec.skipped.get("imu: records with impossible stamps (their bytes are counted above)", 0)
    assert al.summary()["imu_frames_missing"] == \
        dec.sidecar["counts"]["imu"]["frames_dropped_by_simulation"] + dropped_by_reader
    assert any("not the configured" in w for w in al.warnings)


def test_a_session_that_cannot_be_aligned_says_why(tmp_path):
    s, d = simulate(tmp_path, "bad", jitter_mean_s=0.0005)
    dec = measurements.decode_session(d)
    with pytest.raises(timing.AlignmentError, match="at least 3 GPS measurement blocks"):
        alignment.align(dec.gps.tow[:2], dec.gps.stamps[:2], dec.gps.week, dec.imu.stamps, dec.imu.counter, 64)
    with pytest.raises(timing.AlignmentError, match="do not advance with GPS time"):
        alignment.align(dec.gps.tow, np.full(len(dec.gps.tow), dec.gps.stamps[0]), dec.gps.week, dec.imu.stamps,
                        dec.imu.counter, 64)


def test_400_hz_counter_wraps_every_0_64_s(tmp_path):
    """At 400 Hz the counter's period (0.64 s) is shorter than a host stall: stalls, drops, an 8 s
    unplug and a backward step of two counter periods."""
    sc = parse({"name": "fast_imu", "start": START, "segment": SEGMENTS, "imu": {"rate_hz": 400},
                "timing": {"gps_latency_s": GPS_LAT, "imu_latency_s": IMU_LAT, "jitter_mean_s": 0.002,
                           "load_stall_rate_hz": 1.0, "load_stall_mean_s": 0.3, "imu_drop_probability": 0.01,
                           "clock_step_at_s": 27.3, "clock_step_s": -1.28, "imu_baud": 115200}})
    s = sim.simulate(sc, seed=5)
    write_session(s, tmp_path / "fast_imu")
    d = tmp_path / "fast_imu"
    k = sample_index(d)
    keep = ~((s.imu_t[k] > 40.0) & (s.imu_t[k] < 48.0))
    rewrite(d, "imu", keep=keep)
    al, err = align_errors(s, d, k[keep])
    check(al, err, "400 Hz")
    assert len(al.steps_s) == 1 and abs(al.steps_s[0] + 1.28) < 2e-3
    assert al.summary()["imu_frames_missing"] == int(np.sum(np.diff(k[keep]) - 1))


def damage_one_tow(d, change):
    """One ID 23 in the middle gets another time of week, its checksum made good again (as a
    multi-bit flip can leave it: the frame finder accepts it)."""
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    blocks = np.flatnonzero(layouts.message_ids(scan) == 23)
    i = int(blocks[len(blocks) // 2])
    out = []
    for k in range(scan.count):
        raw = scan.record(k)
        if k == i:
            m = ss2.Measurements.decode(scan.frame(k)[ss2.HEADER_LEN:-2])
            m.tow_s = change(m.tow_s)
            frame = m.encode()
            raw = frame[:ss2.HEADER_LEN] + STAMP.pack(scan.stamps[k]) + frame[ss2.HEADER_LEN:]
        out.append(raw)
    (d / "gps-000.bin").write_bytes(b"".join(out))


@pytest.fixture(scope="module")
def clean_drive(tmp_path_factory):
    """A drive with ephemerides and its replays in both modes, undamaged."""
    tmp = tmp_path_factory.mktemp("clean")
    s, d = simulate(tmp, "clean", [{"label": "stand", "duration_s": 20, "speed_mps": 0},
                                   {"label": "drive", "duration_s": 70, "speed_mps": 10, "turn_deg": 90}],
                    jitter_mean_s=0.0005)
    scores = {m: replay.replay(d, tmp / f"out_{m}", mode=m).summary["scoring"]["all"] for m in ("loose", "tight")}
    return d, scores, {m: tmp / f"out_{m}" for m in ("loose", "tight")}


@pytest.mark.parametrize("label,change", [("tow -> 0", lambda t: 0.0), ("tow - 302401 s", lambda t: t - 302401.0),
                                          ("tow - 1000 s", lambda t: t - 1000.0), ("tow + 0.5 s", lambda t: t + 0.5),
                                          ("tow + 1000 s", lambda t: t + 1000.0)])
def test_one_damaged_time_of_week_is_dropped_not_spread(tmp_path, clean_drive, label, change):
    """Before: the week unwrap moved every later epoch by a week (tow -> 0), the IMU counter unwrap
    crashed (- 302401 s), the tight filter refused the session (- 1000 s, + 0.5 s) or took the epoch
    and drifted 50 m (+ 1000 s)."""
    d0, clean, _ = clean_drive
    d = tmp_path / "damaged"
    shutil.copytree(d0, d)
    damage_one_tow(d, change)
    skipped = measurements.decode_session(d).skipped
    for mode in ("loose", "tight"):
        res = replay.replay(d, tmp_path / f"out_{mode}", mode=mode)
        got = res.summary["scoring"]["all"]
        print(f"{label}, {mode}: H/V RMS {got['rms_h_m']:.3f} / {got['rms_v_m']:.3f} m, "
              f"undamaged {clean[mode]['rms_h_m']:.3f} / {clean[mode]['rms_v_m']:.3f} m")
        # One epoch of 90 without its pseudoranges: the run is the undamaged one within a few per cent.
        assert got["rms_h_m"] < 1.05 * clean[mode]["rms_h_m"] and got["rms_v_m"] < 1.05 * clean[mode]["rms_v_m"]
    assert skipped[measurements.TOW_DAMAGED] == 1, skipped


@pytest.mark.parametrize("run", [1, 2, 3])
def test_imu_records_moved_within_the_file(tmp_path, run):
    """`run` whole IMU records (24 bytes each: counter, increments and stamp) cut out 23 s later
    and put back earlier, as a fuzzer's "move" does. Before: their counter made the index
    256 frames too high after them (AlignmentError for two or more; the reader drops a lone one for
    its stamp). Now they are left out, and counted; their old place is a gap of `run` frames."""
    s, d = simulate(tmp_path, "moved", jitter_mean_s=0.0005)
    k = sample_index(d)
    scan = logs.read_record_file(d / "imu-000.bin", "bp3010")
    i, j = scan.count // 4, scan.count // 4 + 1500
    order = [*range(i), *range(j, j + run), *range(i, j), *range(j + run, scan.count)]
    (d / "imu-000.bin").write_bytes(b"".join(scan.record(m) for m in order))
    skipped = measurements.decode_session(d).skipped  # a lone one the reader already drops for its stamp
    assert skipped[measurements.IMU_MOVED] + skipped["imu: records with impossible stamps (their bytes are counted "
                                                     "above)"] == run
    al, err = align_errors(s, d, np.delete(k, np.arange(j, j + run)))
    check(al, err, f"{run} IMU records moved")


def test_a_receiver_restart_that_sends_gps_time_back_replays_in_stretches(tmp_path, clean_drive):
    """50 s in, the receiver restarts and, after a second of silence, serves the drive again from
    its start (GPS time 51 s back, as the fault campaign's emulator did; the IMU goes on). Before:
    the whole session refused ("fixes row 40: time does not increase"). Now two stretches, each
    on its own time line: the first is the undamaged replay of those 50 s."""
    d0, _, clean_out = clean_drive
    d = tmp_path / "restart"
    shutil.copytree(d0, d)
    scan = logs.read_record_file(d / "gps-000.bin", "superstar2")
    restart = scan.stamps[0] + 50.0
    again = scan.stamps - scan.stamps[0] + restart + 1.0
    first, repeat = np.flatnonzero(scan.stamps < restart), np.flatnonzero(again < scan.stamps[-1])
    rec = [scan.record(k) for k in first]
    for k in repeat:
        raw = scan.record(k)
        rec.append(raw[:ss2.HEADER_LEN] + STAMP.pack(again[k]) + raw[ss2.HEADER_LEN + layouts.STAMP_BYTES:])
    (d / "gps-000.bin").write_bytes(b"".join(rec))

    for mode in ("loose", "tight"):
        res = replay.replay(d, tmp_path / mode, mode=mode)
        assert [r.out.name for r in res.stretches] == ["stretch-1", "stretch-2"]
        assert all("receiver restart" in " ".join(r.summary["warnings"]) for r in res.stretches)
        one, whole = results_mod.load(res.stretches[0].out), results_mod.load(clean_out[mode])
        # Up to its last fix (the undamaged replay has one more, at the restart), at the IMU's times
        # as the stretch's own clock fit gives them.
        ok = np.isfinite(one["err_ned_m"][:, 0]) & (one["t"] <= res.stretches[0].summary["outages"]["gnss_last_t"])
        t = one["t"][ok]
        diff = np.abs(one["err_ned_m"][ok] - np.column_stack([np.interp(t, whole["t"], whole["err_ned_m"][:, a])
                                                              for a in range(3)]))
        print(f"{mode}: stretch 1 {t[0]:.1f}-{t[-1]:.1f} s against the undamaged replay: max difference "
              f"{diff.max(axis=0)} m; stretch 2 {res.stretches[1].summary['imu_samples']} IMU samples")
        assert t[-1] - t[0] > 45 and diff.max() < 0.01
        assert res.stretches[1].summary["imu_samples"] > 30 * 64
    # The command line writes each stretch (and mode) on its own and says so.
    assert cli.main(["replay", str(d), "--mode", "both", "--out", str(tmp_path / "cli")]) == 0
    for part in ("stretch-1", "stretch-2"):
        for mode in ("loose", "tight"):
            assert (tmp_path / "cli" / part / mode / "run.json").is_file()
    # ... and the report puts them together.
    assert cli.main(["report", str(tmp_path / "cli")]) == 0
    page = (tmp_path / "cli" / "report" / "report.md").read_text()
    assert all(f"{mode} stretch {i}" in page for mode in ("loose", "tight") for i in (1, 2))
