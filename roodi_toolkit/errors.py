"""Errors the library raises. Each message says what was wrong and what to do about it.

The CLI turns any :class:`RoodiError` into one line on stderr and exit code 1; library code never prints or exits.
"""


class RoodiError(Exception):
    """Base class of every error a user can act on."""


class PlyError(RoodiError):
    """A PLY file could not be read or written."""


class CloudError(RoodiError):
    """A Gaussian cloud is malformed or unsuitable for the requested operation."""


class DatasetError(RoodiError):
    """A posed-image dataset is missing, malformed or inconsistent."""


class OutputError(RoodiError):
    """An output path is unusable (exists without overwrite, equals an input, not writable)."""


class PluginError(RoodiError):
    """A plugin is unknown, failed to load, or does not follow its interface."""


class ConfigError(RoodiError):
    """An option or configuration value is out of range or inconsistent."""


class FormatError(RoodiError):
    """A splat file in another format (compressed PLY, SPZ, SOG, .splat, .ksplat) could not be read or written."""
