"""Recursive and batch filtering over the two-frame measurements.

- ``filters.model``: the state / measurement model (mount + body + planar motion) shared by
  the EKF and the smoother.
- ``filters.drive_sim``: long simulated measurement streams (no rendering) with truth.
- ``filters.ekf``: ``ExtrinsicsEKF`` (filterpy) and ``run_filter``.

Submodules are imported on use (``from filters.ekf import ExtrinsicsEKF``) so importing
``filters`` stays light.
"""
