"""Ride: the body's pitch and roll on its suspension, excited by the road.

A car body rocks on its springs at its pitch and roll modes (about 1 to 2 Hz), more the faster it
goes; its path does not rock. So the ride is added to the attitude only: the velocity stays along
the road, and the body's own vertical and lateral velocity, which a non-holonomic constraint takes
as zero, become the speed times the ride's angles, as on a real car. The body turns about the IMU,
so the IMU's path is the road's; the antenna, away from it, moves with the body.

Each angle is a sum of sinusoids at frequencies spread evenly over ``band_hz`` with phases drawn
from ``seed`` (the road is the same in every run of the scenario), scaled to ``pitch_deg`` /
``roll_deg`` RMS well above ``reference_speed_mps``: the envelope k(v) = v^2 / (v^2 + v_ref^2) is
zero at rest, a fifth at half v_ref. Angles and rates are closed forms, so the IMU's increments stay
exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RideModel:
    pitch_deg: float = 0.0  # RMS at speeds well above reference_speed_mps; 0 with roll_deg 0: no ride
    roll_deg: float = 0.0
    band_hz: tuple = (1.0, 2.0)  # the body's pitch and roll modes
    reference_speed_mps: float = 8.0
    components: int = 16  # sinusoids per angle
    seed: int = 0

    @property
    def enabled(self) -> bool:
        return self.pitch_deg > 0.0 or self.roll_deg > 0.0


def _unit_sum(rng: np.random.Generator, m: RideModel):
    """Frequencies (rad/s) and phases of one angle's unit-RMS sum of sinusoids."""
    lo, hi = (float(x) for x in m.band_hz)
    w = 2.0 * np.pi * np.linspace(lo, hi, m.components)
    return w, rng.uniform(0.0, 2.0 * np.pi, m.components)


def ride(m: RideModel, t: np.ndarray, speed: np.ndarray, speed_dot: np.ndarray):
    """(pitch, pitch rate, roll, roll rate) of the ride at times t, rad and rad/s."""
    rng = np.random.default_rng([m.seed, 0x51DE])
    v2, r2 = speed * speed, m.reference_speed_mps ** 2
    k = v2 / (v2 + r2)
    k_dot = 2.0 * speed * speed_dot * r2 / (v2 + r2) ** 2
    a = np.sqrt(2.0 / m.components)  # each term's amplitude for a unit RMS
    out = []
    for rms_deg in (m.pitch_deg, m.roll_deg):
        w, ph = _unit_sum(rng, m)
        arg = np.asarray(t, float)[:, None] * w + ph
        s = a * np.sin(arg).sum(-1)
        s_dot = a * (w * np.cos(arg)).sum(-1)
        amp = np.radians(rms_deg)
        out += [amp * k * s, amp * (k_dot * s + k * s_dot)]
    return tuple(out)
