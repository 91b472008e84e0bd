"""roodi-toolkit: take one object out of a 3D Gaussian Splatting scene as a clean, standalone 3DGS model.

The names below are the public API. Modules that need PyTorch (rendering, training) are imported only when used, so
``import roodi_toolkit`` stays light.
"""

from ._version import __version__
from .errors import (CloudError, ConfigError, DatasetError, EnvironmentProblemError, FormatError, InputError,
                     OutputError, PlyError, PluginError, RoodiError, UnsupportedFormatError)
from .gaussians import GaussianCloud
from .io.ply import ply_info, read_ply, write_ply
from .io.splat import detect_format, read_cloud, write_cloud
from .stats import describe_cloud

__all__ = [
    "__version__",
    "CloudError", "ConfigError", "DatasetError", "EnvironmentProblemError", "FormatError", "InputError", "OutputError",
    "PlyError", "PluginError", "RoodiError", "UnsupportedFormatError",
    "GaussianCloud", "read_ply", "write_ply", "ply_info", "read_cloud", "write_cloud", "detect_format", "describe_cloud",
]
