"""The report's figures (matplotlib Figure objects, so tests can inspect what each panel holds) and their
captions, from results ``report.data.load`` made. ``report`` builds the pages around them.

Every time axis counts from one origin, ``report.data.time_origin`` (the first GNSS epoch), the same as the
page's tables. An axis whose limits follow the bulk of the data marks what it leaves out with a triangle
at its edge (gid ``EDGE_GID``), one per stretch beyond it.
"""

from __future__ import annotations

from pathlib import Path


from .data import (load_all, KIND_PR, KIND_RR, Result, truth_file, sky_data, time_origin, time_origin_text,
                   true_residual_biases)
from .draw import TimeAxis, plt
from .figures_gnss import (fig_clock, fig_gnss, fig_innovations, fig_satellite_innovations, fig_skyplot,
                           fig_visibility, pseudorange_nis_note)
from .figures_solution import (fig_attitude, fig_bias_sigma, fig_biases, fig_consistency, fig_outage_drift,
                               fig_position_error, fig_sigma, fig_trajectory)


def _time_axis(base: Result) -> TimeAxis:
    return TimeAxis(time_origin(base), f"time ({time_origin_text(base)})")


def build_figures(results: list) -> dict:
    """Every figure of the report, by file name (matplotlib Figures), from results directories, (directory,
    name) pairs or loaded results; the caller saves or inspects and closes them."""
    return _build(load_all(results))


def _build(results: list[Result]) -> dict:
    """Every figure of the report from loaded results."""
    base = results[0]
    tx = _time_axis(base)
    truth = truth_file(base) if base.has_truth else None  # replay --no-truth: none in the figures either
    figs = {"trajectory.png": fig_trajectory(results, base, tx)}
    if base.has_truth:
        figs["position_error.png"] = fig_position_error(results, base, tx)
    figs["attitude.png"] = fig_attitude(results, base, tx)
    figs["sigma.png"] = fig_sigma(results, base, tx)
    figs["biases.png"] = fig_biases(results, base, tx, true_residual_biases(base, truth))
    figs["bias_sigma.png"] = fig_bias_sigma(results, base, tx)
    figs["innovations.png"] = fig_innovations(results, base, tx)
    figs["pseudorange.png"] = fig_satellite_innovations(results, base, tx, KIND_PR)
    figs["range_rate.png"] = fig_satellite_innovations(results, base, tx, KIND_RR)
    figs["gnss.png"] = fig_gnss(results, base, tx)
    figs["consistency.png"] = fig_consistency(results, base, tx)
    figs["clock.png"] = fig_clock(results, base, tx, truth)
    figs["outage_drift.png"] = fig_outage_drift(results, tx)
    sky = sky_data(base)
    if sky is not None and len(sky.obs):
        figs["visibility.png"] = fig_visibility(sky, base, tx)
        figs["skyplot.png"] = fig_skyplot(sky)
    return {k: v for k, v in figs.items() if v is not None}


def figures(results: list, out: Path) -> list[str]:
    """Write every figure as PNG into `out` (results as for ``build_figures``); returns the file names."""
    names = []
    for name, fig in _build(load_all(results)).items():
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)
    return names

