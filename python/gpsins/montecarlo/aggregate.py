"""Statistics across Monte Carlo runs: NEES and NIS against their chi-square bands, errors per
epoch, per segment and per outage. Plain NumPy/SciPy on the runs' summaries (``tasks.summarise``).

The bands (Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 5.4.2): for a consistent filter the NEES of n states summed over N independent
runs at one epoch is chi-square with n N degrees of freedom, so the run average lies in
[chi2.ppf(alpha/2, n N) / N, chi2.ppf(1 - alpha/2, n N) / N] with probability 1 - alpha.
An epoch where only some runs have a value (before a run initialised) uses its own N.
NIS: all accepted updates of one kind that fall into one grid cell, over all runs, sum to
chi-square with the sum of their dimensions as degrees of freedom (innovations are white
in a consistent filter), whatever mix of dimensions (a 2-D and a 3-D fix, several
pseudoranges) the cell holds.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

NEES_DOF = 9


def nees_band(dof: int, runs, alpha: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided band of the run-averaged NEES for ``runs`` runs (an array: one band per epoch)."""
    runs = np.asarray(runs, float)
    lo = np.full(runs.shape, np.nan)
    hi = np.full(runs.shape, np.nan)
    ok = runs > 0
    lo[ok] = chi2.ppf(alpha / 2, dof * runs[ok]) / runs[ok]
    hi[ok] = chi2.ppf(1 - alpha / 2, dof * runs[ok]) / runs[ok]
    return lo, hi


