"""Filters fusing the front end's measurements: EKF, smoother, CAN wheel speed, drift monitor.

Submodules are imported explicitly (``from filters.wheel_speed import SpeedSeries``) so that
importing one does not pull in the others' dependencies (gtsam, filterpy, python-can)."""
