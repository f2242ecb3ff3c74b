"""gpsins batch (issue 40): two arms over many recordings on Dask, paired. The interval is checked
against scipy's own paired t-test; the runs against single replays."""

import csv
import json

import numpy as np
import pytest
from scipy import stats

from gpsins.montecarlo import batch
from gpsins.replay import run
from gpsins import sim
from gpsins.montecarlo.runner import open_client
from gpsins.sim.session import write_session

from drives import stand_and_drive
from test_montecarlo import external_cluster

WALK = "data/walk_0827"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Eight simulated sessions (60 s each, seeds 0-7) and the walk's data sets, in one directory tree."""
    root = tmp_path_factory.mktemp("batch")
    sc = stand_and_drive("short", 15, 45)
    for seed in range(8):
        write_session(sim.simulate(sc, seed=seed), root / "sessions" / f"s{seed}")
    from pathlib import Path

    listing = root / "recordings.txt"
    listing.write_text(f"sessions\n{Path(__file__).parent / WALK / 'walk_0827.toml'}\n"
                       f"{Path(__file__).parent / WALK / 'walk_0827_ubx.toml'}\n")
    return root, listing


def test_two_presets_paired_over_ten_recordings_on_two_local_workers(recordings, tmp_path):
    root, listing = recordings
    arms = (batch.Arm("default"), batch.Arm("report2005", "report2005"))
    with open_client(None, 2) as client:
        comparison = batch.run([listing], arms, tmp_path / "b", outages="20:10:30", client=client)
    assert comparison["recordings"] == 10 and not comparison["failed"]
    rows = list(csv.DictReader(open(tmp_path / "b" / "batch.csv")))
    assert len(rows) == 20
    # One row against a replay of its own.
    r = next(x for x in rows if x["arm"] == "report2005" and x["recording"].endswith("s3"))
    alone = run.replay(r["recording"], tmp_path / "alone", config="report2005", outages="20:10:30")
    assert float(r["h_rms_m"]) == pytest.approx(alone.summary["errors"]["horizontal_rms_m"], rel=1e-12)
    # The paired interval against scipy's paired t-test.
    by = {(x["recording"], x["arm"]): float(x["h_rms_m"]) for x in rows}
    a = np.array([by[(k, "default")] for k, arm in by if arm == "default"])
    b = np.array([by[(k, "report2005")] for k, arm in by if arm == "default"])
    ci = stats.ttest_rel(b, a).confidence_interval(0.95)
    got = comparison["h_rms_m"]
    print(f"H RMS default {a.mean():.2f} m, report2005 {b.mean():.2f} m, difference {got['mean_difference']:+.2f} "
          f"95 % {got['t_interval']}, bootstrap {got['bootstrap_interval']}, wins {got['wins_b']}/{got['n']}")
    assert got["t_interval"] == pytest.approx([ci.low, ci.high], rel=1e-9)
    assert got["bootstrap_interval"][0] <= got["mean_difference"] <= got["bootstrap_interval"][1]
    assert got["wins_b"] + got["losses_b"] <= got["n"] == 10
    assert json.loads((tmp_path / "b" / "paired.json").read_text())["recordings"] == 10
    assert (tmp_path / "b" / "paired.png").stat().st_size > 10000


def test_batch_on_a_scheduler_the_user_runs(recordings, tmp_path):
    """A plug-in as arm B, on `dask scheduler` and two `dask worker` processes started separately."""
    root, _ = recordings
    from dask.distributed import Client

    arms = (batch.Arm("default"), batch.Arm("builtin", None, "gpsins.nav.estimator:builtin"))
    with external_cluster(tmp_path, 2) as (address, worker_pids), Client(address) as client:
        comparison = batch.run([root / "sessions" / f"s{k}" for k in range(4)], arms, tmp_path / "b",
                               client=client)
    rows = list(csv.DictReader(open(tmp_path / "b" / "batch.csv")))
    assert len(worker_pids) == 2 and {int(r["worker_pid"]) for r in rows} == worker_pids  # both worked
    # The built-in filter as a plug-in is the built-in filter: every difference is zero.
    assert comparison["h_rms_m"]["n"] == 4 and comparison["h_rms_m"]["mean_difference"] == 0.0


def test_a_recording_that_fails_is_a_row_not_a_lost_batch(recordings, tmp_path):
    root, _ = recordings
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "session.json").write_text("{}")
    with open_client(None, 1) as client:
        comparison = batch.run([root / "sessions" / "s0", bad], (batch.Arm("default"), batch.Arm("r", "report2005")),
                               tmp_path / "b", client=client)
    assert comparison["recordings"] == 2 and len(comparison["failed"]) == 2
    assert comparison["h_rms_m"]["n"] == 1
