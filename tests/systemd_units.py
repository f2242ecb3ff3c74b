"""Reading the project's systemd units (logger/*.service) for their tests: settings and systemd's own
exposure score."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest


def settings(path: Path) -> dict[str, list[str]]:
    """KEY=VALUE lines, continuation lines joined, each key's values in order."""
    out: dict[str, list[str]] = {}
    text = re.sub(r"\\\n\s*", " ", path.read_text())
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key, []).append(value)
    return out


def exposure(path: Path) -> float:
    """`systemd-analyze security --offline` of the unit file: 0 (confined) to 10 (exposed)."""
    exe = shutil.which("systemd-analyze")
    if not exe:
        pytest.skip("systemd-analyze not installed (Debian package systemd)")
    p = subprocess.run([exe, "security", "--offline=true", str(path)], capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", p.stdout + p.stderr)
    assert m, p.stdout + p.stderr
    print(f"exposure {m.group(1)}")
    return float(m.group(1))
