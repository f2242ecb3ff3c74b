"""The 43-minute drive (scenario `long`): consistency and accuracy of the loose
and tight filters with the default preset.

    python benchmarks/bench_long.py [SEEDS] [--white]

For each seed: loose and tight with the default preset (loose: the fixes' correlated error as
Gauss-Markov states per unit of DOP; tight: every 10 Hz epoch with the pseudoranges' correlated
variance). With --white also the models before: loose with white fixes (UERE 3 m), tight with
white pseudoranges thinned to 1 Hz. Printed: the 9-state NEES averaged over the run (from the first
known heading on) and the share of epochs inside the one-run 95 % band of chi-square(9), the
horizontal RMS error, rejected updates and GNSS resets.
"""

import sys

import numpy as np

from gpsins import evaluate, sim
from gpsins.nav import runs as flt
from gpsins.nav import config as nav_config
from gpsins.sim import scenario

WHITE_FIXES = {"fix_uere_m": 3.0, "fix_uere_2d_m": 0.0, "fix_error_gm_sigma_m": 0.0}
WHITE_1HZ = {"pseudorange_decimation": 10, "pseudorange_error_gm_sigma_m": 0.0}


def run(s, mode: str, over: dict):
    cfg = nav_config.load_config(None, {**sim.imu_noise_truth(s.scenario.imu), "mode": mode, **over})
    extra = sim.tight_inputs(s) if mode == "tight" else {}
    return flt.run(sim.imu_table(s), sim.fix_table(s), cfg, covariance=True, output_every=16, **extra)


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    seeds = int(args[0]) if args else 1
    cases = [("loose", "loose", {}), ("tight", "tight", {})]
    if "--white" in sys.argv:
        cases += [("loose white", "loose", WHITE_FIXES), ("tight 1 Hz white", "tight", WHITE_1HZ)]
    lo, hi = evaluate.nees_band(9, 1)
    for seed in range(seeds):
        s = sim.simulate(scenario.load("long"), seed)
        tr = evaluate.Truth(s.truth.t, s.truth.r_ecef, s.truth.v_ecef, s.truth.q_eb)
        for name, mode, over in cases:
            sol = run(s, mode, over)
            err = evaluate.nav_errors(sol, tr)
            sel = sol.heading_known
            e = evaluate.nees(err.e9[sel], sol.covariance[sel][:, :9, :9])
            h = np.hypot(err.r_ned[sel, 0], err.r_ned[sel, 1])
            c = sol.counters
            print(f"seed {seed} {name:16s}: mean NEES {e.mean():5.2f} (epochs inside {lo:.1f}..{hi:.1f}: "
                  f"{100 * np.mean((e >= lo) & (e <= hi)):4.1f} %), H RMS {np.sqrt(np.mean(h ** 2)):.2f} m, "
                  f"final {np.linalg.norm(err.r_ned[-1]):.2f} m, rejected {c['updates_rejected']}, "
                  f"resets {c['gnss_resets']}", flush=True)


if __name__ == "__main__":
    main()
