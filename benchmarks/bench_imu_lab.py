"""The IMU lab workflow over many simulated lab days.

For each seed: simulate a BP3010 lab day (quick day by default, --full for the
report's ten-minute positions and a two-hour drift run), run the lab plan, and
compare every calibration parameter with the truth: the table gives, per
parameter, the coverage of the 3-sigma intervals (fraction of seeds with
|estimate - truth| <= 3 sigma) and the RMS of the normalised error (about 1
when the stated uncertainty is honest). Then the generated preset of each seed
and the hand-written `default` preset run the filter on the simulated default
drive (same drive seed): horizontal position RMS errors side by side.

    python benchmarks/bench_imu_lab.py --seeds 20 --out bench_lab
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins import evaluate, sim
from gpsins.sim import scenario
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.imu import lab
from gpsins.imu import lab_plan
from gpsins.sim import lab as sim_lab


def _range(day, name, window_s):
    s = next(x for x in day.sessions if x.name == name)
    return s.i0 + int(round(window_s[0] * day.rate_hz)), s.i0 + int(round(window_s[1] * day.rate_hz))


def parameters(day, res) -> dict[str, tuple[float, float, float]]:
    """name -> (estimate, sigma, truth)."""
    tr = day.truth()
    out = {}
    for i, a in enumerate("xyz"):
        v = res["updown"]["axes"][a]
        up, dn = _range(day, f"updown_{a}", v["up"]["window_s"]), _range(day, f"updown_{a}", v["down"]["window_s"])
        b = 0.5 * (day.true_bias("accel", *up)[i] + day.true_bias("accel", *dn)[i])
        out[f"accel_bias_{a}"] = (v["bias_mps2"], v["bias_sigma_mps2"], b)
        out[f"accel_sf_{a}"] = (v["scale_factor"], v["scale_factor_sigma"], tr["accel_scale_factor"][i])
        r = res["rate_table"]["axes"][a]
        out[f"gyro_sf_{a}"] = (r["scale_factor"], r["scale_factor_sigma"], tr["gyro_scale_factor"][i])
        runs = [s for s in day.sessions if s.kind == "rate_table" and s.axis == a]
        out[f"gyro_line_bias_{a}"] = (r["bias_rad_per_s"], r["bias_sigma_rad_per_s"],
                                      day.true_bias("gyro", runs[0].i0, runs[-1].i1)[i])
        d = res["drift"][a]
        out[f"gyro_drift_bias_{a}"] = (d["bias_rad_per_s"], d["bias_sigma_rad_per_s"],
                                       day.true_bias("gyro", *_range(day, "drift", d["window_s"]))[i])
    return out


def horizontal_rms(s, cfg) -> float:
    sol = flt.run(sim.imu_table(s), sim.fix_table(s), cfg)
    tr = s.truth
    err = evaluate.nav_errors(sol, evaluate.Truth(tr.t, tr.r_ecef, tr.v_ecef, tr.q_eb))
    return float(np.sqrt(np.mean(np.sum(err.r_ned[:, :2] ** 2, 1))))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--full", action="store_true", help="the report's lab day (10 min positions, 2 h drift run)")
    ap.add_argument("--out", type=Path, help="write the figures here")
    args = ap.parse_args()
    cfg = sim_lab.LabDayConfig() if args.full else sim_lab.LabDayConfig.quick()
    rows, presets = [], []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            day = sim_lab.simulate_lab_day(cfg, seed)
            plan = sim_lab.write_lab_day(day, Path(tmp) / f"day{seed}")
            p = lab_plan.load_plan(plan)
            res = lab.run_plan(p)
            rows.append(parameters(day, res))
            presets.append(lab.calibration_table(res, p))
    t_lab = time.perf_counter() - t0
    names = list(rows[0])
    z = {n: np.array([(r[n][0] - r[n][2]) / r[n][1] for r in rows]) for n in names}
    print(f"{args.seeds} simulated lab days ({'full' if args.full else 'quick'}), {t_lab:.0f} s")
    print(f"{'parameter':22s} {'coverage 3 sigma':>16s} {'RMS z':>7s} {'median sigma':>13s} {'RMS error':>10s}")
    for n in names:
        sig = np.median([r[n][1] for r in rows])
        err = np.sqrt(np.mean([(r[n][0] - r[n][2]) ** 2 for r in rows]))
        print(f"{n:22s} {np.mean(np.abs(z[n]) <= 3):16.2f} {np.sqrt(np.mean(z[n] ** 2)):7.2f} {sig:13.2e} {err:10.2e}")
    # The generated presets against the hand-written one on the default drive.
    drive = scenario.load("default")
    comp = []
    for seed, p in enumerate(presets):
        s = sim.simulate(drive, seed=seed)
        comp.append((horizontal_rms(s, nav_config.load_config("default")),
                     horizontal_rms(s, nav_config.load_config(None, p))))
        print(f"  seed {seed}: default {comp[-1][0]:.3f} m, generated {comp[-1][1]:.3f} m", flush=True)
    comp = np.array(comp)
    print(f"\ndefault drive, horizontal position RMS (m) over {len(comp)} seeds:")
    print(f"  hand-written default preset: mean {comp[:, 0].mean():.3f}, max {comp[:, 0].max():.3f}")
    print(f"  lab-generated preset:        mean {comp[:, 1].mean():.3f}, max {comp[:, 1].max():.3f}")
    print(f"  generated no worse than default on {np.mean(comp[:, 1] <= comp[:, 0] * 1.02):.0%} of seeds (2 % margin)")
    if args.out:
        figures(args.out, rows, names, z, comp)
        print(f"figures in {args.out}")


def figures(out: Path, rows, names, z, comp) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    fig, axs = plt.subplots(1, 5, figsize=(18, 4))
    groups = ("accel_bias", "accel_sf", "gyro_sf", "gyro_line_bias", "gyro_drift_bias")
    for ax, g in zip(axs, groups):
        for k, a in enumerate("xyz"):
            est, sig, tru = rows[0][f"{g}_{a}"]
            ax.errorbar([k], [est - tru], yerr=[3 * sig], fmt="o", capsize=4)
        ax.axhline(0, color="grey", lw=0.8)
        ax.set_xticks(range(3), list("xyz"))
        ax.set_title(f"{g}: estimate - truth, ±3 sigma (seed 0)", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "recovered_vs_truth.png", dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(12, 4))
    cov = [np.mean(np.abs(z[n]) <= 3) for n in names]
    ax.bar(range(len(names)), cov)
    ax.axhline(0.997, color="r", lw=0.8, label="Gaussian 3-sigma coverage")
    ax.set_xticks(range(len(names)), names, rotation=60, fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_title(f"coverage of the 3-sigma intervals over {len(rows)} seeds")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "coverage.png", dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(comp[:, 0], comp[:, 1], "o")
    lim = [0, comp.max() * 1.1]
    ax.plot(lim, lim, color="grey", lw=0.8)
    ax.set_xlabel("default preset: horizontal RMS (m)")
    ax.set_ylabel("lab-generated preset: horizontal RMS (m)")
    ax.set_title("default drive, one point per seed")
    fig.tight_layout()
    fig.savefig(out / "preset_comparison.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
