"""The error raised for unusable GNSS data files and epochs."""

from derive.errors import ModelError


class GnssDataError(ModelError):
    """A RINEX/SP3 file that does not follow its format, a satellite without a valid
    ephemeris, or an epoch with too few satellites; the message names the file, line,
    satellite or epoch."""
