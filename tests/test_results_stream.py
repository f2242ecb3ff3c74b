"""Replay in bounded memory: a run split into chunks gives what one call over the whole arrays
gives (forward and smoothed), and the results tables read back what was written, with
decimation and the per-chunk running statistics equal to statistics over everything."""

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gpsins.nav import runs as flt
from gpsins.replay import run as replay, results
from gpsins.replay import inputs as replay_inputs
from gpsins import sim
from gpsins.nav import config as nav_config
from gpsins.nav import inputs as nav_inputs
from gpsins.sim import scenario
from gpsins.formats.gpstime import GPS_EPOCH, gpst_text
from gpsins.sim.session import write_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d = tmp_path_factory.mktemp("stream") / "session"
    write_session(sim.simulate(scenario.load("default"), seed=3), d)
    return d


@pytest.fixture(scope="module")
def tight_inputs(session):
    return replay_inputs.load_inputs(session, modes=("tight",))


def _whole_and_chunked(inp, chunk_rows, output_every=2, overlap=True):
    cfg = nav_config.load_config(None, {"mode": "tight"})
    kw = dict(pseudoranges=inp.pseudoranges, ephemerides=inp.ephemerides, klobuchar=inp.klobuchar,
              gps_time_offset_s=inp.week * 604800.0)
    whole = flt.run(inp.imu, inp.fixes, cfg, mode="tight", covariance=True, smooth=True, output_every=output_every,
                    **kw)
    run = flt.ChunkedRun(inp.imu, inp.fixes, cfg, mode="tight", record=True, chunk_rows=chunk_rows,
                         output_every=output_every, overlap=overlap, **kw)
    chunks = list(run.chunks())
    blocks = []
    run.smooth(lambda first, sol: blocks.append((first, sol)), block_rows=997)
    return whole, run, chunks, blocks


# overlap: the next chunk runs on a second thread while this one is taken (the default), or not.
@pytest.mark.parametrize("chunk_rows, overlap", [(1, True), (777, True), (777, False), (10 ** 6, True)])
def test_chunked_run_equals_one_call(tight_inputs, chunk_rows, overlap):
    inp = tight_inputs
    if chunk_rows == 1:  # one sample per call over the first 1500 samples is enough to show the seams
        inp = replay_inputs.Inputs(inp.source, inp.kind, inp.week, inp.imu[:1500], inp.fixes, inp.fix_sats,
                                   inp.gnss_span, inp.pseudoranges, inp.ephemerides, inp.klobuchar)
    whole, run, chunks, blocks = _whole_and_chunked(inp, chunk_rows, overlap=overlap)
    cat = lambda parts, name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    for name in ("t", "r_ecef", "v_ecef", "q_eb", "sigma", "clock", "covariance", "heading_known"):
        np.testing.assert_array_equal(cat(chunks, name), getattr(whole, name), err_msg=name)
    for key in ("t", "kind", "nis", "innovation"):
        np.testing.assert_array_equal(np.concatenate([c.updates[key] for c in chunks]), whole.updates[key])
    assert run.counters == whole.counters
    assert run.fixes_after_end == whole.extra["fixes_after_end"]
    # The smoother's blocks come newest first, each in time order, and tile the run.
    firsts = [f for f, _ in blocks]
    assert firsts == sorted(firsts, reverse=True) and firsts[-1] == 0
    blocks.sort(key=lambda b: b[0])
    sm = whole.extra["smoothed"]
    for name in ("t", "r_ecef", "q_eb", "sigma", "covariance"):
        np.testing.assert_array_equal(cat([b for _, b in blocks], name), getattr(sm, name), err_msg=name)


@pytest.mark.parametrize("mode, estimate_time_offset", [("loose", False), ("tight", False), ("loose", True)])
def test_navigation_covariance_is_the_full_ones_block(tight_inputs, mode, estimate_time_offset):
    """The covariance a replay asks for (attitude, velocity and position, then the IMU time offset when
    it is a state) is that block of the full covariance, entry for entry, forward and smoothed, and so
    are the position sigmas the time offset moves to GNSS time."""
    inp = tight_inputs
    imu = inp.imu[:6000]
    cfg = nav_config.load_config(None, {"mode": mode, "estimate_time_offset": estimate_time_offset})
    kw = dict(pseudoranges=inp.pseudoranges, ephemerides=inp.ephemerides, klobuchar=inp.klobuchar,
              gps_time_offset_s=inp.week * 604800.0) if mode == "tight" else {}
    cat = lambda parts, name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    for smoothed in (False, True):
        sols = {}
        for block in (False, True):
            run = flt.ChunkedRun(imu, inp.fixes, cfg, mode=mode, chunk_rows=1000, record=smoothed, **kw)
            sols[block] = [s for s in run.chunks(navigation_covariance=block)]
            if smoothed:
                blocks = []
                run.smooth(lambda first, sol, blocks=blocks: blocks.append((first, sol)), navigation_covariance=block)
                sols[block] = [sol for _, sol in sorted(blocks, key=lambda b: b[0])]
        full, nav = sols[False], sols[True]
        p_full, p_nav = cat(full, "covariance"), cat(nav, "covariance")
        keep = list(range(9)) + ([p_full.shape[1] - 1] if estimate_time_offset else [])
        assert p_nav.shape == (len(p_full), len(keep), len(keep)) and len(p_full) > 5000
        np.testing.assert_array_equal(p_nav, p_full[:, keep][:, :, keep])
        np.testing.assert_array_equal(cat(nav, "sigma"), cat(full, "sigma"))
        np.testing.assert_array_equal(cat(nav, "r_ecef"), cat(full, "r_ecef"))


