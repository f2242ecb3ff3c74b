"""What live navigation writes as it goes: NMEA sentences to the clients of a loopback TCP port
(``NmeaServer``), the full-precision epochs file (``read_epochs``), the NIS of a round's updates.
"""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import numpy as np

from ..nav import runs as flt


DEFAULT_LEAP_S = 18  # GPS - UTC since 2017, for NMEA times when the receiver has not said
EPOCH_COLUMNS = ("t", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "sigma_n", "sigma_e", "sigma_d")


def read_epochs(path: str | Path) -> dict:
    """live.f64 as arrays: t (s of the week), r_ecef, v_ecef, q_eb, sigma_ned_m (whole rows only)."""
    a = np.fromfile(path, dtype="<f8")
    a = a[:len(a) // len(EPOCH_COLUMNS) * len(EPOCH_COLUMNS)].reshape(-1, len(EPOCH_COLUMNS))
    return {"t": a[:, 0], "r_ecef": a[:, 1:4], "v_ecef": a[:, 4:7], "q_eb": a[:, 7:11], "sigma_ned_m": a[:, 11:14]}


class NmeaServer:
    """Sentences to every client of a loopback TCP port; a client that stops reading is dropped."""

    def __init__(self, port: int = 0):
        self._sock = socket.create_server(("127.0.0.1", port))
        self.port = self._sock.getsockname()[1]
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._stop = False
        threading.Thread(target=self._accept, name="gpsins-nmea", daemon=True).start()

    def _accept(self) -> None:
        self._sock.settimeout(0.2)
        while not self._stop:
            try:
                c, _ = self._sock.accept()
            except (socket.timeout, OSError):
                continue
            c.settimeout(1.0)
            with self._lock:
                self._clients.append(c)

    def send(self, text: str) -> None:
        data = text.encode("ascii")
        with self._lock:
            for c in list(self._clients):
                try:
                    c.sendall(data)
                except OSError:
                    self._clients.remove(c)
                    c.close()

    def close(self) -> None:
        self._stop = True
        with self._lock:
            for c in self._clients:
                c.close()
            self._clients.clear()
        self._sock.close()


def nis_per_source(updates: dict) -> dict:
    """This round's accepted updates per source: mean NIS per degree of freedom, and the 95 % band of
    that mean for white innovations of that many degrees of freedom (chi-square)."""
    from scipy.stats import chi2

    out = {}
    kind, dof, nis = (np.asarray(updates.get(k, ())) for k in ("kind", "dof", "nis"))
    ok = np.asarray(updates.get("accepted", np.ones(len(kind), bool)), bool) & (dof > 0)
    for k in np.unique(kind[ok]):
        m = ok & (kind == k)
        total = float(dof[m].sum())
        lo, hi = chi2.ppf([0.025, 0.975], total) / total
        out[flt.UPDATE_KINDS.get(int(k), str(int(k)))] = {"mean": float(nis[m].sum() / total), "n": int(m.sum()),
                                                          "band": [float(lo), float(hi)]}
    return out
