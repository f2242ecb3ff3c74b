"""Short simulated drives the tests share: a stand, then a drive with a turn, near Stockholm in GPS
week 1590 (the report's place and the simulator's ephemerides' day)."""

from gpsins.sim.scenario import parse

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def stand_and_drive(name: str, stand_s: float, drive_s: float, speed_mps: float = 10.0, turn_deg: float = 90.0):
    """A scenario: ``stand_s`` at rest, then ``drive_s`` at ``speed_mps`` turning ``turn_deg``."""
    return parse({"name": name, "start": START,
                  "segment": [{"label": "stand", "duration_s": stand_s, "speed_mps": 0},
                              {"label": "drive", "duration_s": drive_s, "speed_mps": speed_mps,
                               "turn_deg": turn_deg}]})
