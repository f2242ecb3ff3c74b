"""`gpsins allan` and `gpsins calibrate`."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np

from . import allan, calibration, records
from .records import AXES


def _error(message: str) -> Exception:
    """A failure the user can fix, printed by the CLI as one line with exit status 2."""
    from ..errors import CommandError

    return CommandError(message)


GENERIC = "col"  # the name of a single undeclared column


def _one_column(source: str) -> bool:
    """A CSV/NPY file of one column (read as records.load reads it: NPY, CSV by commas, else blanks)."""
    p = Path(source)
    if not p.is_file():
        return False
    try:
        if p.suffix == ".npy":
            shape = np.load(p, mmap_mode="r").shape
            return len(shape) == 1 or (len(shape) == 2 and shape[1] == 1)
        with p.open(encoding="utf-8", errors="replace") as fh:
            for line in fh:
                line = line.split("#", 1)[0].strip()
                if line:
                    return len(line.split(",") if p.suffix == ".csv" else line.split()) == 1
    except (OSError, ValueError):
        return False  # records.load says what is wrong with it
    return False


def load_rates(source: str, rate_hz: float | None, columns: str | None = None, start_s: float | None = None,
               end_s: float | None = None, keep: bool = True):
    """(n, k) rate samples: a session's IMU (gyro rad/s then accel m/s^2) or a CSV/NPY file whose
    columns are declared (six columns default to gyro x y z, accel x y z). One undeclared column
    is analysed as it is, named GENERIC: whether it is rad/s or m/s^2 the file cannot say, and the
    numbers and axes are then in the column's own unit. ``keep=False``: the caller may turn a single
    column into its phase in place; the samples then come with the N + 1 buffer (``records.Record.front``)
    as a fourth item."""
    generic = columns is None and _one_column(source)
    try:
        # records knows only sensor kinds: a gyro column without a unit (factor 1) reads it unchanged.
        rec = records.load(source, rate_hz, "gyro_x" if generic else columns, start_s, end_s, spare_front=not keep)
    except records.RecordError as e:
        raise _error(str(e)) from None
    if not keep:
        rates, rate, names = load_rates_named(source, rec, generic)
        return rates, rate, names, rec.front
    return load_rates_named(source, rec, generic)


def load_rates_named(source: str, rec, generic: bool) -> tuple[np.ndarray, float, tuple[str, ...]]:
    for note in rec.notes:
        print(f"gpsins allan: warning: {source}: {note}", file=sys.stderr)
    if generic:
        print(f"gpsins allan: note: {source}: one undeclared column, analysed in its own unit (u below: rad/s "
              f"for a gyro, m/s^2 for an accelerometer, if it is in SI); --columns gyro_x or accel_x (a unit after "
              f"a colon, e.g. gyro_x:deg/s) names it and gives the report's units", file=sys.stderr)
        return rec.rates, rec.rate_hz, (GENERIC,)
    return rec.rates, rec.rate_hz, rec.columns


def units(name: str) -> dict:
    """Units of a column's rate and of its fitted terms (u for an undeclared column)."""
    from . import noise_fit

    r = noise_fit.rate_unit(name)
    i = {"rad/s": "rad", "m/s^2": "m/s"}.get(r, "u s")  # the integrated rate
    n = f"{i}/sqrt(s)" if r != "u" else "u sqrt(s)"
    return {"rate": r, "psd": f"({r})^2/Hz", "N": n, "B": r, "K": f"{r}/sqrt(s)", "Q": i, "F": i}


def _import_noise_fit() -> None:
    """Import the noise fit (SciPy's optimize: about as long as analysing 10^7 samples) while the
    kernel and the noise identification run on other threads (they let go of the GIL)."""
    from . import noise_fit  # noqa: F401


