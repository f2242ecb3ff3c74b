"""IMU characterisation: Allan deviation, PSD, noise-term fit, deterministic
calibration, and the filter parameters they give (seed 000; seed 004 ch. 5)."""
