"""The systemd unit of `gpsins live` on the vehicle computer (logger/gpsins-live.service): ordered after the
logger, its command one the CLI accepts, the sessions read only, the network the loopback's, and a sandbox
systemd itself scores as confined."""

import re
import shlex
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from gpsins import cli

LOGGER = Path(__file__).resolve().parents[1] / "logger"
UNIT = LOGGER / "gpsins-live.service"


def _settings(path: Path) -> dict[str, list[str]]:
    """KEY=VALUE lines, continuation lines joined, each key's values in order."""
    out: dict[str, list[str]] = {}
    text = re.sub(r"\\\n\s*", " ", path.read_text())
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key, []).append(value)
    return out


def test_the_unit_runs_a_live_command_the_cli_accepts_on_the_loggers_root():
    u = _settings(UNIT)
    argv = shlex.split(u["ExecStart"][0])
    assert Path(argv[0]).name == "gpsins"
    args = cli.build_parser().parse_args(argv[1:])
    assert args.func is cli._cmd_live and args.follow_root
    root = tomllib.loads((LOGGER / "logger.example.toml").read_text())["session"]["root"]
    assert Path(args.session) == Path(root)
    # Its output is its own state directory, outside what the logger writes.
    assert Path(args.out) == Path("/var/lib") / u["StateDirectory"][0]
    assert not Path(args.out).is_relative_to(Path(root).parent)
    assert args.nmea_port and args.http_port


def test_the_unit_follows_the_logger_reads_sessions_only_and_stays_on_the_loopback():
    u, logger = _settings(UNIT), _settings(LOGGER / "gpsins-logger.service")
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
    exe = shutil.which("systemd-analyze")
    if not exe:
        pytest.skip("systemd-analyze not installed (Debian package systemd)")
    p = subprocess.run([exe, "security", "--offline=true", str(UNIT)], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", p.stdout + p.stderr)
    assert m, p.stdout + p.stderr
    print(f"exposure {m.group(1)}")
    # systemd's own scale: below 2 is "OK", the logger's unit sits at about 0.5.
    assert float(m.group(1)) <= 2.0
