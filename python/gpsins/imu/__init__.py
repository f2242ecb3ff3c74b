"""IMU characterisation: Allan deviation, PSD, noise-term fit, deterministic
calibration, and the filter parameters they give (the tuning notes; the FOI report's
chapter 5: docs/references.md)."""
