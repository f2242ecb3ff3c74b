"""The plan of one filter mode's run over decoded inputs (``Plan``, made by ``plan``): the mode and point
checked, the configuration assembled, the outages' fixes and pseudoranges removed, the statistics and the
mounting taken from the recording where asked, and the reference system's heading as an aiding input.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..evaluate import outages as outages_mod
from ..formats import gpstime
from ..formats import reference as reference_mod
from ..nav import config as nav_config
from ..nav import constraint_noise, lever_arm, mounting, noise_from_data
from ..nav import runs as flt
from ..session import layouts
from .inputs import Inputs
from .scoring import reference_system, heading_aiding

MODES = ("loose", "tight", "ins")
POINTS = ("antenna", "imu")


def _with_estimated_mounting(imu, fixes: np.ndarray, cfg: dict) -> tuple[dict, dict | None]:
    """The car's body-to-vehicle yaw and pitch from a first pass without the non-holonomic constraint
    (``mounting.estimate``), put into the configuration; unchanged when the drive cannot show them."""
    step = max(1, int(round(float(cfg.get("imu_rate_hz", 100.0)) / 10.0)))  # 10 Hz is plenty for a median
    first = flt.run(imu, fixes, {**cfg, "nonholonomic_constraint": False}, mode="loose", output_every=step)
    found = mounting.estimate(first.t, first.q_eb, first.v_ecef, first.heading_known)
    if found is None:
        return cfg, None
    out = {k: v for k, v in cfg.items() if k not in ("body_to_vehicle_ypr_rad", "body_to_vehicle_ypr_deg")}
    out["body_to_vehicle_ypr_deg"] = [found["yaw_deg"], found["pitch_deg"], 0.0]
    return out, found


def lever_arm_body_m(cfg: dict) -> np.ndarray:
    return np.broadcast_to(np.asarray(cfg.get("lever_arm_body_m", 0.0), float), (3,)).copy()


@dataclass
class Plan:
    """What one mode's run is to be: its configuration and the measurements it gets."""

    mode: str  # loose, tight or ins
    filter_mode: str  # the filter that runs: ins is the loose filter
    source: Path
    spec: outages_mod.OutageSpec | None  # the outages asked for (or the data set's)
    schedule: np.ndarray  # (k, 2) outage spans
    cfg: dict  # the configuration (an INS run's first pass adds its searched heading)
    fixes: np.ndarray  # the fixes the filter gets: outages removed (an INS run's: up to its free start)
    fix_out: np.ndarray  # which of the receiver's fixes an outage removed
    prs: np.ndarray | None  # the tight filter's pseudoranges, outages removed
    prs_removed: int
    n_imu: int
    tight: dict  # the tight filter's further inputs (pseudoranges, ephemerides, ...)
    noise_fit: dict | None
    mount_fit: dict | None
    constraint_fit: dict | None  # the vehicle constraint's interval and sigmas, measured (nav.constraint_noise)
    lever_fit: dict | None  # the antenna's lever arm from the recording (nav.lever_arm)
    ref_system: object  # the session's reference system (reference.csv), if any
    attitude: np.ndarray | None  # its heading and pitch as aiding (--aid-heading)
    clock: dict = field(default_factory=dict)  # wall times so far (run.json's wall_time_s)


