"""NMEA 0183 sentences of a navigation solution: GGA (position), RMC (course and speed) and GST (the
filter's own sigmas), so gpsd, QGIS or OpenCPN can take the live solution.

Times are UTC (GPS time less the leap seconds); heights are ellipsoidal with a geoid separation of 0
(the solution has no geoid model); GGA's quality is 1 while GNSS aids the solution and 6 (estimated,
dead reckoning) without.
"""

from __future__ import annotations

import math

import numpy as np

KNOTS_PER_MPS = 3600.0 / 1852.0
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ms")


def checksum(body: str) -> str:
    c = 0
    for ch in body.encode("ascii"):
        c ^= ch
    return f"{c:02X}"


def sentence(body: str) -> str:
    return f"${body}*{checksum(body)}\r\n"


def _utc(t_abs_gps: float, leap_s: int) -> tuple[str, str]:
    """hhmmss.ss and ddmmyy of a GPS time (seconds since the GPS epoch)."""
    cs = round((t_abs_gps - leap_s) * 100.0)  # to the hundredth the sentence holds (59.996 s is no 60.00)
    whole, frac = divmod(cs, 100)
    day = GPS_EPOCH + np.timedelta64(int(whole), "s")
    text = str(day.astype("datetime64[s]"))  # YYYY-MM-DDThh:mm:ss
    hms = f"{text[11:13]}{text[14:16]}{text[17:19]}.{int(frac):02d}"
    return hms, f"{text[8:10]}{text[5:7]}{text[2:4]}"


def _angle(value_deg: float, width: int) -> tuple[str, bool]:
    a = abs(value_deg)
    deg = int(a)
    return f"{deg:0{width}d}{(a - deg) * 60.0:09.6f}", value_deg >= 0


def gga(t_abs: float, leap_s: int, lat_rad: float, lon_rad: float, height_m: float, aided: bool, sats: int,
        hdop: float) -> str:
    hms, _ = _utc(t_abs, leap_s)
    lat, north = _angle(math.degrees(lat_rad), 2)
    lon, east = _angle(math.degrees(lon_rad), 3)
    return sentence(f"GPGGA,{hms},{lat},{'N' if north else 'S'},{lon},{'E' if east else 'W'},"
                    f"{1 if aided else 6},{sats:02d},{hdop:.1f},{height_m:.3f},M,0.0,M,,")


def rmc(t_abs: float, leap_s: int, lat_rad: float, lon_rad: float, v_ned_mps: np.ndarray, aided: bool) -> str:
    hms, dmy = _utc(t_abs, leap_s)
    lat, north = _angle(math.degrees(lat_rad), 2)
    lon, east = _angle(math.degrees(lon_rad), 3)
    speed = math.hypot(v_ned_mps[0], v_ned_mps[1])
    course = math.degrees(math.atan2(v_ned_mps[1], v_ned_mps[0])) % 360.0
    return sentence(f"GPRMC,{hms},A,{lat},{'N' if north else 'S'},{lon},{'E' if east else 'W'},"
                    f"{speed * KNOTS_PER_MPS:.3f},{course:.2f},{dmy},,,{'A' if aided else 'E'}")


def gst(t_abs: float, leap_s: int, sigma_ned_m: np.ndarray) -> str:
    """Position error statistics: RMS of the range residuals unknown (empty), no error ellipse, the
    1-sigma of latitude, longitude and height as the filter states them."""
    hms, _ = _utc(t_abs, leap_s)
    n, e, d = (float(x) for x in sigma_ned_m[:3])
    return sentence(f"GPGST,{hms},,,,,{n:.3f},{e:.3f},{d:.3f}")
