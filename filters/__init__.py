"""Filters over the two-frame measurements: EKF, smoother, CAN wheel speed, drift monitor.

- ``filters.model``: the state / measurement model (mount + body + planar motion) shared by
  the EKF and the smoother.
- ``filters.drive_sim``: long simulated measurement streams (no rendering) with truth.
- ``filters.ekf``: ``ExtrinsicsEKF`` (filterpy) and ``run_filter``.
- ``filters.metrics``: accuracy and NEES / NIS consistency against a drive's truth.

Shipped as ``vipm_track.filters`` (the folder stays at the repository root). Submodules are
imported on use (``from vipm_track.filters.ekf import ExtrinsicsEKF``) so importing the
package stays light.
"""