def plan(inp: Inputs, *, mode: str, overrides: dict | None, outages, point: str, smooth: bool, aid_heading: bool,
         estimator) -> Plan:
    """The plan of a run of ``mode`` over ``inp`` (arguments as for ``run.run_mode``); raises on a
    combination that cannot run, before the filter does."""
    if mode not in MODES:
        raise ValueError(f"--mode {mode!r}: one of {', '.join(MODES)}")
    if point not in POINTS:
        raise ValueError(f"--point {point!r}: one of {', '.join(POINTS)}")
    if mode == "tight" and inp.kind == "session" and inp.pseudoranges is None:
        raise ValueError(f"{inp.source}: inputs were decoded without pseudoranges (load_inputs modes)")
    source = inp.source
    overrides = dict(overrides or {})
    if outages_mod.is_none(outages):
        spec = None
    else:
        spec = outages_mod.parse(outages) if isinstance(outages, str) else outages
        spec = spec if spec is not None else inp.outage_spec
    clock = {k: v for k, v in inp.info.items() if k in ("decode_s", "align_s")}
    filter_mode = "loose" if mode == "ins" else mode
    schedule = outages_mod.schedule(spec, *inp.gnss_span) if spec is not None else np.zeros((0, 2))
    if spec is not None and not len(schedule):
        raise layouts.LogError(f"{source}: outages {spec.text()}: none falls inside the GNSS span, "
                               f"{inp.gnss_span[1] - inp.gnss_span[0]:.1f} s from its first epoch")

    ins_overrides = {"zero_velocity_updates": False} if mode == "ins" else {}
    cfg = nav_config.load_config(inp.base_config, {**inp.data_config, **overrides, **ins_overrides,
                                                   "mode": filter_mode})
    fix_out = outages_mod.inside(inp.fixes[:, 0], schedule)
    fixes = inp.fixes[~fix_out]
    prs = inp.pseudoranges if filter_mode == "tight" else None
    n_imu, n_prs = len(inp.imu), len(prs) if prs is not None else 0
    if prs is not None and len(schedule):  # a copy only when something is left out (a day's table is 200 MB)
        prs = prs[~outages_mod.inside(prs[:, 0], schedule)]
    prs_removed = n_prs - len(prs) if prs is not None else 0
    tight = {}
    if filter_mode == "tight":
        tight = dict(pseudoranges=prs if prs is not None else np.zeros((0, 5)), ephemerides=inp.ephemerides,
                     klobuchar=inp.klobuchar, gps_time_offset_s=inp.week * gpstime.SECONDS_PER_WEEK)

    if estimator is not None and (mode == "ins" or smooth or aid_heading):
        raise ValueError(f"--estimator {estimator}: not with --mode ins, --smooth or --aid-heading (the built-in "
                         "filter's)")
    noise_fit = mount_fit = constraint_fit = lever_fit = None
    # (A plug-in gets the configuration and fixes these make: what the built-in filter would run with.)
    if cfg.get("fit_noise") and filter_mode == "loose" and len(fixes):
        # The statistics from the recording: fitted on the fixes this run uses (outages removed),
        # without the vehicle constraint, whose mounting may not be known yet.
        t_fit = time.perf_counter()
        noise_fit = noise_from_data.fit_noise(inp.imu, fixes, {**cfg, "nonholonomic_constraint": False},
                                              mode=filter_mode)
        cfg, fixes = noise_from_data.scaled(cfg, fixes, noise_fit["factors"])
        clock["noise_fit_s"] = time.perf_counter() - t_fit
    if cfg.get("estimate_mounting") and cfg.get("nonholonomic_constraint") and filter_mode == "loose" and len(fixes):
        cfg, mount_fit = _with_estimated_mounting(inp.imu, fixes, cfg)
    if cfg.get("fit_noise") and cfg.get("nonholonomic_constraint") and filter_mode == "loose" and len(fixes):
        # The constraint's own errors (a car's ride above all), measured with the mounting known.
        cfg, constraint_fit = constraint_noise.fit_constraint(inp.imu, fixes, cfg)
    if mount_fit is not None:
        # With the constraint's noise known, the mounting the constraint and the fixes agree on best.
        t_fit = time.perf_counter()
        mount_fit = mounting.refine(inp.imu, fixes, cfg, mount_fit)
        cfg = {**cfg, "body_to_vehicle_ypr_deg": [mount_fit["yaw_deg"], mount_fit["pitch_deg"], 0.0]}
        clock["mounting_refine_s"] = time.perf_counter() - t_fit
    if filter_mode == "loose" and len(fixes):
        # Last the lever arm, where the data set knows it only roughly: with the noise, the mounting and the
        # constraint fitted first, its likelihood does not take up their misfit (the simulated mismatched car,
        # seeds 0-2: drift with the fit 0.92-1.03 x the run stated exactly, 0.99-1.30 x with the lever first,
        # when the fits ran with the gate off; 0.89-1.06 x since).
        t_fit = time.perf_counter()
        lever_fit = lever_arm.fit(inp.imu, fixes, cfg, mode=filter_mode)
        if lever_fit is not None:
            cfg = {**cfg, "lever_arm_body_m": lever_fit["lever_arm_body_m"]}
            clock["lever_arm_fit_s"] = time.perf_counter() - t_fit

    ref_system = reference_system(source)
    attitude = None
    if aid_heading:
        if ref_system is None:
            raise ValueError(f"{source}: --aid-heading: no dual-antenna reference ({reference_mod.FILE_NAME}) beside "
                             "the session")
        attitude = heading_aiding(ref_system, inp.week)
        if mode == "ins":
            raise ValueError(f"{source}: --aid-heading and --mode ins: free inertial navigation takes no aiding")
    return Plan(mode, filter_mode, source, spec, schedule, cfg, fixes, fix_out, prs, prs_removed, n_imu, tight,
                noise_fit, mount_fit, constraint_fit, lever_fit, ref_system, attitude, clock)
