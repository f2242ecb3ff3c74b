"""Two ways of navigating over many recordings, paired (``gpsins batch DIR|LIST ...``).

Every session directory (it holds ``session.json``) and data-set TOML found is replayed by arm A
(``--config A``) and arm B (``--config B`` or ``--estimator X``) as Dask tasks - a local cluster by
default, ``--scheduler ADDRESS`` for one the user runs - and each recording gives one row per arm:
horizontal RMS (against the truth, else the reference), the outage drift RMS, the mean NEES. The
paired comparison, per figure: the mean of B - A over the recordings both arms scored, its 95 %
interval (Student t on the differences, and a paired bootstrap of 10,000 resamples), and the wins and
losses of B (smaller is better for the errors; for NEES, nearer its 9 degrees of freedom).
"""

from __future__ import annotations

import csv
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..replay import results

METRICS = ("h_rms_m", "drift_rms_m", "nees9_mean")
NEES_DOF = 9
BOOTSTRAP = 10000


@dataclass(frozen=True)
class Arm:
    name: str
    config: str | None = None
    estimator: str | None = None


def find_recordings(sources: list[str | Path]) -> list[Path]:
    """Sessions and data sets under directories (recursively), named in a list file, or given."""
    found: list[Path] = []
    for src in map(Path, sources):
        if src.is_dir():
            if (src / "session.json").is_file():
                found.append(src)
                continue
            found += sorted(p.parent for p in src.rglob("session.json"))
            found += sorted(p for p in src.rglob("*.toml") if _is_dataset(p))
        elif src.suffix.lower() == ".toml":
            found.append(src)
        elif src.is_file():  # a list: one path per line, relative to the list
            for line in src.read_text(encoding="utf-8").splitlines():
                if line.strip() and not line.lstrip().startswith("#"):
                    p = Path(line.strip())
                    found += find_recordings([p if p.is_absolute() else src.parent / p])
        else:
            raise FileNotFoundError(2, "no such session, data set, directory or list", str(src))
    return list(dict.fromkeys(p.resolve() for p in found))


def _is_dataset(p: Path) -> bool:
    import tomllib

    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc.get("imu"), dict) and isinstance(doc.get("gnss"), dict)


def replay_task(recording: str, arm: Arm, mode: str, outages: str | None, out: str) -> dict:
    """One recording replayed by one arm, as the row of the batch table."""
    from ..replay import run as replay

    row = {"recording": recording, "arm": arm.name, "out": out, "worker_pid": os.getpid()}
    t0 = time.perf_counter()
    try:
        res = replay.replay(recording, out, mode=mode, config=arm.config, outages=outages, overlap=False,
                            estimator=arm.estimator, force=True)
    except Exception as e:  # one recording that fails is one row that says so, not a lost batch
        return {**row, "error": f"{type(e).__name__}: {e}"}
    s = res.summary
    e, sc = s.get("errors") or {}, s.get("scoring") or {}
    h = e.get("horizontal_rms_m", (sc.get("all") or {}).get("rms_h_m"))
    drift = (sc.get("horizontal_m") or {}).get("rms") if sc.get("n_scored") else None
    return {**row, "h_rms_m": _num(h), "drift_rms_m": _num(drift), "nees9_mean": _num(e.get("nees9_mean")),
            "wall_s": time.perf_counter() - t0}


def _num(x) -> float:
    return float(x) if x is not None and math.isfinite(float(x)) else float("nan")


def paired(a: np.ndarray, b: np.ndarray, metric: str, seed: int = 0) -> dict:
    """B - A over the recordings both scored: mean, 95 % t and bootstrap intervals, wins and losses of B."""
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = int(ok.sum())
    if n == 0:
        return {"n": 0}
    d = b - a
    out = {"n": n, "mean_a": float(a.mean()), "mean_b": float(b.mean()), "mean_difference": float(d.mean())}
    if n >= 2:
        from scipy.stats import t as student_t

        half = float(student_t.ppf(0.975, n - 1) * d.std(ddof=1) / math.sqrt(n))
        rng = np.random.default_rng(seed)
        boot = d[rng.integers(0, n, size=(BOOTSTRAP, n))].mean(axis=1)
        out.update(t_interval=[out["mean_difference"] - half, out["mean_difference"] + half],
                   bootstrap_interval=[float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))])
    better = np.abs(b - NEES_DOF) < np.abs(a - NEES_DOF) if metric == "nees9_mean" else b < a
    worse = np.abs(b - NEES_DOF) > np.abs(a - NEES_DOF) if metric == "nees9_mean" else b > a
    out.update(wins_b=int(better.sum()), losses_b=int(worse.sum()))
    return out