EDGE_NOTE = "A triangle at an axis edge stands for values beyond it (the axis follows the bulk of the data)."
CAPTIONS = {
    "trajectory.png": "Horizontal track, metres east and north of the first epoch: each filter's solution, the "
                      "receiver's own fixes (circles) and, with a truth, the true track (dashed). Where the filter "
                      "leaves the fixes or the truth, it has lost its way.",
    "position_error.png": "Position error (estimate minus truth) east, north and up, each filter in its colour with "
                          "its +-3-sigma band shaded in the same colour, and the receiver's own fixes' errors as "
                          "green dots. A consistent filter keeps its error inside its band almost all the time; an "
                          "error that leaves the band is one the filter does not know about. " + EDGE_NOTE,
    "attitude.png": "Attitude error (estimate minus truth) in yaw, pitch and roll with the +-3-sigma band in the "
                    "filter's colour; grey shading: before the heading is known (the yaw error means nothing there). "
                    "Yaw's line is broken where it wraps at +-180 deg. " + EDGE_NOTE,
    "sigma.png": "The filter's standard deviations (log scale) of attitude about the north, east and down axes, of "
                 "velocity and of position; line style: axis. They shrink as updates come and grow without them; "
                 "yaw (down) shrinks only once the motion makes it observable.",
    "biases.png": "Residual gyro and accelerometer bias estimates with their +-3-sigma bands in the filter's colour; "
                  "with a simulated truth, the true residual (truth less the calibration) dashed. The truth should "
                  "stay inside the band; a band that stays wide means the motion did not make that bias observable.",
    "bias_sigma.png": "The bias estimates' standard deviations (log scale); line style: axis. Where one falls, the "
                      "motion (turns, accelerations) made that bias observable.",
    "innovations.png": "Fix innovations (fix minus the filter's prediction) with the innovation's +-3 sigma: 3D "
                       "fixes in ECEF x, y and z, 2D fixes in north and east (the local level their update uses). "
                       "Almost all should lie inside their lines; a run outside is a fix error or a filter that is "
                       "too sure (Table 7.4 lists them). " + EDGE_NOTE,
    "pseudorange.png": "Top: each satellite's pseudorange innovation over its sigma (colour: PRN), with +-3 and the "
                       "gate (rejected updates as crosses). Bottom: their NIS against the 95 % band of chi-square "
                       "with 1 dof; mostly below the band: the update's sigma is wider than its error, above: "
                       "narrower. " + EDGE_NOTE,
    "range_rate.png": "Top: each satellite's range-rate (Doppler) innovation over its sigma (colour: PRN), with +-3 "
                      "and the gate (rejected updates as crosses). Bottom: their NIS against the 95 % band of "
                      "chi-square with 1 dof; mostly below the band: the sigma is wider than the error, above: "
                      "narrower. " + EDGE_NOTE,
    "gnss.png": "Satellites in the receiver's fix (line) and pseudoranges the tight filter used (dots) per epoch, and "
                "the fixes' HDOP and VDOP (log scale). Few satellites and a high DOP explain large fix errors.",
    "consistency.png": "Consistency: the NIS of the fix updates, each kind against the 95 % chi-square band of its "
                       "own dof (3D fixes 3, 2D fixes 2), and with a truth the NEES of the 9 navigation states "
                       "against the 9-dof band. Mostly below a band: the filter is more cautious than its errors "
                       "need; above: over-confident. " + EDGE_NOTE,
    "clock.png": "The tight filter's receiver clock bias and drift (in metres and m/s) with +-3-sigma bands in the "
                 "filter's colour; with a simulated truth, the truth (dashed) and the estimate's error beside it, "
                 "which should stay inside its band. " + EDGE_NOTE,
    "outage_drift.png": "Top: drift from the reference since each outage began (solid: horizontal, dotted: "
                        "vertical; one line per outage and filter). Bottom: horizontal error against the reference "
                        "over time with the outages shaded: the same outages and times as the drift table.",
    "visibility.png": "Satellites the receiver tracked over time, coloured by C/N0; a gap is a lost satellite.",
    "skyplot.png": "Sky tracks of the tracked satellites: azimuth clockwise from north, elevation from the horizon "
                   "(outer circle) to the zenith (centre); the number marks a track's end.",
}
ATTITUDE_WITHOUT_TRUTH = ("Yaw, pitch and roll as each filter estimates them (no truth to compare with); grey "
                          "shading: before the heading is known. Yaw's line is broken where it wraps at +-180 deg.")
TIMELESS = ("trajectory.png", "skyplot.png")


def figure_captions(results: list[Result]) -> dict[str, str]:
    """What each figure shows and how to read it, by file name, with this report's time origin and the
    reasons for what looks wrong by design (the tight filter's low pseudorange NIS)."""
    base = results[0]
    origin = f"Time axes: {time_origin_text(base)}, as in the tables."
    caps = dict(CAPTIONS, **({} if base.has_truth else {"attitude.png": ATTITUDE_WITHOUT_TRUTH}))
    caps = {name: text if name in TIMELESS else f"{text} {origin}" for name, text in caps.items()}
    if "seg_t" in base.a and base.has_truth:
        caps["trajectory.png"] += " Letters: where the truth's segments start."
    notes = [n[1] for r in results if (n := pseudorange_nis_note(r))]
    if notes:
        caps["pseudorange.png"] += " " + " ".join(notes)
    return caps
