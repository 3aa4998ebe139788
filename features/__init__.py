"""Readers and signal processing: pure functions of raw device data.

This package imports nothing else of envfuse; every other package may import it.

One subpackage per sensor, and the modules every sensor shares:

- ``gnss/`` — NMEA 0183 reader, the five GNSS features, fixes in ENU with σ; raw
  pseudoranges (smartLoc text), the per-epoch WLS + RAIM solver;
- ``acoustic/`` — audio reader, matched filter, chirp detection and tracking,
  acoustic positions, the CIR and its nine features (and the UWB CIR log reader);
- ``imu/`` — IMU CSV reader, steps, step length, heading, PDR;
- ``vehicle/`` — odometry (speed, yaw rate) dead reckoning into PDR-like events;
- ``site`` (``site.toml``), ``walk`` (``walk.toml`` / ``cell.toml``, ``truth.csv``),
  ``fileio`` (atomic writes), ``constants`` (units and sources), ``errors``
  (typed exceptions), ``geodesy`` (geodetic ↔ ENU).
"""

__all__ = ["gnss", "acoustic", "imu", "vehicle", "site", "walk", "fileio", "constants", "errors", "geodesy"]
