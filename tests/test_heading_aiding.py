"""Dual-antenna heading as an aiding source (seed 004 section 4.2's reference receiver; issue 21):
the simulated reference system's heading and pitch fed to the filter, scored against the
simulator's truth, which the reference's errors are independent of."""

import numpy as np
import pytest

from gpsins import _core, sim
from gpsins.nav import runs as flt
from gpsins.replay import run, results
from gpsins.replay import inputs as replay_inputs
from gpsins.replay import scoring as replay_scoring
from gpsins.sim import scenario
from gpsins.formats.reference import FILE_NAME
from gpsins.sim.session import write_session

REFERENCE_YAW_SIGMA_DEG = 0.004 / 1.5 * 180 / np.pi  # the report's Table 4.4 for a 1.5 m baseline: 0.15 deg


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d = tmp_path_factory.mktemp("heading") / "session"
    write_session(sim.simulate(scenario.load("default"), seed=1), d)
    return d


def _yaw_rms_deg(z) -> float:
    m = z["heading_known"] & np.isfinite(z["err_ypr_deg"][:, 0])
    return float(np.sqrt(np.mean(z["err_ypr_deg"][m, 0] ** 2)))


@pytest.mark.parametrize("mode", ["loose", "tight"])
def test_heading_aiding_gives_the_reference_heading_from_the_start(session, tmp_path, mode):
    inp = replay_inputs.load_inputs(session, modes=(mode,))
    free = run.run_mode(inp, tmp_path / "free", mode=mode)
    aided = run.run_mode(inp, tmp_path / "aided", mode=mode, aid_heading=True)
    zf, za = results.load(tmp_path / "free"), results.load(tmp_path / "aided")
    # The car stands for its first 31 s: without aiding the heading comes from the course once it moves.
    first_free = next(e["t"] for e in free.summary["events"] if e["kind"] == "heading_set") - zf["t"][0]
    first_aided = next(e["t"] for e in aided.summary["events"] if e["kind"] == "heading_set") - za["t"][0]
    assert first_free > 30.0
    assert first_aided < 1.5  # the first reference epoch after levelling
    assert _yaw_rms_deg(za) < 3 * REFERENCE_YAW_SIGMA_DEG
    assert _yaw_rms_deg(za) < 0.3 * _yaw_rms_deg(zf)
    reference = replay_scoring.heading_aiding(replay_scoring.reference_system(session), inp.week)
    assert aided.summary["update_kinds"]["baseline_attitude"] == aided.summary["heading_aiding"]["epochs"] - \
        int(np.sum(reference[:, 0] < za["t"][0]))
    assert aided.summary["counters"]["diverged"] is False


def test_heading_aiding_needs_a_reference(session, tmp_path):
    bare = tmp_path / "bare"
    bare.mkdir()
    for f in session.iterdir():
        if f.name != FILE_NAME:
            (bare / f.name).symlink_to(f)
    with pytest.raises(ValueError, match="no dual-antenna reference"):
        run.replay(bare, tmp_path / "out", aid_heading=True)


def test_streaming_attitude_input_is_checked():
    f = flt.streaming()
    with pytest.raises(ValueError, match="attitude row 0"):
        f.push_attitude(0.0, 0.1, sigma_yaw=0.0)  # no sigma: not a measurement
    f.push_attitude(1.0, 0.1, sigma_yaw=0.01)
    with pytest.raises(ValueError, match="attitude row 1"):
        f.push_attitude(0.5, 0.1, sigma_yaw=0.01)  # back in time
    assert isinstance(_core.InsConfig().antenna_baseline_body, np.ndarray)
