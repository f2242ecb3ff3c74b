"""Single-point positioning over a whole data set: RINEX 2 obs + nav, a logger
session, or a raw Superstar II capture; results as RTKLIB-style .pos.

The solver is the C++ core's (``_core.gnss.spp``): iterated weighted least
squares with Klobuchar, Saastamoinen, TGD, an elevation mask, RTKLIB's
elevation-dependent variances, a chi-square residual test and single-fault
exclusion.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from gpsins_logger import superstar2 as ss2

from .. import _core, evaluate
from ..formats import rinex
from ..formats import gpstime
from ..formats.gpstime import SECONDS_PER_WEEK


@dataclass
class Epochs:
    """Pseudoranges per epoch with what is needed to use them."""

    t_abs: list[float]  # receiver time, s since the GPS epoch
    prns: list[list[int]]
    pr_m: list[list[float]]
    store: object  # _core.gnss.EphemerisStore
    alpha: list[float] = field(default_factory=list)
    beta: list[float] = field(default_factory=list)
    reference_xyz: np.ndarray | None = None  # a known position (RINEX header), if any
    source: str = ""
    week: int | None = None


def from_rinex(obs_path: str | Path, nav_path: str | Path, code: str = "C1") -> Epochs:
    nav = rinex.read_nav(nav_path)
    obs = rinex.read_obs(obs_path)
    col = obs.column(code)
    t, prns, prs = [], [], []
    for te, p, v in obs.epochs:
        ok = np.isfinite(v[:, col])
        t.append(te)
        prns.append([x for x, o in zip(p, ok) if o])
        prs.append(v[ok, col].tolist())
    return Epochs(t, prns, prs, nav.store(), nav.alpha, nav.beta, obs.approx_xyz, f"{Path(obs_path).name}")


def from_superstar2_frames(frames: list[bytes], source: str, nav_path: str | Path | None = None) -> Epochs:
    """Epochs from Superstar II frames in stream order (ID 23, 22, 75, 21/49 for the week)."""
    store = _core.gnss.EphemerisStore()
    alpha, beta = [], []
    week = None
    leap = None
    pending_eph = []
    t, prns, prs = [], [], []
    last_tow = None
    for fr in frames:
        try:
            msg_id, payload = ss2.decode_frame(fr)
            if msg_id == ss2.ID_LEAP:
                leap = ss2.LeapSeconds.decode(payload).leap_s
            elif msg_id == ss2.ID_NAV_USER and week is None and leap is not None:
                u = ss2.NavUser.decode(payload)  # UTC date and time: the week with the leap seconds
                if u.year > 1980:
                    utc = dt.datetime(u.year, u.month, u.day, u.hour, u.minute) + dt.timedelta(seconds=u.second)
                    week = int(((utc - gpstime.GPS_EPOCH).total_seconds() + leap) // SECONDS_PER_WEEK)
            elif msg_id == ss2.ID_NAV_ECEF:
                week = ss2.NavEcef.decode(payload).week or week
            elif msg_id == ss2.ID_RECEIVER_STATUS:
                week = ss2.ReceiverStatus.decode(payload).week or week
            elif msg_id == ss2.ID_IONO_UTC:
                io = ss2.IonoUtc.decode(payload)
                alpha, beta, leap = list(io.alpha), list(io.beta), io.leap_s
            elif msg_id == ss2.ID_EPHEMERIS:
                pending_eph.append(ss2.EphemerisWords.decode(payload))
            elif msg_id == ss2.ID_MEASUREMENTS:
                m = ss2.Measurements.decode(payload)
                if week is None:
                    continue
                if last_tow is not None and m.tow_s < last_tow - SECONDS_PER_WEEK / 2:
                    week += 1
                last_tow = m.tow_s
                t.append(week * SECONDS_PER_WEEK + m.tow_s)
                prns.append([o.prn for o in m.observations if not o.sbas])
                prs.append([m.pseudorange_m(o) for o in m.observations if not o.sbas])
            if week is not None and pending_eph:
                for w in pending_eph:
                    try:
                        store.add(_core.gnss.decode_subframes(w.subframes, w.prn, week))
                    except ValueError:
                        pass  # an inconsistent set (IODE/IODC) is not used
                pending_eph.clear()
        except ss2.ProtocolError:
            continue
    if nav_path is not None:
        nav = rinex.read_nav(nav_path)
        for e in nav.ephemerides:
            store.add(e)
        if not alpha:
            alpha, beta = nav.alpha, nav.beta
    ep = Epochs(t, prns, prs, store, alpha, beta, None, source)
    ep.week = week
    return ep


def from_session(directory: str | Path, nav_path=None) -> Epochs:
    from ..session import logs

    s = logs.read_session(directory)
    return from_superstar2_frames(s.sensors["gps"].frames(), Path(directory).name, nav_path)


def from_raw(path: str | Path, nav_path=None) -> Epochs:
    from gpsins_logger.framing import FrameFinder

    data = Path(path).read_bytes()
    if Path(path).suffix == ".raw":
        from ..session import logs
        data = b"".join(chunk for _, _, chunk in logs.read_raw_capture(path))
    finder = FrameFinder(ss2.FRAMING)
    frames = [f.data for f in finder.feed(data)]
    return from_superstar2_frames(frames, Path(path).name, nav_path)


@dataclass
class SppRun:
    t_abs: np.ndarray
    ok: np.ndarray
    r_ecef: np.ndarray
    clock_m: np.ndarray
    n_used: np.ndarray
    dops: np.ndarray  # gdop, pdop, hdop, vdop
    excluded: np.ndarray


def solve(ep: Epochs, mask_deg: float = 15.0, ionosphere: bool = True, troposphere: bool = True) -> SppRun:
    n = len(ep.t_abs)
    out = SppRun(np.array(ep.t_abs), np.zeros(n, bool), np.full((n, 3), np.nan), np.full(n, np.nan),
                 np.zeros(n, int), np.full((n, 4), np.nan), np.zeros(n, int))
    guess = np.zeros(3) if ep.reference_xyz is None else ep.reference_xyz * 0.0
    for k in range(n):
        r = _core.gnss.spp(ep.store, ep.t_abs[k], ep.prns[k], ep.pr_m[k], ep.alpha, ep.beta, mask_deg, ionosphere,
                           troposphere, True, True, guess)
        out.n_used[k] = r["n_used"]
        out.excluded[k] = r["excluded_prn"]
        if r["ok"]:
            out.ok[k] = True
            out.r_ecef[k] = r["r_ecef"]
            out.clock_m[k] = r["clock_m"]
            out.dops[k] = [r["gdop"], r["pdop"], r["hdop"], r["vdop"]]
            guess = r["r_ecef"]
    return out


def errors_ned(run: SppRun, reference_xyz: np.ndarray) -> np.ndarray:
    llh = _core.ecef_to_geodetic(reference_xyz)
    c = evaluate.c_en(np.array([llh[0]]), np.array([llh[1]]))[0]
    return (run.r_ecef[run.ok] - reference_xyz) @ c


def write_pos(path: str | Path, run: SppRun, source: str, llh: bool = True) -> None:
    """RTKLIB-style .pos: GPST epochs, lat/lon/height (or ECEF with llh=False), Q = 5 (single)."""
    lines = ["% program   : gpsins spp", f"% inp file  : {source}", "% pos mode  : single",
             "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)"]
    lines.append("%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns" if llh else
                 "%  GPST                      x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns")
    pos = _core.ecef_to_geodetic(run.r_ecef[run.ok]) if run.ok.any() else np.zeros((0, 3))
    ok = np.flatnonzero(run.ok)
    for j, (k, ts) in enumerate(zip(ok, gpstime.gpst_text(run.t_abs[ok]) if len(ok) else [])):
        if llh:
            lat, lon = np.degrees(pos[j, :2])
            lines.append(f"{ts} {lat:14.9f} {lon:14.9f} {pos[j, 2]:10.4f} {5:3d} {run.n_used[k]:3d}")
        else:
            x, y, z = run.r_ecef[k]
            lines.append(f"{ts} {x:14.4f} {y:14.4f} {z:14.4f} {5:3d} {run.n_used[k]:3d}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def truth_errors(run: SppRun, directory: str | Path) -> np.ndarray | None:
    """NED errors of the solved epochs against a simulator's truth.npz next to a session, if there is one."""
    from ..replay.inputs import load_session_truth

    found = load_session_truth(Path(directory), 0.0)
    if found is None or not run.ok.any():
        return None
    truth = found[0]
    t = run.t_abs[run.ok]
    inside = (t >= truth.t[0]) & (t <= truth.t[-1])
    if not inside.any():
        return None
    ref = truth.at(t[inside]).r_ecef
    llh = _core.ecef_to_geodetic(ref)
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])
    return np.einsum("nji,nj->ni", c_en, run.r_ecef[run.ok][inside] - ref)


