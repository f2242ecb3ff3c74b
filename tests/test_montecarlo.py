"""Monte Carlo on Dask: the aggregate statistics against an independent computation with known
inputs, and whole runs on a scheduler and a worker started as separate processes with Dask's own
command-line tools, checked against the same seeds run in this process."""

import contextlib
import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

import gpsins
from gpsins import cli, evaluate
from gpsins.replay import results
from gpsins.sim import scenario
from gpsins.montecarlo.runner import Plan, open_client, run_plan
from gpsins.montecarlo import aggregate, tasks

SHORT = """name = "short"
description = "45 s: standing, pulling away, a turn, faster"
[start]
gps_week = 1590
gps_tow_s = 419400.0
lat_deg = 59.37
lon_deg = 17.95
height_m = 30.0
heading_deg = 160.0
[[segment]]
label = "Start-A"
duration_s = 10
speed_mps = 0
[[segment]]
label = "A-B"
duration_s = 8
speed_mps = 8
[[segment]]
label = "B-C"
duration_s = 12
turn_deg = 70
[[segment]]
label = "C-D"
duration_s = 15
speed_mps = 11
"""
SEEDS = (3, 4, 5)
START_TIMEOUT_S = 120  # a busy 2-core machine starts a Python process slowly


# --- the statistics, with known inputs ---

def _random_covariance(rng, n=9):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.diag(rng.uniform(0.1, 10.0, n))


def test_the_nees_band_is_the_chi_square_band_of_the_run_average():
    for runs in (1, 5, 20):
        lo, hi = aggregate.nees_band(9, [runs], alpha=0.05)
        assert lo[0] == pytest.approx(chi2.ppf(0.025, 9 * runs) / runs, rel=1e-12)
        assert hi[0] == pytest.approx(chi2.ppf(0.975, 9 * runs) / runs, rel=1e-12)
    assert aggregate.nees_band(9, [20])[0][0] == pytest.approx(evaluate.nees_band(9, 20)[0])


def _nees_of(errors, p):
    """e^T P^-1 e with an explicit inverse (not the module's solve)."""
    return np.einsum("rki,ij,rkj->rk", errors, np.linalg.inv(p), errors)


def test_gaussian_errors_with_their_true_covariance_fall_in_the_band_95_percent_of_the_time():
    rng = np.random.default_rng(17)
    p = _random_covariance(rng)
    runs, epochs = 20, 4000
    e = rng.multivariate_normal(np.zeros(9), p, size=(runs, epochs))
    got = aggregate.aggregate_nees(_nees_of(e, p), alpha=0.05)
    # Inside the band: binomial(4000, 0.95), sd 0.0034.
    assert got["fraction_inside"] == pytest.approx(0.95, abs=0.015)
    assert got["fraction_below"] == pytest.approx(0.025, abs=0.01)
    assert got["time_averaged"] == pytest.approx(9.0, abs=0.1)  # sd of the mean of 80000 chi2(9): 0.015
    assert got["band_all_runs"] == pytest.approx([chi2.ppf(0.025, 180) / 20, chi2.ppf(0.975, 180) / 20])
    # A filter that claims half the true variance is seen as inconsistent.
    bad = aggregate.aggregate_nees(_nees_of(e, p / 2), alpha=0.05)
    assert bad["fraction_above"] > 0.9 and bad["time_averaged"] == pytest.approx(18.0, abs=0.3)


def test_an_epoch_where_only_some_runs_have_a_nees_uses_its_own_band():
    nees = np.array([[np.nan, 9.0, 2.0], [np.nan, np.nan, 30.0], [np.nan, 8.0, 1.0]])
    got = aggregate.aggregate_nees(nees, alpha=0.05)
    s = got["series"]
    assert np.isnan(s["mean"][0]) and list(s["runs"]) == [0, 2, 3]
    assert s["mean"][1] == pytest.approx(8.5) and s["mean"][2] == pytest.approx(11.0)
    assert s["lower"][1] == pytest.approx(chi2.ppf(0.025, 18) / 2)
    assert s["upper"][2] == pytest.approx(chi2.ppf(0.975, 27) / 3)
    assert got["epochs"] == 2 and got["epochs_with_every_run"] == 1
    assert got["time_averaged"] == pytest.approx((8.5 + 11.0) / 2)


