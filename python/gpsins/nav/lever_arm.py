"""The antenna's lever arm from the recording, where the data set says it knows it only roughly.

A fix is of the antenna; the filter carries it to the IMU through C_eb l. A lever arm wrong by d puts
C_eb d into every position innovation: steady while the body holds its attitude, swinging as it turns,
so the innovations run correlated and the filter takes the swing for motion. A hand-held device's
antenna is "about 5 cm away", a car's measured with a tape to a few cm. Where the data set states how
well it knows the offset (``[gnss] antenna_sigma_m``, the filter key ``lever_arm_sigma_m``), replay
takes the lever arm of largest posterior: the innovations' -2 ln L (noise_from_data's, the same
runs over the fixes the run uses) plus the prior's sum ((l - l_stated) / sigma)^2, minimised by
Nelder-Mead over the three components. The stated lever arm stays where the fit finds nothing better.
"""

from __future__ import annotations

import numpy as np

from . import config as nav_config
from . import noise_from_data

MAX_EVALUATIONS = 60
TOLERANCE_M = 0.002  # the simplex's size at which it stops: a few mm, well below any stated sigma


def fit(imu, fixes: np.ndarray, cfg: dict, *, mode: str = "loose") -> dict | None:
    """The lever arm (body axes, m) of largest posterior given ``cfg``'s ``lever_arm_body_m`` and
    ``lever_arm_sigma_m``; None when no component has a sigma. Returns ``{"lever_arm_body_m",
    "stated_m", "sigma_m", "minus_two_log_posterior": {"stated", "fitted"}, "evaluations", "fixes"}``."""
    sigma = nav_config.as_vec3(cfg.get("lever_arm_sigma_m", 0.0), "lever_arm_sigma_m")
    if not (sigma > 0).any() or not len(fixes):
        return None
    stated = nav_config.as_vec3(cfg.get("lever_arm_body_m", 0.0), "lever_arm_body_m")
    free = sigma > 0  # a component stated exactly stays as stated
    imu, fixes, base = noise_from_data.fit_start(imu, fixes, cfg)

    def lever(x: np.ndarray) -> np.ndarray:
        out = stated.copy()
        out[free] = x
        return out

    def cost(x: np.ndarray) -> float:
        prior = float(np.sum(((x - stated[free]) / sigma[free]) ** 2))
        return noise_from_data.run_likelihood(imu, fixes, dict(base, lever_arm_body_m=lever(x).tolist()), mode) + prior

    found = noise_from_data.minimise_from(cost, stated[free], sigma[free], max_evaluations=MAX_EVALUATIONS,
                                          tolerance=TOLERANCE_M)
    return {"lever_arm_body_m": lever(found["x"]).tolist(), "stated_m": stated.tolist(), "sigma_m": sigma.tolist(),
            "minus_two_log_posterior": {"stated": found["at_start"], "fitted": found["best"]},
            "evaluations": found["evaluations"], "fixes": int(len(fixes))}
