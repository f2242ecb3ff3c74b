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
