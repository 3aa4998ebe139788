"""GNSS from NMEA 0183: epochs, the five environment features, ENU fixes.

Open ``nmea`` to read a file (:func:`~features.gnss.nmea.read_nmea`, epochs on the
walk's time base); ``tokens`` for checksums and splitting, ``quirks`` for every
receiver's field layouts; ``features`` for μ, σ, β, ζ, λ of DESIGN.md §5 and the
open-sky C/N0 reference; ``positions`` for fixes in the site's ENU frame with σ.
"""

__all__ = ["nmea", "tokens", "quirks", "features", "positions"]
