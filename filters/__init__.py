"""Filters over the two-frame measurements: EKF, smoother, CAN wheel speed, drift monitor."""