def run_allan(args) -> int:
    taus = args.taus if args.taus in ("octave", "all", "decade") else int(args.taus)
    estimator = getattr(args, "estimator", "overlapping")
    out = Path(args.out) if args.out else None
    # Without figures the samples are not needed after the deviation: one column's phase is then made in
    # place of it (the record's memory, not twice that).
    front = None
    if out is None and estimator == "overlapping":
        data, rate, names, front = load_rates(args.source, args.rate, getattr(args, "columns", None),
                                              getattr(args, "start_s", None), getattr(args, "end_s", None), keep=False)
    else:
        data, rate, names = load_rates(args.source, args.rate, getattr(args, "columns", None),
                                       getattr(args, "start_s", None), getattr(args, "end_s", None))
    n_samples = len(data)
    st = records.steady_windows(data, rate)
    moved = records.motion_warning(st, len(data) / rate)
    if moved:
        print(f"gpsins allan: warning: {args.source}: {moved}", file=sys.stderr)
    results, fits = {}, {}
    with _progress(data.shape[1]) as advance:
        for k, name in enumerate(names):
            if estimator == "overlapping" and front is not None:
                x = allan.phase_from_rate(data[:, 0], 1.0 / rate, out=front)
                data = None  # overwritten by its phase
                r = allan.oadev(x, rate, taus=taus, data_type="phase", meanwhile=_import_noise_fit)
            elif estimator == "overlapping":
                r = allan.oadev(data[:, k], rate, taus=taus, meanwhile=_import_noise_fit)
            else:
                r = allan.adev_nonoverlapping(data[:, k], rate, taus=taus)
            results[name] = r
            advance()
    from . import noise_fit  # imported meanwhile (oadev), else now

    min_edf = float(getattr(args, "min_edf", noise_fit.MIN_EDF))
    for name, r in results.items():
        fits[name] = noise_fit.fit(r.tau, r.adev, r.edf, min_edf=min_edf)
    for name, f in fits.items():
        if f.fitted_from_tau_s > results[name].tau[0]:
            print(f"gpsins allan: note: {name}: fitted from tau = {f.fitted_from_tau_s:g} s; the shorter taus follow "
                  f"the sensor's output filter, which no term describes", file=sys.stderr)
    print(f"{n_samples} samples at {rate:g} Hz ({n_samples / rate / 3600:.2f} h), {estimator} Allan deviation")
    short = int((next(iter(results.values())).edf < min_edf).sum())
    if short:
        print(f"gpsins allan: note: {short} of {len(next(iter(results.values())).tau)} taus have fewer than "
              f"{min_edf:g} degrees of freedom: shown, not used for slope read-outs", file=sys.stderr)
    if moved:
        print("noise terms withheld: the record moved (see the warning); trim it with --start-s / --end-s")
    else:
        print(f"{'axis':8s} {'N':>11s} {'B':>11s} {'K':>11s} {'Q':>11s} {'F':>11s}  report units")
        for name in names:
            f = fits[name]
            kind = name.split("_")[0]
            tu = noise_fit.table_units(kind, f) if kind in ("gyro", "accel") else {}
            print(f"{name:8s} " + " ".join(f"{f.value.get(t, 0):11.3e}" for t in ("N", "B", "K", "Q", "F")) + "  " +
                  (", ".join(f"{k} {v:.4g}" for k, v in tu.items()) or "-"))
        for kind in dict.fromkeys(n.split("_")[0] for n in names):
            u = units(kind)
            print(f"  {kind}: N {u['N']}, B {u['B']}, K {u['K']}, Q {u['Q']}, F {u['F']} (F: the 1/tau^2 term when "
                  f"negative, the sensor's output filter)")
    if args.json:
        doc = {"rate_hz": rate, "samples": n_samples, "estimator": estimator, "min_edf": min_edf,
               "moved": moved, "axes": {}}
        for name in names:
            r, f = results[name], fits[name]
            doc["axes"][name] = {"tau_s": r.tau.tolist(), "adev": r.adev.tolist(), "lo": r.lo.tolist(),
                                 "hi": r.hi.tolist(), "edf": r.edf.tolist(), "alpha": np.asarray(r.alpha).tolist(),
                                 "confidence": r.confidence,
                                 "eq59_rel_sigma": np.broadcast_to(r.rel_sigma_eq59, r.tau.shape).tolist(),
                                 "eq59_lo": r.eq59_lo.tolist(), "eq59_hi": r.eq59_hi.tolist(),
                                 "fit": None if moved else f.value, "fit_sigma": None if moved else f.sigma,
                                 "fitted_from_tau_s": None if moved else f.fitted_from_tau_s,
                                 "units": units(name),
                                 "slope_readouts": None if moved else f.slope_readouts}
        from ..replay.results import json_text

        Path(args.json).write_text(json_text(doc, indent=1) + "\n", encoding="utf-8")
    if out:
        out.mkdir(parents=True, exist_ok=True)
        _plots(out, names, results, fits, data, rate)
        files = tuple(names) == AXES and not moved
        if files:
            _filter_files(out, fits, rate)
        print(f"figures{' and parameter files' if files else ''} in {out}")
    return 0


class _progress:
    """A transient progress bar over the axes on a terminal (rich), nothing otherwise: ``with
    _progress(total) as advance: ... advance()``."""

    def __init__(self, total: int):
        self.total, self.bar = total, None

    def __enter__(self):
        if not sys.stdout.isatty():
            return lambda: None
        from rich.progress import Progress

        self.bar = Progress(transient=True)
        self.bar.__enter__()
        task = self.bar.add_task("Allan deviation", total=self.total)
        return lambda: self.bar.advance(task)

    def __exit__(self, *exc):
        return self.bar.__exit__(*exc) if self.bar is not None else False