def run(sources, arms: tuple[Arm, Arm], out: str | Path, *, mode: str = "loose", outages: str | None = None,
        client=None) -> dict:
    """Replay every recording by both arms on the Dask client; write batch.csv, paired.json and
    paired.png in ``out``; return the paired comparison."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    recs = find_recordings(sources)
    if not recs:
        raise FileNotFoundError(2, "no session or data set found", ", ".join(map(str, sources)))
    jobs = [(str(r), arm, mode, outages, str(out / arm.name / f"{i:03d}-{r.stem}"))
            for i, r in enumerate(recs) for arm in arms]
    t0 = time.perf_counter()
    futures = [client.submit(replay_task, *j, pure=False) for j in jobs]
    rows = client.gather(futures)
    wall = time.perf_counter() - t0
    with open(out / "batch.csv", "w", newline="", encoding="utf-8") as f:
        cols = ["recording", "arm", *METRICS, "wall_s", "error", "out", "worker_pid"]
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    by = {(r["recording"], r["arm"]): r for r in rows}
    comparison = {"arms": [vars(a) for a in arms], "recordings": len(recs), "wall_s": wall,
                  "failed": [r for r in rows if "error" in r]}
    for m in METRICS:
        comparison[m] = paired(_values(recs, by, arms[0], m), _values(recs, by, arms[1], m), m)
    (out / "paired.json").write_text(results.json_text(comparison) + "\n", encoding="utf-8")
    _figure(recs, by, arms, out / "paired.png")
    return comparison


def _values(recs, by: dict, arm: Arm, metric: str) -> np.ndarray:
    """One arm's figure per recording (NaN where it failed or has none)."""
    return np.array([by[(str(r), arm.name)].get(metric, np.nan) for r in recs], float)


def _figure(recs, by, arms, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(METRICS), figsize=(4.2 * len(METRICS), 4.0))
    labels = {"h_rms_m": "horizontal RMS (m)", "drift_rms_m": "outage drift RMS (m)", "nees9_mean": "mean NEES"}
    for ax, m in zip(axes, METRICS):
        a, b = _values(recs, by, arms[0], m), _values(recs, by, arms[1], m)
        ok = np.isfinite(a) & np.isfinite(b)
        ax.plot(a[ok], b[ok], "o", ms=4)
        if ok.any():
            lo, hi = float(min(a[ok].min(), b[ok].min())), float(max(a[ok].max(), b[ok].max()))
            ax.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="equal")
            ax.legend(loc="upper left", fontsize=8)
        ax.set_xlabel(f"{arms[0].name}: {labels[m]}")
        ax.set_ylabel(f"{arms[1].name}: {labels[m]}")
        ax.set_title(f"{labels[m]}, {int(ok.sum())} recordings", fontsize=9)
    fig.suptitle("each point one recording; below the line B is smaller", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary_lines(comparison: dict) -> list[str]:
    a, b = (x["name"] for x in comparison["arms"])
    lines = [f"{comparison['recordings']} recordings, {b} - {a} ({comparison['wall_s']:.1f} s):"]
    for m in METRICS:
        c = comparison[m]
        if not c.get("n"):
            lines.append(f"  {m}: no recording scored by both")
            continue
        ti = c.get("t_interval")
        interval = f", 95 % [{ti[0]:+.3f}, {ti[1]:+.3f}] (t)" if ti else ""
        lines.append(f"  {m}: {c['mean_a']:.3f} -> {c['mean_b']:.3f}, difference {c['mean_difference']:+.3f}"
                     f"{interval}; {b} better on {c['wins_b']}, worse on {c['losses_b']} of {c['n']}")
    for r in comparison["failed"]:
        lines.append(f"  failed: {r['arm']} {r['recording']}: {r['error']}")
    return lines


__all__ = ["Arm", "find_recordings", "paired", "run", "summary_lines"]