def _fractions(value: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> dict:
    ok = np.isfinite(value)
    n = int(ok.sum())
    if not n:
        return {"epochs": 0, "fraction_inside": float("nan"), "fraction_below": float("nan"),
                "fraction_above": float("nan")}
    v, a, b = value[ok], lo[ok], hi[ok]
    return {"epochs": n, "fraction_inside": float(np.mean((v >= a) & (v <= b))),
            "fraction_below": float(np.mean(v < a)), "fraction_above": float(np.mean(v > b))}


def aggregate_nees(nees: np.ndarray, dof: int = NEES_DOF, alpha: float = 0.05) -> dict:
    """NEES of R runs on a common grid, (R, K) with NaN where a run has none: the run average per
    epoch, its band, and the share of epochs inside it; the time average of the run average."""
    nees = np.atleast_2d(np.asarray(nees, float))
    count = np.sum(np.isfinite(nees), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, np.nansum(nees, axis=0) / np.maximum(count, 1), np.nan)
    lo, hi = nees_band(dof, count, alpha)
    full = count == nees.shape[0]
    band_n = nees_band(dof, [nees.shape[0]], alpha)
    return {"dof": dof, "runs": int(nees.shape[0]), "alpha": alpha,
            "band_all_runs": [float(band_n[0][0]), float(band_n[1][0])] if nees.shape[0] else [None, None],
            "time_averaged": float(np.nanmean(mean)) if np.isfinite(mean).any() else float("nan"),
            "epochs_with_every_run": int(full.sum()),
            **_fractions(mean, lo, hi),
            "series": {"mean": mean, "lower": lo, "upper": hi, "runs": count}}


def aggregate_nis(cells: list[dict], alpha: float = 0.05) -> dict:
    """NIS of one update kind: ``cells`` per run {"nis": (K,) sums, "dof": (K,) sums} on the grid.
    Per cell the sum over runs against chi-square(sum of dof); overall the mean NIS per degree of
    freedom against chi2(D)/D for all D degrees of freedom."""
    nis = np.sum([c["nis"] for c in cells], axis=0)
    dof = np.sum([c["dof"] for c in cells], axis=0)
    used = dof > 0
    lo, hi = np.full(dof.shape, np.nan), np.full(dof.shape, np.nan)
    lo[used] = chi2.ppf(alpha / 2, dof[used]) / dof[used]
    hi[used] = chi2.ppf(1 - alpha / 2, dof[used]) / dof[used]
    per_dof = np.where(used, nis / np.where(used, dof, 1), np.nan)
    total_dof, total = float(dof.sum()), float(nis.sum())
    out = {"cells": int(used.sum()), "dof_total": total_dof,
           "mean_per_dof": total / total_dof if total_dof else float("nan"),
           "band_mean_per_dof": ([float(chi2.ppf(q, total_dof) / total_dof) for q in (alpha / 2, 1 - alpha / 2)]
                                 if total_dof else [None, None]),
           **{k.replace("epochs", "cells"): v for k, v in _fractions(per_dof, lo, hi).items()},
           "series": {"per_dof": per_dof, "lower": lo, "upper": hi}}
    return out


def rms_across_runs(x: np.ndarray) -> np.ndarray:
    """Root mean square over runs (axis 0) per epoch, ignoring runs without a value."""
    x = np.asarray(x, float)
    n = np.sum(np.isfinite(x), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(np.nansum(x ** 2, axis=0) / np.maximum(n, 1)), np.nan)


def _spread(values) -> dict:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if not len(v):
        return {"n": 0}
    return {"n": int(len(v)), "mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
            "min": float(v.min()), "max": float(v.max()), "rms": float(np.sqrt(np.mean(v ** 2)))}


def aggregate_segments(runs: list[list[dict]]) -> list[dict]:
    """Per segment (in the scenario's order) over runs: pooled RMS (every epoch of every run), the
    worst maximum, the spread of the runs' own RMS, and the epoch-weighted mean NEES."""
    out = []
    for j, first in enumerate(runs[0] if runs else []):
        rows = [r[j] for r in runs if j < len(r) and r[j].get("n")]
        agg = {"label": first["label"], "t0_s": first["t0_s"], "t1_s": first["t1_s"], "runs": len(rows)}
        if rows:
            n = np.array([r["n"] for r in rows], float)
            for axis in ("h", "v"):
                rms = np.array([r[f"{axis}_rms_m"] for r in rows])
                agg[f"{axis}_rms_m"] = float(np.sqrt(np.sum(n * rms ** 2) / n.sum()))
                agg[f"{axis}_max_m"] = float(max(r[f"{axis}_max_m"] for r in rows))
                agg[f"{axis}_rms_across_runs"] = _spread(rms)
            nees = np.array([r["nees9_mean"] for r in rows])
            ok = np.isfinite(nees)
            agg["nees9_mean"] = float(np.sum(n[ok] * nees[ok]) / n[ok].sum()) if ok.any() else float("nan")
        out.append(agg)
    return out


def aggregate_outages(runs: list[list[dict]]) -> list[dict]:
    """Per outage (by index in the schedule) over runs: its span and the spread of the maximum
    horizontal and vertical drift."""
    n = max((len(r) for r in runs), default=0)
    out = []
    for i in range(n):
        rows = [r[i] for r in runs if i < len(r)]
        out.append({"index": i, "start_s": rows[0]["start_s"], "end_s": rows[0]["end_s"], "runs": len(rows),
                    "max_h_m": _spread(r["max_h_m"] for r in rows), "max_v_m": _spread(r["max_v_m"] for r in rows)})
    return out


def aggregate_group(summaries: list[dict], alpha: float = 0.05) -> dict:
    """Everything aggregated over the successful runs of one (mode, value) group."""
    ok = [s for s in summaries if "error" not in s]
    out = {"runs": len(summaries), "succeeded": len(ok), "failed": [
        {"seed": s["seed"], "error": s["error"]} for s in summaries if "error" in s]}
    if not ok:
        return out
    k = min(len(s["series"]["nees9"]) for s in ok)
    grid_s = ok[0]["grid_s"]
    series = {key: np.array([s["series"][key][:k] for s in ok]) for key in ok[0]["series"]}
    nees_all = aggregate_nees(series["nees9"], alpha=alpha)
    nees_hk = aggregate_nees(np.where(series["heading_known"], series["nees9"], np.nan), alpha=alpha)
    kinds = sorted({kind for s in ok for kind in s["nis_cells"]})
    nis = {}
    for kind in kinds:
        cells = [{"nis": s["nis_cells"][kind]["nis"][:k], "dof": s["nis_cells"][kind]["dof"][:k]}
                 for s in ok if kind in s["nis_cells"]]
        nis[kind] = aggregate_nis(cells, alpha)
        nis[kind]["updates"] = sum(s["nis"][kind]["updates"] for s in ok if kind in s["nis"])
        nis[kind]["accepted"] = sum(s["nis"][kind]["accepted"] for s in ok if kind in s["nis"])
    fig = lambda name: [s["figures"].get(name) for s in ok]  # noqa: E731
    errors = {name: _spread(fig(name)) for name in ("horizontal_rms_m", "horizontal_max_m", "vertical_rms_m",
                                                    "vertical_max_m", "nees9_mean", "inside_3_sigma",
                                                    "all_rms_h_m", "all_rms_v_m", "first_heading_s")}
    out.update(grid_s=grid_s, nees9=nees_all, nees9_heading_known=nees_hk, nis=nis, errors=errors,
               segments=aggregate_segments([s["segments"] for s in ok]),
               outages=aggregate_outages([s["outages"] for s in ok]),
               series={"t_s": np.arange(k) * grid_s,
                       "h_rms_m": rms_across_runs(series["err_h_m"]), "v_rms_m": rms_across_runs(series["err_v_m"]),
                       "sigma_h_rms_m": rms_across_runs(series["sigma_h_m"]),
                       "sigma_v_rms_m": rms_across_runs(series["sigma_v_m"])})
    return out
