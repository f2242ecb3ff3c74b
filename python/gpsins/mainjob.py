"""The main job: the default end-to-end run (grows as the pipeline's stages land)."""

from __future__ import annotations

import argparse
import math

from . import _core


def run(args: argparse.Namespace) -> int:
    lat, lon, h = math.radians(59.37), math.radians(17.95), 30.0
    xyz = _core.geodetic_to_ecef([lat, lon, h])
    g = _core.normal_gravity(lat, h)
    print("gpsins core: WGS-84 Earth model at the default site (59.37 N, 17.95 E, 30 m)")
    print(f"  ECEF            {xyz[0]:.3f} {xyz[1]:.3f} {xyz[2]:.3f} m")
    print(f"  normal gravity  {float(g):.6f} m/s^2")
    return 0