def test_nis_cells_with_mixed_dimensions_are_tested_against_the_sum_of_their_dof():
    rng = np.random.default_rng(3)
    runs, cells = 10, 3000
    per_run = []
    for _ in range(runs):
        dof = rng.choice([2, 3], size=(cells, 4))  # four updates per cell: 2-D and 3-D fixes mixed
        nis = rng.chisquare(dof)
        used = rng.random((cells, 4)) < 0.7  # and not every update in every cell
        per_run.append({"nis": np.sum(nis * used, axis=1), "dof": np.sum(dof * used, axis=1).astype(float)})
    got = aggregate.aggregate_nis(per_run, alpha=0.05)
    assert got["fraction_inside"] == pytest.approx(0.95, abs=0.015)
    total_dof = sum(c["dof"].sum() for c in per_run)
    assert got["dof_total"] == total_dof
    assert got["mean_per_dof"] == pytest.approx(1.0, abs=3 * math.sqrt(2 / total_dof))
    assert got["band_mean_per_dof"][0] == pytest.approx(chi2.ppf(0.025, total_dof) / total_dof)
    # Innovations twice as large as the filter thinks: NIS four times too large.
    scaled = aggregate.aggregate_nis([{"nis": 4 * c["nis"], "dof": c["dof"]} for c in per_run])
    assert scaled["fraction_above"] > 0.99


def test_segment_statistics_pool_every_epoch_of_every_run():
    runs = [[{"label": "A", "t0_s": 0.0, "t1_s": 5.0, "n": 100, "h_rms_m": 1.0, "v_rms_m": 2.0, "h_max_m": 3.0,
              "v_max_m": 4.0, "nees9_mean": 9.0}],
            [{"label": "A", "t0_s": 0.0, "t1_s": 5.0, "n": 300, "h_rms_m": 3.0, "v_rms_m": 2.0, "h_max_m": 7.0,
              "v_max_m": 5.0, "nees9_mean": 13.0}]]
    (seg,) = aggregate.aggregate_segments(runs)
    assert seg["h_rms_m"] == pytest.approx(math.sqrt((100 * 1 + 300 * 9) / 400))
    assert seg["v_rms_m"] == pytest.approx(2.0) and seg["h_max_m"] == 7.0 and seg["v_max_m"] == 5.0
    assert seg["nees9_mean"] == pytest.approx((100 * 9 + 300 * 13) / 400)
    assert seg["h_rms_across_runs"]["mean"] == pytest.approx(2.0)


def test_grid_selection_takes_the_nearest_epoch_and_nothing_far_away():
    tau = np.array([0.01, 0.98, 1.01, 3.5])
    got = tasks._on_grid(tau, np.array([1.0, 2.0, 3.0, 4.0]), np.arange(5.0), max_dt=0.05)
    assert np.array_equal(got[:2], [1.0, 3.0]) and np.all(np.isnan(got[2:]))


# --- whole runs on a cluster of separate processes ---

def _python_path() -> str:
    """The gpsins and gpsins_logger under test, for processes started from here."""
    import gpsins_logger

    dirs = [str(Path(gpsins.__file__).parents[1]), str(Path(gpsins_logger.__file__).parents[1])]
    return os.pathsep.join(dirs + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """`dask scheduler` and `dask worker` (one process, one thread), as a user starts them."""
    with external_cluster(tmp_path_factory.mktemp("dask"), 1) as found:
        yield found


@contextlib.contextmanager
def external_cluster(root, workers: int):
    """A scheduler and ``workers`` worker processes of one thread, started as separate processes on
    the loopback interface; yields the scheduler's address and the workers' process ids."""
    sched_file = root / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": _python_path()}
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--dashboard-address", ":0", "--scheduler-file", str(sched_file), "--idle-timeout", "900"],
            env=env, cwd=root, stdout=subprocess.DEVNULL, stderr=open(root / "scheduler.log", "w")))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not (sched_file.exists() and sched_file.stat().st_size) and time.monotonic() < deadline:
            assert procs[0].poll() is None, (root / "scheduler.log").read_text()
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1", "--nworkers", str(workers),
             "--no-dashboard", "--death-timeout", "120", "--memory-limit", "0", "--local-directory", str(root)],
            env=env, cwd=root, stdout=subprocess.DEVNULL, stderr=open(root / "worker.log", "w")))
        from dask.distributed import Client

        with Client(address, timeout=f"{START_TIMEOUT_S}s") as c:
            c.wait_for_workers(workers, timeout=START_TIMEOUT_S)
            worker_pids = set(c.run(os.getpid).values())
        yield address, worker_pids
    finally:
        for p in reversed(procs):
            _stop(p)


