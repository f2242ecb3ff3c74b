"""The simulator in blocks: the same run, to the byte, whatever the block length, and the
blocks joined still pass the physics checks of test_sim (truth re-integrated across block ends,
increments composed back into the truth)."""

import numpy as np
import pytest

from gpsins.replay import inputs as replay_inputs
from gpsins import sim
from gpsins.sim import scenario
from gpsins.sim import Simulator, gnss, trajectory
from gpsins.sim.scenario import parse, with_imu_rate
from gpsins.sim.session import simulate_session, write_session
from gpsins.formats.truth import load_truth, open_truth
from simcheck import increment_errors, reintegration_errors

START = {"lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0, "heading_deg": 10.0}
SEGMENTS = [{"label": "stand", "duration_s": 6.0, "speed_mps": 0},
            {"label": "go", "duration_s": 8.0, "speed_mps": 12, "grade_deg": 2},
            {"label": "turn", "duration_s": 9.0, "turn_deg": 120, "coordinated": True},
            {"label": "dip", "duration_s": 7.0, "grade_deg": -3, "bank_deg": 4},
            {"label": "stop", "duration_s": 5.0, "speed_mps": 0, "grade_deg": 0, "bank_deg": 0}]


def _scenario(**timing):
    """A 60 s drive with everything that carries state: obstructions (one flickering) on every pass of a
    repeated span, host stalls, dropped IMU frames, jitter, a clock step, an unsteered receiver clock,
    the reference with random outages."""
    return parse({"name": "chunks", "start": START, "segment": SEGMENTS,
                  "repeat": [{"first": "go", "last": "dip", "count": 2}],
                  "obstruction": [{"segment": "go", "azimuth_deg": [0, 360], "below_elevation_deg": 50,
                                   "flicker": 0.4, "flicker_period_s": 1.5},
                                  {"segment": "dip", "azimuth_deg": [90, 270], "below_elevation_deg": 70}],
                  "gnss": {"clock": "unsteered", "reacquire_s": 1.0},
                  "timing": {"load_stall_rate_hz": 0.2, "imu_drop_probability": 0.02, "jitter_mean_s": 0.001,
                             "clock_step_at_s": 20.0, "clock_step_s": 0.2, **timing},
                  "reference": {"moving_outage_rate_hz": 0.2, "moving_outage_mean_s": 1.5}})


def _files(d):
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """The drive written whole and in blocks of 8 s (one integration span) and 24 s."""
    sc = _scenario()
    root = tmp_path_factory.mktemp("chunks")
    out = {"whole": write_session(sim.simulate(sc, 11), root / "whole")}
    for block_s in (8.0, 24.0):
        out[block_s] = simulate_session(sc, 11, root / f"b{block_s:g}", block_s)
    return sc, out


def test_blocks_write_the_same_bytes_as_the_whole_run(sessions):
    sc, d = sessions
    whole = _files(d["whole"])
    assert set(whole) == {"gps-000.bin", "imu-000.bin", "clock.csv", "reference.csv", "session.json", "truth.npz"}
    assert Simulator(sc, 11).block_samples(8.0) < Simulator(sc, 11).n_imu / 6  # several blocks indeed
    for block_s in (8.0, 24.0):
        files = _files(d[block_s])
        assert files.keys() == whole.keys()
        for name in whole:
            assert files[name] == whole[name], (block_s, name)
    # The run exercised what carries state across block ends.
    side = sessions[1]["whole"] / "session.json"
    assert '"frames_dropped_by_simulation": 0' not in side.read_text()
    ref = (d["whole"] / "reference.csv").read_text().splitlines()
    assert any(",,," in line for line in ref) and sum(",,," not in line for line in ref) > 30


def test_another_rate_and_seed_also_agree(tmp_path):
    """200 Hz (10 grid steps per sample, spans of 819 samples) with the steered clock and no jitter."""
    sc = with_imu_rate(_scenario(jitter_mean_s=0.0), 200)
    sc.gnss.clock = "steered"
    a = write_session(sim.simulate(sc, 3), tmp_path / "a")
    b = simulate_session(sc, 3, tmp_path / "b", 5.0)
    assert _files(a) == _files(b)


def _join(blocks):
    """Blocks in order as one Simulation (block truth grids share their end points)."""
    first = blocks[0]
    tr = trajectory.Truth(*(np.concatenate([getattr(b.truth, f)[1 if i else 0:] for i, b in enumerate(blocks)])
                            for f in ("t", "lat", "lon", "h", "r_ecef", "v_ecef", "v_ned", "a_ecef", "q_eb", "ypr",
                                      "f_body", "w_ib_body", "c_eb")), first.truth.substeps)
    cat = lambda f: np.concatenate([f(b) for b in blocks])  # noqa: E731
    return sim.Simulation(first.scenario, first.seed, tr, first.imu_rate_hz, cat(lambda b: b.imu_t),
                          cat(lambda b: b.ideal_dtheta), cat(lambda b: b.ideal_dv), cat(lambda b: b.imu_dtheta),
                          cat(lambda b: b.imu_dv), first.imu_errors, gnss.concatenate([b.gnss for b in blocks]))


def test_joined_blocks_pass_the_physics_checks():
    sc = scenario.load("default")
    sc.segments = sc.segments[:9]  # standing, pulling away, the first turns and hills: 106 s
    blocks = list(Simulator(sc, 0).blocks(16.0))
    assert len(blocks) >= 6
    s = _join(blocks)
    whole = sim.simulate(sc, 0)
    for name in ("imu_t", "ideal_dtheta", "ideal_dv", "imu_dtheta", "imu_dv"):
        assert np.array_equal(getattr(s, name), getattr(whole, name)), name
    assert np.array_equal(s.truth.r_ecef, whole.truth.r_ecef) and np.array_equal(s.truth.q_eb, whole.truth.q_eb)
    # test_sim's bounds: the truth re-integrated by a simple strapdown, the increments composed.
    att, pos = reintegration_errors(s.truth)
    assert att < 2e-8 and pos < 2e-3, (att, pos)
    for t0, t1, tol in ((0.0, s.imu_t[-1], 2e-8), (blocks[2].imu_t[0] - 3.0, blocks[2].imu_t[0] + 3.0, 1e-10)):
        att, vel = increment_errors(s, t0, t1)
        assert att < 1e-12 and vel < tol, (t0, att, vel)
    # The receiver's epochs every 0.1 s of receiver time, each once, and its fixes once per second.
    g = s.gnss
    assert np.allclose(np.diff(g.tow_rx), 0.1, atol=1e-9) and len(g.t) == int(sc.duration_s * 10) + 1
    assert np.allclose(np.diff([f.tow_s for f in g.fixes]), 1.0, atol=1e-9)


def test_a_block_must_end_on_an_integration_span():
    sc = _scenario()
    stream = Simulator(sc, 0).truth
    with pytest.raises(ValueError, match="span"):
        stream.span(stream.atom_samples + 1)


def test_truth_file_opens_memory_mapped_and_the_replay_reads_it(sessions):
    _, d = sessions
    path = d[24.0] / "truth.npz"
    mapped, loaded = open_truth(path), load_truth(path)
    assert isinstance(mapped["r_ecef"], np.memmap)
    for k, v in loaded.items():
        if k != "model":
            np.testing.assert_array_equal(np.asarray(mapped[k]), v, err_msg=k)
    found = replay_inputs.load_session_truth(d[24.0], 0.0)
    assert found is not None
    truth, extra = found
    assert np.array_equal(truth.t, loaded["tow_s"] + int(loaded["gps_week"]) * 604800.0)
    assert np.array_equal(truth.r_ecef, loaded["r_ecef"]) and list(extra["seg_labels"])[:2] == ["stand", "go"]


def test_the_data_set_in_blocks_is_the_whole_runs(tmp_path):
    """`gpsins sim --dataset` writes the data set from the same blocks: the same files as from the whole run."""
    from gpsins.sim.dataset_writer import write_dataset

    sc = _scenario()
    whole = write_dataset(sim.simulate(sc, 5), tmp_path / "whole").parent
    simulate_session(sc, 5, tmp_path / "s", 16.0, dataset=tmp_path / "blocks")
    assert _files(tmp_path / "blocks") == _files(whole)
    rows = (whole / "receiver.pos").read_text().splitlines()
    assert len(rows) - 3 == len(np.arange(0.137, sim.simulate(sc, 5).imu_t[-1] - 0.5, 0.2))


def test_the_data_sets_fix_rate_is_the_one_asked_for(tmp_path):
    """`gpsins sim --dataset --fix-rate 1` (the 1 Hz receiver of KF-GINS's hour): fixes a second apart, as many as
    fit in the run; a rate that is not positive is refused by name."""
    from gpsins import cli

    sc = _scenario()
    simulate_session(sc, 5, tmp_path / "s", 16.0, dataset=tmp_path / "d", fix_rate_hz=1.0)
    rows = [r for r in (tmp_path / "d" / "receiver.pos").read_text().splitlines() if not r.startswith("%")]
    hms = np.array([[float(x) for x in r.split()[1].split(":")] for r in rows])
    assert np.allclose(np.diff(hms @ [3600.0, 60.0, 1.0]), 1.0)
    assert len(rows) == len(np.arange(0.137, sim.simulate(sc, 5).imu_t[-1] - 0.5, 1.0))
    assert cli.main(["sim", "--out", str(tmp_path / "x"), "--dataset", "--fix-rate", "0"]) == 2
    assert not (tmp_path / "x").exists()


def test_a_fast_receiver_keeps_its_message_order_across_blocks(tmp_path):
    """At 50 Hz a fix's messages (60 ms after its epoch) come after the next epochs' measurements (20 ms after
    theirs), also across a block's end."""
    sc = _scenario()
    sc.gnss.measurement_rate_hz = 50
    a = write_session(sim.simulate(sc, 2), tmp_path / "a")
    b = simulate_session(sc, 2, tmp_path / "b", 8.0)
    assert _files(a) == _files(b)


def test_a_degenerate_geometry_gives_no_fix_rather_than_an_error(monkeypatch):
    """A day's drive met a singular least-squares geometry, then one whose iterations diverged (a position
    too large for the message's float): the receiver reports no fix for those epochs and goes on."""
    real, calls = gnss._solve, []

    def degenerate(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise np.linalg.LinAlgError("Singular matrix")
        r, clock, geo, step = real(*args, **kwargs)
        return (r * 1e40, clock, geo, 1e40) if len(calls) == 7 else (r, clock, geo, step)

    monkeypatch.setattr(gnss, "_solve", degenerate)
    sc = parse({"name": "stand", "start": START, "segment": [{"label": "s", "duration_s": 10.0}]})
    s = sim.simulate(sc, 0)
    modes = [f.mode for f in s.gnss.fixes]
    assert modes[4] == 0 and modes[6] == 0 and all(m == 2 for i, m in enumerate(modes) if i not in (4, 6)), modes
