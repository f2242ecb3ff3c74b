"""A finished session grown again record by record in stamp order, as the logger wrote it: what a follower
of the session sees at each moment of the drive, without ptys or waits on the wall clock."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gpsins.session import layouts
from gpsins.session.scan import scan

def _records(path: Path, device: str):
    data = path.read_bytes()
    s = scan(data, layouts.LAYOUTS[device], str(path))
    return data, s.starts, s.lengths, s.stamps


class GrowingCopy:
    """``dst`` made from the finished session ``src`` as the logger wrote it: ``grow_to(t)`` appends
    every record stamped up to system time t, ``finish()`` the rest and marks the session stopped."""

    def __init__(self, src: Path, dst: Path):
        self.side = json.loads((src / "session.json").read_text())
        dst.mkdir(parents=True)
        self.dst, self.files = dst, []
        for sensor in self.side["sensors"].values():
            for name in sensor["files"]:
                data, starts, lengths, stamps = _records(src / name, sensor["device"])
                (dst / name).write_bytes(b"")
                self.files.append({"path": dst / name, "data": data, "starts": starts, "ends": starts + lengths,
                                   "stamps": stamps, "done": 0})
        self._sidecar("running")

    @property
    def span(self) -> tuple[float, float]:
        return (min(f["stamps"][0] for f in self.files), max(f["stamps"][-1] for f in self.files))

    def grow_to(self, t: float) -> None:
        for f in self.files:
            k = int(np.searchsorted(f["stamps"], t, side="right"))
            if k > f["done"]:
                with open(f["path"], "ab") as out:
                    out.write(f["data"][int(f["starts"][f["done"]]):int(f["ends"][k - 1])])
                f["done"] = k

    def finish(self) -> None:
        self.grow_to(np.inf)
        self._sidecar("stopped")

    def _sidecar(self, state: str) -> None:
        (self.dst / "session.json").write_text(json.dumps({**self.side, "state": state}))
