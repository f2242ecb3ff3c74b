"""The replay's .pos writer: byte for byte what Python's own formatting of RTKLIB's layout gives,
and read back by the project's RTKLIB reader (time tags, positions, sigmas)."""

import datetime as dt

import numpy as np

from gpsins.formats import rtklib_pos
from gpsins.replay.solution import PosWriter

# RTKLIB's solution line (outpos with time format yyyy/mm/dd hh:mm:ss.sss, degrees), written here
# independently of the writer under test.
LINE = ("%04d/%02d/%02d %02d:%02d:%02d.%03d %14.9f %14.9f %10.4f %3d %3d %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f "
        "%6.2f %6.1f")


def _expected(week: int, t: np.ndarray, llh: np.ndarray, sig: np.ndarray, sats: np.ndarray) -> list[str]:
    gps0 = dt.datetime(1980, 1, 6)
    out = []
    for ti, p, s, ns in zip(t, llh, sig, sats):
        us = round(week * 604800 * 1_000_000 + float(ti) * 1e6)
        when = gps0 + dt.timedelta(milliseconds=us // 1000)
        out.append(LINE % (when.year, when.month, when.day, when.hour, when.minute, when.second,
                           when.microsecond // 1000, np.degrees(p[0]), np.degrees(p[1]), p[2], 5, ns,
                           s[0], s[1], s[2], 0, 0, 0, 0, 0))
    return out


def test_pos_lines_equal_python_formatting_and_read_back(tmp_path):
    rng = np.random.default_rng(5)
    n = 500
    week = 2200
    # Across a day and a week boundary, with sub-millisecond parts that the tag cuts off.
    t = np.sort(np.concatenate([rng.uniform(86_390, 86_410, n // 2), rng.uniform(604_790, 604_810, n // 2)]))
    llh = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-3.1, 3.1, n), rng.uniform(-400, 9000, n)])
    sig = rng.uniform(0, 120, (n, 3))
    sats = rng.integers(0, 13, n)
    path = tmp_path / "a.pos"
    w = PosWriter(path, week, "test")
    w.add(t[:200], llh[:200], sig[:200], sats[:200])
    w.add(t[200:], llh[200:], sig[200:], sats[200:])
    w.close()
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("%")]
    assert lines == _expected(week, t, llh, sig, sats)

    fixes = rtklib_pos.read(path)
    assert len(fixes) == n
    np.testing.assert_array_equal(fixes.q, 5)
    np.testing.assert_array_equal(fixes.ns, sats)
    np.testing.assert_allclose(fixes.sigma_ned_m, sig, atol=6e-5)
    got = fixes.llh()
    np.testing.assert_allclose(got[:, :2], llh[:, :2], atol=1e-10)
    np.testing.assert_allclose(got[:, 2], llh[:, 2], atol=1e-4)
    t_abs = week * 604800 + t
    assert np.all((fixes.t_abs <= t_abs + 1e-6) & (fixes.t_abs > t_abs - 1e-3))


def test_reversed_blocks_come_out_in_time_order(tmp_path):
    t = np.arange(10.0)
    llh = np.column_stack([np.full(10, 0.7), np.full(10, 0.3), t])
    sig = np.ones((10, 3))
    path = tmp_path / "s.pos"
    w = PosWriter(path, 2000, "", reversed_blocks=True)
    for block in (slice(6, 10), slice(3, 6), slice(0, 3)):
        w.add(t[block], llh[block], sig[block], np.full(10, 7)[block])
    w.close()
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("%")]
    assert lines == _expected(2000, t, llh, sig, np.full(10, 7))