def _plots(out: Path, names, results, fits, data, rate) -> None:
    import matplotlib

    from . import noise_fit, psd

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for group in ("gyro", "accel", GENERIC):
        cols = [n for n in names if n.startswith(group)]
        if not cols:
            continue
        fig, axs = plt.subplots(1, 2, figsize=(12, 5))
        for j, n in enumerate(cols):
            color = f"C{j}"  # one colour per axis: data, band, fit and PSD
            r, f = results[n], fits[n]
            axs[0].loglog(r.tau, r.adev, "o", ms=3, color=color, label=f"{n} data")
            axs[0].fill_between(r.tau, r.lo, r.hi, alpha=0.2, color=color, lw=0)
            axs[0].loglog(r.tau, r.eq59_lo, "--", lw=0.6, color=color)
            axs[0].loglog(r.tau, r.eq59_hi, "--", lw=0.6, color=color)
            fitted = r.tau >= f.fitted_from_tau_s
            axs[0].loglog(r.tau[fitted], f.model_adev[fitted], "-", lw=1, color=color)
            for term in f.terms:
                single = noise_fit.fit_term_curve(r.tau, f, term)
                if single is not None:
                    axs[0].loglog(r.tau, single, ":", lw=0.7, color=color, alpha=0.7)
            fr, p = psd.psd(data[:, names.index(n)], rate)
            fc, pc = psd.log_average(fr, p)
            axs[1].loglog(fc, pc, color=color, label=n)
        axs[0].plot([], [], "k-", lw=1, label="fit")
        axs[0].plot([], [], "k:", lw=0.7, label="fitted terms")
        axs[0].fill_between([], [], [], color="0.5", alpha=0.3, label="confidence band")
        axs[1].legend(fontsize=8)
        axs[0].set_xlabel("tau (s)")
        u = units(group)
        axs[0].set_ylabel(f"Allan deviation ({u['rate']})")
        axs[0].set_title(f"{group}: data, {100 * results[cols[0]].confidence:.0f} % band, fit (solid), "
                         f"terms (dotted), eq. 5.9 (dashed)", fontsize=8)
        axs[0].legend(fontsize=8)
        axs[1].set_xlabel("frequency (Hz)")
        axs[1].set_ylabel(f"one-sided PSD ({u['psd']})")
        axs[1].set_title("PSD, log-averaged" + ("; u: the column's own unit (undeclared)" if group == GENERIC else ""))
        fig.tight_layout()
        fig.savefig(out / f"allan_{group}.png", dpi=110)
        plt.close(fig)


def _vec(fits, prefix, term):
    return [float(fits[f"{prefix}_{a}"].value.get(term, 0.0)) for a in "xyz"]


def _filter_files(out: Path, fits, rate) -> None:
    g_n, a_n = _vec(fits, "gyro", "N"), _vec(fits, "accel", "N")
    g_b, a_b = _vec(fits, "gyro", "B"), _vec(fits, "accel", "B")
    g_k, a_k = _vec(fits, "gyro", "K"), _vec(fits, "accel", "K")
    (out / "imu_noise.toml").write_text(f"""\
# From `gpsins allan`: Allan coefficients, continuous-time (the filter squares N into V = N^2).
# N white noise (gyro rad/sqrt(s) = rad/s/sqrt(Hz); accel m/s/sqrt(s)), B bias instability (rad/s, m/s^2),
# K rate random walk (rad/s/sqrt(s), m/s^2/sqrt(s)). Use as the [imu_noise] table of a filter configuration.
[imu_noise]
gyro_arw_rad_per_sqrt_s = {g_n}
gyro_bias_instability_rad_per_s = {g_b}
gyro_rrw_rad_per_s_sqrt_s = {g_k}
accel_vrw_mps_per_sqrt_s = {a_n}
accel_bias_instability_mps2 = {a_b}
accel_rrw_mps2_per_sqrt_s = {a_k}
bias_tau_s = 100.0
""", encoding="utf-8")
    rms = lambda v: math.sqrt(sum(x * x for x in v) / 3)  # noqa: E731
    (out / "imu.yaml").write_text(f"""\
# Kalibr IMU noise model (continuous time; one value for all axes: the RMS over x, y, z)
accelerometer_noise_density: {rms(a_n):.6e}   # m/s^2/sqrt(Hz)
accelerometer_random_walk: {rms(a_k):.6e}     # m/s^3/sqrt(Hz)
gyroscope_noise_density: {rms(g_n):.6e}       # rad/s/sqrt(Hz)
gyroscope_random_walk: {rms(g_k):.6e}         # rad/s^2/sqrt(Hz)
rostopic: /imu0
update_rate: {rate:g}
""", encoding="utf-8")


