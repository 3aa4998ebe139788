"""Synthetic substations that write exactly what real devices write.

Writes the on-disk formats of docs/design.md §4 and nothing else; downstream code
reads those files, never this package's internals. Imports only ``features``
(its constants, site model, geodesy, file writing).

- ``site/`` — layout, ray geometry, environment truth, walking routes;
- ``gnss/`` — orbits, signal (C/N0, blockage, fading), fixes, NMEA writer, the GNSS stream;
- ``acoustic/`` — propagation formulas, channel, chirp and schedule, sample synthesis, the audio stream;
- ``imu/`` — walker, magnetic field, the IMU stream;
- ``walk`` and ``survey`` write a walk log / a survey; ``streams`` runs the stream
  writers; ``rng`` gives every seeded random stream.
"""

__all__ = ["site", "gnss", "acoustic", "imu", "walk", "survey", "streams", "rng"]