def _rms_line(what: str, e: np.ndarray) -> str:
    return (f"vs {what}: horizontal RMS {np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)):.3f} m, "
            f"vertical RMS {np.sqrt(np.mean(e[:, 2] ** 2)):.3f} m over {len(e)} epochs")


def main(args) -> int:
    from ..errors import CommandError

    if args.rinex:
        if not args.nav:
            raise CommandError(f"{args.rinex}: --rinex needs --nav NAV_FILE (the broadcast ephemerides)")
        ep = from_rinex(args.rinex, args.nav)
    elif args.raw:
        ep = from_raw(args.raw, args.nav)
    elif args.session:
        ep = from_session(args.session, args.nav)
    else:
        raise CommandError("nothing to solve: give a SESSION, --raw FILE or --rinex OBS --nav NAV")
    if not ep.t_abs:
        what = args.rinex or args.raw or args.session
        raise CommandError(f"{what}: no pseudorange epochs (Superstar II ID 23 with a known GPS week, or RINEX "
                           "observations); is it the right file?")
    run = solve(ep, args.mask_deg, not args.no_iono, not args.no_trop)
    print(f"{ep.source}: {run.ok.sum()} of {len(run.ok)} epochs solved "
          f"({len(ep.store)} ephemerides, Klobuchar {'yes' if ep.alpha else 'no'})")
    if ep.reference_xyz is not None and run.ok.any():
        print(_rms_line("the header position", errors_ned(run, ep.reference_xyz)))
    if args.session:
        e = truth_errors(run, args.session)
        if e is not None:
            print(_rms_line("the simulator's truth", e))
    if args.out:
        write_pos(args.out, run, ep.source, llh=not args.ecef)
        print(f"positions in {args.out}")
    if not run.ok.any():
        raise CommandError(f"{ep.source}: no epoch solved ({len(ep.store)} ephemerides); a session needs ID 22 "
                           "subframes, a raw capture or RINEX obs a --nav file with the broadcast ephemerides")
    return 0
