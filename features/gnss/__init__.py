"""GNSS from NMEA 0183 or raw pseudoranges: epochs, the five environment features, ENU fixes.

Open ``nmea`` to read a file (:func:`~features.gnss.nmea.read_nmea`, epochs on the
walk's time base); ``tokens`` for checksums and splitting, ``quirks`` for every
receiver's field layouts; ``features`` for μ, σ, β, ζ, λ of docs/design.md §5 and the
open-sky C/N0 reference; ``positions`` for fixes in the site's ENU frame with σ.

From pseudoranges: ``pseudorange`` reads smartLoc text files into column tables (the
tables a RINEX stage would fill too); ``weights`` holds the pseudorange variance models;
``wls`` solves each epoch (weighted least squares, a clock per system, Sagnac, RAIM) into
the same fix table as ``positions``; ``sat_features`` builds the features' sky from
per-satellite data.
"""

__all__ = ["nmea", "tokens", "quirks", "features", "positions", "pseudorange", "weights", "wls", "sat_features"]
