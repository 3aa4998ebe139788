"""Pedestrian dead reckoning from a waist-worn IMU.

``reader`` reads and repairs ``imu.csv`` onto one uniform time base; ``steps``
detects steps and gives their Weinberg length; ``heading`` the gyro /
magnetometer heading (navigation convention: 0 = north, clockwise); ``pdr``
puts them together into a track (:func:`~features.imu.pdr.run_pdr`).
"""

__all__ = ["reader", "steps", "heading", "pdr"]
