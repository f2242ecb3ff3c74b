"""The noise fit's budget: its likelihood runs cover the recording up to FIT_SPAN_S after the first
fix, so a long recording fits in the time of a short one, and what lies after the window cannot
change the factors."""

import numpy as np
import pytest

from gpsins import sim
from gpsins.nav import config as nav_config
from gpsins.nav import noise_from_data
from gpsins.sim import scenario

pytest.importorskip("scipy")


def test_the_noise_fit_sees_only_its_window(monkeypatch):
    s = sim.simulate(scenario.load("default"), seed=1)
    imu, fixes = sim.imu_table(s), sim.fix_table(s)
    cfg = nav_config.load_config(None, sim.imu_noise_truth(s.scenario.imu))
    monkeypatch.setattr(noise_from_data, "FIT_SPAN_S", 100.0)
    whole = noise_from_data.fit_noise(imu, fixes, cfg)
    end = fixes[0, 0] + 100.0
    cut = noise_from_data.fit_noise(imu[imu[:, 0] <= end], fixes[fixes[:, 0] <= end], cfg)
    assert whole == cut
    assert whole["span_s"] <= 100.0 and whole["fixes"] == int(np.sum(fixes[:, 0] <= end))
    assert len(fixes) > 2 * whole["fixes"]  # the drive goes on well past the window


def test_the_window_of_imu_columns_is_the_tables_window(monkeypatch):
    """A replay's IMU comes as columns (nav.inputs.ImuColumns): the fit's window of them is the same rows as the
    table's, built from those rows only; NumPy never walks the columns row by row (an hour at 200 Hz took 7 s
    that way, from the mounting refinement's fit_start)."""
    from gpsins.nav.inputs import ImuColumns

    rng = np.random.default_rng(4)
    t = 1000.0 + np.arange(5000) * 0.01
    cols = ImuColumns(t, rng.normal(size=(5000, 3)), rng.normal(size=(5000, 3)))
    table = np.column_stack([t, cols.dtheta, cols.dv])
    fixes = np.column_stack([np.arange(1000.5, 1050.0, 1.0), np.zeros((50, 10))])
    monkeypatch.setattr(noise_from_data, "FIT_SPAN_S", 20.0)
    rows = []
    real = ImuColumns.__getitem__
    monkeypatch.setattr(ImuColumns, "__getitem__", lambda self, i: rows.append(i) or real(self, i))
    got_imu, got_fixes = noise_from_data.fit_window(cols, fixes)
    want_imu, want_fixes = noise_from_data.fit_window(table, fixes)
    np.testing.assert_array_equal(got_imu, table[t <= 1020.5])
    np.testing.assert_array_equal(got_imu, want_imu)
    np.testing.assert_array_equal(got_fixes, want_fixes)
    assert len(rows) == 1  # one slice of rows, not one call per row
    np.testing.assert_array_equal(np.asarray(cols), table)
    assert np.asarray(cols, dtype=np.float32).dtype == np.float32