def test_results_tables_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    chunks = [dict(t=np.arange(n, dtype=float) + 100 * k, r_ecef=rng.normal(size=(n, 3)), flag=rng.random(n) > 0.5,
                   sigma=rng.random((n, 17))) for k, n in enumerate((5, 0, 7, 3))]
    with results.TableWriter(tmp_path / "x.parquet") as w:
        for c in chunks:
            w.append(c)
    full = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    back = results.read_table(tmp_path / "x.parquet")
    for k, v in full.items():
        np.testing.assert_array_equal(back[k], v)
    # Chunks gathered into row groups (of at least 1000 bytes here), newest first as the smoother
    # writes them: reversing the row groups gives time order, whatever the grouping.
    with results.TableWriter(tmp_path / "r.parquet", newest_first=True, group_bytes=1000) as w:
        for c in chunks[::-1]:
            w.append(c)
    assert pq.ParquetFile(tmp_path / "r.parquet").num_row_groups == 2  # (3 + 7 rows), then 5 rows
    results.reverse_row_groups(tmp_path / "r.parquet", tmp_path / "f.parquet")
    back = results.read_table(tmp_path / "f.parquet")
    for k, v in full.items():
        np.testing.assert_array_equal(back[k], v)
    for stride in (2, 4):
        dec = results.read_table(tmp_path / "x.parquet", columns=["t", "r_ecef"], stride=stride)
        np.testing.assert_array_equal(dec["t"], full["t"][::stride])
        np.testing.assert_array_equal(dec["r_ecef"], full["r_ecef"][::stride])
    # What pandas.read_parquet uses: the components are plain named columns.
    np.testing.assert_array_equal(pq.read_table(tmp_path / "x.parquet").column("r_ecef_y").to_numpy(),
                                  full["r_ecef"][:, 1])


def test_replay_in_chunks_writes_what_one_chunk_writes(session, tmp_path):
    """Small chunks against one chunk: the same tables, .pos, statistics and scoring, and the statistics
    equal those recomputed from the per-epoch errors."""
    inp = replay_inputs.load_inputs(session)
    a = replay.run_mode(inp, tmp_path / "one", chunk_rows=10 ** 7, smooth=True)
    b = replay.run_mode(inp, tmp_path / "many", chunk_rows=1000, smooth=True)
    for name in ("solution.pos", "smoothed.pos"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "many" / name).read_bytes()
    za, zb = results.load(tmp_path / "one"), results.load(tmp_path / "many")
    assert za.keys() == zb.keys()
    for k in za:
        np.testing.assert_array_equal(za[k], zb[k], err_msg=k)
    assert a.summary["errors"] == pytest.approx(b.summary["errors"], rel=1e-12)
    assert json.dumps(a.summary["scoring"]) == json.dumps(b.summary["scoring"])
    assert a.summary["smoothed"]["errors"] == pytest.approx(b.summary["smoothed"]["errors"], rel=1e-12)
    hk = za["heading_known"] & np.isfinite(za["err_ned_m"][:, 0])
    h = np.hypot(za["err_ned_m"][hk, 0], za["err_ned_m"][hk, 1])
    assert b.summary["errors"]["horizontal_rms_m"] == pytest.approx(np.sqrt(np.mean(h ** 2)), rel=1e-12)
    assert b.summary["errors"]["nees9_mean"] == pytest.approx(np.mean(za["nees9"][hk]), rel=1e-12)
    assert np.all(np.diff(zb["smooth_t"]) > 0)
    # Full covariance on request, every Nth epoch.
    c = replay.run_mode(inp, tmp_path / "cov", chunk_rows=1000, covariance_every=50)
    t, p = results.load_covariance(tmp_path / "cov")
    zc = results.load(tmp_path / "cov")
    np.testing.assert_array_equal(t, zc["t"][::50])
    np.testing.assert_allclose(np.sqrt(np.diagonal(p, axis1=1, axis2=2)), zc["sigma"][::50], rtol=1e-12)
    assert c.summary["epochs"] == len(zc["t"])


