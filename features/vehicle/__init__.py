"""Vehicle sensors: wheel/CAN odometry (speed and yaw rate) as a dead-reckoning stream.

``odometry`` integrates speed and yaw rate into displacement events with the same fields as
PDR's steps (:class:`features.imu.pdr.PdrResult`: ``t_s``, ``step_length_m``, ``heading_rad``,
``east_m``, ``north_m``), so the fusion filters consume a car's odometry as they consume a
walker's steps; the initial heading comes from the first GNSS fixes' motion.
"""

__all__ = ["odometry"]
