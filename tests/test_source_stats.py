"""run.json's per-source statistics, gathered chunk by chunk (nav.noise_from_data.SourceStats, running
sums and one value per update), against the same statistics computed here in plain NumPy over the whole
updates table of a replay, read back from updates.parquet."""

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from gpsins.nav import noise_from_data
from gpsins.nav import runs as flt
from gpsins.replay import run

WALK = Path(__file__).parent / "data" / "walk_0827" / "walk_0827.toml"


def plain_stats(u: dict) -> dict:
    out = {}
    for k in np.unique(u["kind"]):
        sel = u["kind"] == k
        nis, dof = u["nis"][sel], u["dof"][sel].astype(float)
        ok = np.isfinite(nis) & (dof > 0)
        per_dof = nis[ok] / dof[ok]
        z = u["innovation"][sel] / u["innovation_sigma"][sel]
        lag1 = []
        for col in z.T:
            c = col[np.isfinite(col)]
            if len(c) >= 3:
                c = c - c.mean()
                lag1.append(np.dot(c[:-1], c[1:]) / np.dot(c, c))
        out[flt.UPDATE_KINDS.get(int(k), str(int(k)))] = {
            "n": int(sel.sum()), "nis_per_dof_mean": per_dof.mean(), "nis_per_dof_median": np.median(per_dof),
            "rejected_fraction": np.mean(~u["accepted"][sel]),
            "downweighted": int(np.sum((u["r_scale"][sel] > 1.0) & u["accepted"][sel])),
            "lag1_autocorrelation": np.mean(lag1)}
    return out


def assert_same(got: dict, want: dict) -> None:
    assert got.keys() == want.keys()
    for k in want:
        assert got[k] == pytest.approx(want[k], rel=1e-9), k


def test_chunked_source_statistics_equal_the_whole_tables(tmp_path):
    res = run.replay(WALK, tmp_path / "walk", mode="loose")
    t = pq.read_table(res.out / "updates.parquet").to_pydict()
    u = {k: np.asarray(t[k]) for k in ("kind", "dof", "nis", "accepted", "r_scale")}
    u["innovation"] = np.column_stack([t[f"innovation_{i}"] for i in range(3)])
    u["innovation_sigma"] = np.column_stack([t[f"innovation_sigma_{i}"] for i in range(3)])
    want = plain_stats(u)
    assert len(want) >= 3  # fixes, their velocities and the standstill updates
    assert_same(res.summary["sources"], want)  # the replay's own chunks
    rng = np.random.default_rng(1)
    cuts = np.sort(rng.choice(np.arange(1, len(u["kind"])), 40, replace=False))
    stats = noise_from_data.SourceStats()
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(u["kind"])]])):
        stats.add({k: v[a:b] for k, v in u.items()})
    assert_same(stats.result(), want)