def test_replay_output_every_nth_sample_is_those_epochs_of_the_full_one(session, tmp_path):
    """--output-every N (a 1 Hz .pos from a fast IMU, the writing of an hour at 200 Hz left out): every
    Nth sample's epoch of the full output, the forward and the smoothed, value for value, with chunks
    that do not divide by N; the .pos has those epochs' lines."""
    inp = replay_inputs.load_inputs(session)
    replay.run_mode(inp, tmp_path / "all", chunk_rows=1000, smooth=True)
    replay.run_mode(inp, tmp_path / "every", chunk_rows=1000, smooth=True, output_every=64)
    za, ze = results.load(tmp_path / "all"), results.load(tmp_path / "every")
    k = np.searchsorted(za["t"], ze["t"])
    assert len(ze["t"]) == pytest.approx(len(za["t"]) / 64, abs=2) and np.array_equal(za["t"][k], ze["t"])
    assert np.allclose(np.diff(ze["t"]), 1.0, atol=1e-6)  # 64 samples of the 64 Hz unit
    for name in ("r_ecef", "q_eb", "sigma_ned_m"):
        np.testing.assert_array_equal(ze[name], za[name][k], err_msg=name)
    # The smoother's tape multiplies the steps between outputs into one transition: the same to rounding.
    for name in ("smooth_r_ecef", "smooth_q_eb", "smooth_sigma_ned_m"):
        np.testing.assert_allclose(ze[name], za[name][k], rtol=1e-12, atol=1e-9, err_msg=name)
    lines = [x for x in (tmp_path / "every" / "solution.pos").read_text().splitlines() if not x.startswith("%")]
    all_lines = [x for x in (tmp_path / "all" / "solution.pos").read_text().splitlines() if not x.startswith("%")]
    assert lines == [all_lines[i] for i in k]
    with pytest.raises(ValueError, match="--output-every 0"):
        replay.run_mode(inp, tmp_path / "zero", output_every=0)


def test_gpst_text_matches_datetime():
    import datetime as dt
    x = np.array([0.0005, 1.0004999, 12.9995, 1e9 + 0.0015, 1.5e9 + 0.9999996, 86399.9996])
    want = [(GPS_EPOCH + dt.timedelta(seconds=float(v))).strftime("%Y/%m/%d %H:%M:%S.%f")[:-3] for v in x]
    assert gpst_text(x) == want


def test_smoothed_covariance_is_a_covariance(tight_inputs):
    """The tight filter sets its clock bias from the first pseudorange epoch's residuals; the smoother's
    record calls that a restart, so the forward covariance must forget the bias's past too (it did not,
    and the smoothed clock-drift variance came out at -8100 m^2/s^2 before the first pseudorange)."""
    whole, _, _, _ = _whole_and_chunked(tight_inputs, 10 ** 6, output_every=1)
    p = whole.extra["smoothed"].covariance
    assert np.all(np.diagonal(p, axis1=1, axis2=2) >= 0)
    assert np.all(np.linalg.eigvalsh(0.5 * (p + np.swapaxes(p, 1, 2)))[:, 0] > -1e-9 * np.abs(p).max(axis=(1, 2)))


def test_imu_columns_index_like_the_table():
    rng = np.random.default_rng(2)
    c = nav_inputs.ImuColumns(np.arange(9.0), rng.normal(size=(9, 3)), rng.normal(size=(9, 3)))
    t = np.column_stack([c.t, c.dtheta, c.dv])
    for ix in (slice(2, 5), slice(None, None, 3), (0, 0), (-1, 0), (slice(None), 0), (4, slice(1, 4)),
               (slice(1, 7), slice(0, 2))):
        np.testing.assert_array_equal(c[ix], t[ix])
    assert len(c) == 9
    with pytest.raises(IndexError):
        c[9]


def test_run_json_is_strict_json(tmp_path):
    """RFC 8259 has no NaN: a value a run could not compute is null (the walk's run.json held NaN
    before: the NIS of a source with no updates, the errors of a run without a truth)."""
    res = replay.replay(Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml", tmp_path / "w")
    text = (res.out / "run.json").read_text()

    def refuse(name):
        raise ValueError(f"run.json holds {name}")

    json.loads(text, parse_constant=refuse)
    assert results.json_text({"a": float("nan"), "b": [np.inf, np.float32(2.5)], "c": np.int64(3)}) == \
        json.dumps({"a": None, "b": [None, 2.5], "c": 3}, indent=2)


def test_run_json_says_what_made_it(session, tmp_path):
    """Version, the configuration's hash (of the config.toml written beside it), the source and the
    simulation's scenario and seed: enough to make the result again."""
    import hashlib

    from gpsins import __version__

    res = replay.replay(session, tmp_path / "r")
    p = json.loads((res.out / "run.json").read_text())["provenance"]
    assert p["gpsins"] == __version__ and p["source"] == str(session)
    assert p["config_sha256"] == hashlib.sha256((res.out / "config.toml").read_bytes()).hexdigest()
    assert p["simulation"]["scenario"] == "default" and p["simulation"]["seed"] == 3
