"""The simulated GNSS receiver.

``orbits`` (GPS and BeiDou-3 positions, azimuth / elevation), ``signal`` (open-sky
C/N0, blockage, fading, tracking), ``fix`` (pseudorange errors, weighted least
squares, fix quality), ``nmea_writer`` (sentences), ``stream`` (writes ``gnss.nmea``).
"""

__all__ = ["orbits", "signal", "fix", "nmea_writer", "stream"]
