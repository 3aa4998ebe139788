"""The simulated waist-worn IMU.

``walker`` (steps, body motion, sensor errors), ``magnetic`` (Earth field and
steel disturbances), ``stream`` (writes ``imu.csv`` and ``truth_steps.csv``).
"""

__all__ = ["walker", "magnetic", "stream"]
