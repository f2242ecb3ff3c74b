"""GPS time: the GPS epoch, weeks, leap seconds and RTKLIB's epoch text.

Times are GPS seconds since the GPS epoch (1980-01-06 00:00 GPST), "t_abs", as the C++ core takes them.
"""

from __future__ import annotations

import datetime as dt

import numpy as np


GPS_EPOCH = dt.datetime(1980, 1, 6)
UNIX_TO_GPS_S = (GPS_EPOCH - dt.datetime(1970, 1, 1)).total_seconds()  # 315964800: both without leap seconds
SECONDS_PER_WEEK = 604800.0
MILLISECONDS_PER_WEEK = 604_800_000  # time-of-week counters in ms (u-blox iTOW)

# UTC dates from which GPST - UTC steps up by one second (IERS bulletins).
_LEAP_DATES = [dt.datetime(*d) for d in (
    (1981, 7, 1), (1982, 7, 1), (1983, 7, 1), (1985, 7, 1), (1988, 1, 1), (1990, 1, 1), (1991, 1, 1), (1992, 7, 1),
    (1993, 7, 1), (1994, 7, 1), (1996, 1, 1), (1997, 7, 1), (1999, 1, 1), (2006, 1, 1), (2009, 1, 1), (2012, 7, 1),
    (2015, 7, 1), (2017, 1, 1))]


def gps_seconds(y: int, mo: int, d: int, h: int, mi: int, s: float) -> float:
    """Seconds since the GPS epoch of a GPST calendar date (two-digit years as RINEX 2 has them)."""
    year = y + (2000 if y < 80 else 1900) if y < 100 else y
    t = dt.datetime(year, mo, d, h, mi) - GPS_EPOCH
    return t.days * 86400.0 + t.seconds + s


def gpst_text(t_abs) -> list[str]:
    """RTKLIB's GPST epoch text, 'YYYY/MM/DD hh:mm:ss.sss', for seconds since the GPS epoch
    (to the microsecond, then cut to the millisecond, as datetime's formatting does)."""
    x = np.atleast_1d(np.asarray(t_abs, dtype=np.float64))
    whole = np.floor(x)
    us = whole.astype(np.int64) * 1_000_000 + np.round((x - whole) * 1e6).astype(np.int64)  # x - whole is exact
    ms = np.datetime64("1980-01-06T00:00:00", "ms") + (us // 1000).astype("timedelta64[ms]")
    text = np.datetime_as_string(ms, unit="ms")
    return np.strings.replace(np.strings.replace(text, "-", "/"), "T", " ").tolist()


def leap_seconds(utc: dt.datetime) -> int:
    """GPST - UTC at a UTC instant (from 1980 on)."""
    return sum(utc >= d for d in _LEAP_DATES)


def utc_to_gps_seconds(utc: dt.datetime, leap_s: int | None = None) -> float:
    t = utc - GPS_EPOCH
    return t.days * 86400.0 + t.seconds + t.microseconds * 1e-6 + (leap_seconds(utc) if leap_s is None else leap_s)


def week_and_tow(t_abs: float) -> tuple[int, float]:
    week = int(t_abs // SECONDS_PER_WEEK)
    return week, t_abs - week * SECONDS_PER_WEEK
