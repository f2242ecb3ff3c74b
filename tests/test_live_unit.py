"""The systemd unit of `gpsins live` on the vehicle computer (logger/gpsins-live.service): ordered after the
logger, its command one the CLI accepts, the sessions read only, the network the loopback's, and a sandbox
systemd itself scores as confined."""

import shlex
import tomllib
from pathlib import Path

from systemd_units import exposure, settings

from gpsins import cli
from gpsins import commands

LOGGER = Path(__file__).resolve().parents[1] / "logger"
UNIT = LOGGER / "gpsins-live.service"


def test_the_unit_runs_a_live_command_the_cli_accepts_on_the_loggers_root():
    u = settings(UNIT)
    argv = shlex.split(u["ExecStart"][0])
    assert Path(argv[0]).name == "gpsins"
    args = cli.build_parser().parse_args(argv[1:])
    assert args.func is commands.cmd_live and args.follow_root
    root = tomllib.loads((LOGGER / "logger.example.toml").read_text())["session"]["root"]
    assert Path(args.session) == Path(root)
    # Its output is its own state directory, outside what the logger writes.
    assert Path(args.out) == Path("/var/lib") / u["StateDirectory"][0]
    assert not Path(args.out).is_relative_to(Path(root).parent)
    assert args.nmea_port and args.http_port


def test_the_unit_follows_the_logger_reads_sessions_only_and_stays_on_the_loopback():
    u, logger = settings(UNIT), settings(LOGGER / "gpsins-logger.service")
    assert "gpsins-logger.service" in u["After"][0].split()
    # The same user as the logger (its sessions are 0750), the logger's state directory mounted read only.
    assert u["User"] == logger["User"]
    assert u["ReadOnlyPaths"][0].lstrip("-") == "/var/lib/" + logger["StateDirectory"][0]
    assert u["ProtectSystem"] == ["strict"]
    assert u["IPAddressDeny"] == ["any"] and u["IPAddressAllow"] == ["localhost"]
    assert u["CapabilityBoundingSet"] == [""] and u["NoNewPrivileges"] == ["yes"]
    # The logger keeps the CPU when both want it.
    assert int(u["Nice"][0]) > 0 and int(u["CPUWeight"][0]) < 100
    assert u["Restart"] == ["on-failure"] and u["RestartPreventExitStatus"] == ["2"]


def test_the_units_exposure_score():
    # systemd's own scale: below 2 is "OK", the logger's unit sits at about 0.5.
    assert exposure(UNIT) <= 2.0
