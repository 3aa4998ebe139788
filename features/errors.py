"""Typed exceptions. The CLI maps every :class:`EnvfuseError` to one line on stderr."""

__all__ = ["EnvfuseError", "ConfigError", "NmeaError", "AudioError", "ImuError", "DataError", "PseudorangeError", "UwbError"]


class EnvfuseError(Exception):
    """Base class of every error envfuse reports to a user as a clean message."""


class ConfigError(EnvfuseError, ValueError):
    """A configuration file (site.toml, walk.toml, cell.toml) is missing or malformed."""


class DataError(EnvfuseError, ValueError):
    """A data file cannot be used at all (not: a few bad lines, which are skipped and counted)."""


class NmeaError(DataError):
    """An NMEA file holds no usable epoch."""


class AudioError(DataError):
    """An audio file cannot be read or processed."""


class ImuError(DataError):
    """An IMU file lacks required columns or usable samples."""


class PseudorangeError(DataError):
    """A pseudorange / odometry / reference text file has a malformed line (named by file and line) or
    holds no usable record."""


class UwbError(DataError):
    """A UWB ranging log (``uwb.csv``) lacks its columns, has a malformed line or holds no usable row."""
