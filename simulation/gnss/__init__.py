"""The simulated GNSS receiver.

``orbits`` (GPS and BeiDou-3 positions, azimuth / elevation), ``signal`` (open-sky
C/N0, blockage, fading, tracking), ``reflection`` (specular NLOS off the layout's
faces: geometry, materials, polarisation), ``fix`` (pseudorange and carrier errors,
weighted least squares, fix quality), ``rtk`` (float ambiguities, fix-and-hold),
``ambiguity`` (LAMBDA, ratio test, success rate), ``gst`` (the receiver's error
statistics), ``nmea_writer`` (sentences), ``stream`` (writes ``gnss.nmea``).
"""

__all__ = ["orbits", "signal", "reflection", "fix", "rtk", "ambiguity", "gst", "nmea_writer", "stream"]