def _table(path: str, columns: int) -> np.ndarray:
    from ..errors import CommandError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: said below
            rows = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
    except FileNotFoundError:
        raise CommandError(f"{path}: no such file") from None
    except ValueError as e:
        raise CommandError(f"{path}: not a comma-separated table of numbers ({e})") from None
    if rows.shape[0] == 0 or rows.shape[1] < columns:
        raise CommandError(f"{path}: expected rows of at least {columns} comma-separated numbers")
    return rows


def run_calibrate(args) -> int:
    lat = math.radians(args.lat_deg)
    if args.kind == "accel-updown" and Path(args.table).is_dir():
        return _updown_session(args, lat)
    if args.kind == "accel-updown":
        g = calibration.local_gravity_mps2(lat, args.height_m)
        rows = _table(args.table, 2)
        print(f"local gravity {g:.5f} m/s^2 (WGS-84 normal gravity at {args.lat_deg:g} deg, {args.height_m:g} m)")
        print("axis  bias (m/s^2)  scale factor")
        for k, (z1, z2) in enumerate(rows[:, :2]):
            c = calibration.accel_up_down(z1, z2, g)
            print(f"{'xyz'[k] if len(rows) <= 3 else k:4}  {c.bias:12.5f}  {c.scale_factor:12.6f}")
    else:
        rows = _table(args.table, 2)
        w_ex = calibration.earth_rate_component(lat, args.axis_up)
        c = calibration.gyro_rate_table(rows[:, 0], rows[:, 1], w_ex, args.drift_bias)
        print(f"gyro: bias {c.bias:.6f} rad/s, scale factor {c.scale_factor:.6f}, residual RMS {c.residual_rms:.2e} "
              f"rad/s over {len(rows)} rates (Earth rate along the axis {w_ex:.3e} rad/s)")
    return 0


def _updown_session(args, lat: float) -> int:
    """Up-down from a recording: its steady windows, classified by the axis that sees gravity (one
    session with the up and down positions of one or more axes, or all six)."""
    from . import lab_plan
    from . import lab_calibration

    plan = lab_plan.Plan(Path(args.table).resolve().parent / "plan", lat, args.height_m,
                         [{"session": str(Path(args.table).resolve())}], [], None)
    notes: list[str] = []
    try:
        res = lab_calibration.updown(plan, None, notes)
    except records.RecordError as e:
        raise _error(str(e)) from None
    for w in notes:
        print(f"gpsins calibrate: warning: {w}", file=sys.stderr)
    print(f"local gravity {res['gravity_mps2']:.5f} m/s^2 (WGS-84 normal gravity at {args.lat_deg:g} deg, "
          f"{args.height_m:g} m); uncertainties: white noise only (`gpsins lab` adds the drift run's wander)")
    print("axis  bias (m/s^2)          scale factor           up window (s)   down window (s)")
    for a, v in res["axes"].items():
        print(f"{a:4}  {v['bias_mps2']:9.5f} ± {v['bias_sigma_mps2']:.1e}  {v['scale_factor']:10.6f} ± "
              f"{v['scale_factor_sigma']:.1e}  {v['up']['window_s'][0]:6.0f}-{v['up']['window_s'][1]:<6.0f}  "
              f"{v['down']['window_s'][0]:6.0f}-{v['down']['window_s'][1]:<6.0f}")
    return 0 if res["axes"] else 2


def run_lab(args) -> int:
    """`gpsins lab PLAN --out DIR`, or `gpsins lab --simulate --out DIR`: a simulated lab day first."""
    from . import lab
    from . import lab_plan
    from . import records as records_mod

    out = Path(args.out)
    plan = args.plan
    if args.simulate:
        from ..sim import lab as sim_lab
        from ..devices import lab as lab_mod

        cfg = sim_lab.LabDayConfig.quick() if args.quick else sim_lab.LabDayConfig()
        day_dir = out / "lab_day"
        if day_dir.exists():
            raise _error(f"{day_dir} exists; give a new --out")
        day = sim_lab.simulate_lab_day(cfg, args.seed)
        if args.speed:
            plan = lab_mod.record_through_logger(day, day_dir, speed=args.speed)
        else:
            plan = sim_lab.write_lab_day(day, day_dir)
        how = f"recorded through the emulators and the logger at {args.speed:g}x" if args.speed else "written"
        print(f"simulated lab day (seed {args.seed}, {len(day.t) / day.rate_hz / 3600:.2f} h) {how} in {day_dir}")
    elif plan is None:
        raise _error("give a lab plan (PLAN.toml) or --simulate")
    try:
        res = lab.run(plan, out / "report" if args.simulate else out)
    except (lab_plan.PlanError, records_mod.RecordError) as e:
        raise _error(str(e)) from None
    for w in res["warnings"]:
        print(f"gpsins lab: warning: {w}", file=sys.stderr)
    where = out / "report" if args.simulate else out
    print(f"report: {where / 'report.html'} (and report.md, lab.json, imu_preset.toml, imu.yaml)")
    return 0
