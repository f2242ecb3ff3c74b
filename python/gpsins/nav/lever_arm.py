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
from . import runs as flt

MAX_EVALUATIONS = 60
TOLERANCE_M = 0.002  # the simplex's size at which it stops: a few mm, well below any stated sigma


def fit(imu, fixes: np.ndarray, cfg: dict, *, mode: str = "loose") -> dict | None:
    """The lever arm (body axes, m) of largest posterior given ``cfg``'s ``lever_arm_body_m`` and
    ``lever_arm_sigma_m``; None when no component has a sigma. Returns ``{"lever_arm_body_m",
    "stated_m", "sigma_m", "minus_two_log_posterior": {"stated", "fitted"}, "evaluations", "fixes"}``."""
    from scipy.optimize import minimize

    sigma = nav_config.as_vec3(cfg.get("lever_arm_sigma_m", 0.0), "lever_arm_sigma_m")
    if not (sigma > 0).any() or not len(fixes):
        return None
    stated = nav_config.as_vec3(cfg.get("lever_arm_body_m", 0.0), "lever_arm_body_m")
    free = sigma > 0  # a component stated exactly stays as stated
    imu, fixes, base = noise_from_data.fit_start(imu, fixes, cfg)
    evaluations = []

    def lever(x: np.ndarray) -> np.ndarray:
        out = stated.copy()
        out[free] = x
        return out

    def cost(x: np.ndarray) -> float:
        arm = lever(x)
        updates = flt.run(imu, fixes, dict(base, lever_arm_body_m=arm.tolist()), mode=mode,
                          output_every=10 ** 9).updates
        prior = float(np.sum(((x - stated[free]) / sigma[free]) ** 2))
        value = noise_from_data.minus_two_log_likelihood(updates) + prior
        evaluations.append(value)
        return value

    x0 = stated[free]
    at_stated = cost(x0)
    res = minimize(cost, x0, method="Nelder-Mead",
                   options={"maxfev": MAX_EVALUATIONS, "xatol": TOLERANCE_M, "fatol": 0.5,
                            "initial_simplex": np.vstack([x0, x0 + np.diag(sigma[free])])})
    better = res.fun < at_stated
    return {"lever_arm_body_m": (lever(res.x) if better else stated).tolist(), "stated_m": stated.tolist(),
            "sigma_m": sigma.tolist(),
            "minus_two_log_posterior": {"stated": at_stated, "fitted": float(min(res.fun, at_stated))},
            "evaluations": len(evaluations), "fixes": int(len(fixes))}