@pytest.fixture(scope="module")
def short_scenario(tmp_path_factory):
    path = tmp_path_factory.mktemp("scenario") / "short.toml"
    path.write_text(SHORT, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def remote_run(dask_cluster, short_scenario, tmp_path_factory):
    """`gpsins montecarlo` on the external scheduler."""
    out = tmp_path_factory.mktemp("mc") / "out"
    code = cli.main(["montecarlo", str(short_scenario), "--seeds", str(len(SEEDS)), "--first-seed", str(SEEDS[0]),
                     "--mode", "both", "--scheduler", dask_cluster[0], "--out", str(out), "--quiet"])
    return code, out


def _table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_the_remote_run_has_a_row_per_seed_and_mode_with_finite_values(remote_run, dask_cluster):
    code, out = remote_run
    assert code == 0
    rows = _table(out / "runs.csv")
    expected = sorted((s, m) for s in SEEDS for m in ("loose", "tight"))
    assert sorted((int(r["seed"]), r["mode"]) for r in rows) == expected
    for r in rows:
        assert r["status"] == "ok", r["error"]
        for key in ("horizontal_rms_m", "vertical_rms_m", "nees9_mean", "all_rms_h_m", "simulate_s", "filter_s"):
            assert math.isfinite(float(r[key])), (key, r)
        assert float(r["horizontal_rms_m"]) < 20.0
        # The work ran in the separate worker process, not here.
        pid = int(r["worker"].rsplit(":", 1)[1])
        assert pid in dask_cluster[1] and pid != os.getpid()
    tight = [r for r in rows if r["mode"] == "tight"]
    assert all(int(r["nis_pseudorange_accepted"]) > 0 for r in tight)
    segs = _table(out / "segments.csv")
    assert len(segs) == 2 * len(SEEDS) * 4 and {r["label"] for r in segs} == {"Start-A", "A-B", "B-C", "C-D"}


def test_the_remote_runs_equal_the_same_seeds_run_in_this_process(remote_run, short_scenario, tmp_path):
    _, out = remote_run
    sc = scenario.load(short_scenario)
    rows = {(int(r["seed"]), r["mode"]): r for r in _table(out / "runs.csv")}
    for seed in SEEDS:
        simulated = tasks.simulate_task(sc, seed, str(tmp_path / f"s{seed}" / "session"))
        for mode in ("loose", "tight"):
            here = tasks.replay_task(simulated, {"mode": mode, "out": str(tmp_path / f"s{seed}" / mode)}, 1.0)
            row = rows[(seed, mode)]
            for key, value in here["figures"].items():
                assert float(row[key]) == value or (math.isnan(value) and math.isnan(float(row[key]))), key
            remote = results.load(out / f"seed-{seed:04d}" / mode)
            local = results.load(tmp_path / f"s{seed}" / mode)
            assert set(remote) == set(local)
            for k in local:
                assert np.array_equal(remote[k], local[k], equal_nan=local[k].dtype.kind == "f"), (seed, mode, k)


def test_the_aggregate_nees_is_the_run_average_of_each_runs_nees_on_the_grid(remote_run):
    _, out = remote_run
    agg = json.loads((out / "aggregate.json").read_text())
    (g,) = [g for g in agg["groups"] if g["mode"] == "loose"]
    # Recomputed here from the runs' own results: NEES at the epoch nearest each whole second.
    per_run = []
    for seed in SEEDS:
        z = results.load(out / f"seed-{seed:04d}" / "loose")
        tau = z["t"] - z["seg_t"][0, 0]
        grid = np.arange(len(g["series"]["t_s"]), dtype=float)
        j = np.abs(tau[None, :] - grid[:, None]).argmin(axis=1)
        near = np.abs(tau[j] - grid) <= np.median(np.diff(tau))
        per_run.append(np.where(near, z["nees9"][j], np.nan))
    per_run = np.array(per_run)
    every = np.all(np.isfinite(per_run), axis=0)
    mean = per_run[:, every].mean(axis=0)
    got = np.array(g["nees9"]["series"]["mean"], dtype=float)[every]
    assert np.allclose(got, mean, rtol=1e-12)
    lo, hi = chi2.ppf([0.025, 0.975], 9 * len(SEEDS)) / len(SEEDS)
    assert g["nees9"]["band_all_runs"] == pytest.approx([lo, hi])
    inside = np.mean((mean >= lo) & (mean <= hi))
    n_every = g["nees9"]["epochs_with_every_run"]
    assert n_every == every.sum()
    # The module counts epochs with fewer runs too (each with its band); those are few here.
    n_all = g["nees9"]["epochs"]
    assert abs(g["nees9"]["fraction_inside"] * n_all - inside * n_every) <= n_all - n_every
    assert (out / g["figure"]).stat().st_size > 10_000
    assert set(g["nis"]) >= {"fix_3d", "zero_velocity"}
    assert [s["label"] for s in g["segments"]] == ["Start-A", "A-B", "B-C", "C-D"]


def test_a_sweep_on_a_local_cluster_reaches_the_filter(short_scenario, tmp_path):
    sc = scenario.load(short_scenario)
    plan = Plan(scenario=sc, seeds=[1, 2], out=tmp_path / "sweep", sweep_key="fix_uere_m",
                sweep_values=["1.0", "10.0"], sweep_texts=["1.0", "10.0"], keep="results")
    with open_client(workers=1) as client:
        outcome = run_plan(plan, client, progress=False)
        environ = client.run(lambda: {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")})
    # The local workers keep Dask's thread limit but not its 64 kB heap trim (see open_client).
    assert list(environ.values()) == [{"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1"}]
    rows = _table(tmp_path / "sweep" / "runs.csv")
    assert [(int(r["seed"]), r["fix_uere_m"]) for r in rows] == [(1, "1.0"), (1, "10.0"), (2, "1.0"), (2, "10.0")]
    assert all(r["status"] == "ok" for r in rows)
    nis = {g["fix_uere_m"]: g["nis"]["fix_3d"]["mean_per_dof"] for g in outcome.aggregate["groups"]}
    # Fix sigmas ten times larger: the fixes' NIS shrinks by far more than a factor of five.
    assert nis["10.0"] < nis["1.0"] / 5
    configs = [(tmp_path / "sweep" / f"seed-0001/sweep-0{i}/loose/config.toml").read_text() for i in (0, 1)]
    assert "fix_uere_m = 1.0" in configs[0] and "fix_uere_m = 10.0" in configs[1]
    # keep="results": each seed's session went once its replays had read it.
    assert not (tmp_path / "sweep" / "seed-0001" / "session").exists()
    assert (tmp_path / "sweep" / "seed-0002" / "sweep-01" / "loose" / "results.npz").is_file()


def test_a_run_that_fails_is_a_row_with_its_error(tmp_path, capsys):
    from gpsins.montecarlo import cli as mc_cli, runner

    missing = tmp_path / "no-session"
    failed = tasks.replay_task({"seed": 7, "session": str(missing), "simulate_s": 0.5},
                               {"mode": "loose", "out": str(tmp_path / "r")}, 1.0)
    assert failed["error"].startswith("replay: ") and str(missing) in failed["error"]
    plan = Plan(scenario=scenario.load("default"), seeds=[7], out=tmp_path / "mc")
    plan.out.mkdir()
    agg, files = runner.write_outputs(plan, [failed], 1.0, 1)
    (row,) = _table(plan.out / "runs.csv")
    assert row["status"] == "failed" and row["seed"] == "7" and str(missing) in row["error"]
    assert agg["failed"] == 1 and agg["groups"][0]["succeeded"] == 0
    mc_cli.print_summary(runner.Outcome([failed], agg, files, 1.0, 1), None)
    assert "every run failed" in capsys.readouterr().out


def test_bad_command_lines_fail_in_one_line(short_scenario, tmp_path, capsys):
    assert cli.main(["sweep", str(short_scenario), "--key", "gate_probability", "--values", "0.9,2", "--seeds", "2",
                     "--out", str(tmp_path / "a")]) == 2
    assert "gate_probability=2" in capsys.readouterr().err
    assert cli.main(["montecarlo", str(short_scenario), "--seeds", "2", "--workers", "2", "--scheduler",
                     "tcp://127.0.0.1:1", "--out", str(tmp_path / "b")]) == 2
    assert "--workers" in capsys.readouterr().err
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "x").write_text("")
    assert cli.main(["montecarlo", str(short_scenario), "--seeds", "2", "--out", str(tmp_path / "c")]) == 2
    assert "not empty" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_montecarlo_takes_a_plug_in_estimator(short_scenario, tmp_path, capsys):
    """The built-in filter as a plug-in over two seeds: the same errors per seed as the native runs."""
    runs = {}
    for name, extra in (("native", []), ("plugin", ["--estimator", "gpsins.nav.estimator:builtin"])):
        out = tmp_path / name
        assert cli.main(["montecarlo", str(short_scenario), "--seeds", "2", "--workers", "1", "--out", str(out),
                         "--quiet", *extra]) == 0
        runs[name] = _table(out / "runs.csv")
    assert [r["horizontal_rms_m"] for r in runs["native"]] == [r["horizontal_rms_m"] for r in runs["plugin"]]
    assert cli.main(["montecarlo", str(short_scenario), "--seeds", "1", "--estimator", "nosuch:x", "--out",
                     str(tmp_path / "bad"), "--quiet"]) == 2
    assert "cannot import" in capsys.readouterr().err
