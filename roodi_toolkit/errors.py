"""Errors the library raises, one class per kind of failure. Each message says what was wrong and what to do about it.

The kinds, and the classes that refine them::

    RoodiError                   base of every error a user can act on
    ├── InputError               a file or option the user gave is wrong
    │   ├── UnsupportedFormatError   a file in a format or variant the toolkit does not read
    │   ├── FormatError              a splat file (compressed PLY, SPZ, SOG, .splat, .ksplat) that is corrupt
    │   ├── PlyError, CloudError, DatasetError, ModelError, ConfigError, OutputError
    ├── PluginError              a plugin is unknown, failed to load, or broke its interface
    └── EnvironmentProblemError  the machine is at fault: a missing system library, a read-only folder, a full disk

The CLI turns any :class:`RoodiError` into one line on stderr and exit code 1 (``roodi_toolkit.cli.main`` documents
the mapping); library code never prints or exits.

Example:
    >>> import errno
    >>> print(os_error_problem(OSError(errno.ENOSPC, "No space left on device"), "out.ply"))
    out.ply: the disk is full (No space left on device); free some space or write the output to another disk
"""

from __future__ import annotations

import errno
import os
import re


class RoodiError(Exception):
    """Base class of every error a user can act on."""


class InputError(RoodiError):
    """A file or option the user gave is wrong: missing, malformed, out of range or inconsistent."""


class UnsupportedFormatError(InputError):
    """A file is in a format (or a variant of one) that the toolkit does not read; the message names what does."""


class PlyError(InputError):
    """A PLY file could not be read or written."""


class CloudError(InputError):
    """A Gaussian cloud is malformed or unsuitable for the requested operation."""


class DatasetError(InputError):
    """A posed-image dataset is missing, malformed or inconsistent."""


class ModelError(InputError):
    """A model or distillation folder is missing, malformed or does not belong to its model (raised by
    :mod:`roodi_toolkit.io.model` and :mod:`roodi_toolkit.io.other_models`; importable from the first as before)."""


class OutputError(InputError):
    """An output path is unusable (exists without overwrite, equals an input, its folder is missing)."""


class ConfigError(InputError):
    """An option or configuration value is out of range or inconsistent."""


class FormatError(InputError):
    """A splat file in another format (compressed PLY, SPZ, SOG, .splat, .ksplat) could not be read or written."""


class PluginError(RoodiError):
    """A plugin is unknown, failed to load, or does not follow its interface."""


class EnvironmentProblemError(RoodiError):
    """The machine is at fault, not the input: a missing system library, a read-only folder, a full disk, no display."""


class InputWarning(UserWarning):
    """An input was used with something left out or assumed (frames whose images are missing, a split chosen for the
    user): issued with :func:`warnings.warn`, shown by the CLI as one ``warning:`` line on stderr."""


# errno -> (what is wrong, what to do) for the failures of writing an output that the machine, not the user, causes
_OS_PROBLEMS: dict[int, tuple[str, str]] = {
    errno.ENOSPC: ("the disk is full", "free some space or write the output to another disk"),
    errno.EDQUOT: ("the disk quota is used up", "free some space or write the output to another disk"),
    errno.EROFS: ("the file system is read-only", "write the output to a writable folder"),
    errno.EACCES: ("permission denied", "write the output to a folder you may write to, or change its permissions"),
    errno.EPERM: ("operation not permitted", "write the output to a folder you may write to, or change its permissions"),
}

# shared library -> Debian package, for the libraries Open3D and PyVista/VTK load (DESIGN.md, facts about the machines)
SYSTEM_LIBRARIES: dict[str, str] = {
    "libGL.so": "libgl1",
    "libEGL.so": "libegl1",
    "libgomp.so": "libgomp1",
    "libusb-1.0.so": "libusb-1.0-0",
    "libOSMesa.so": "libosmesa6",
    "libX11.so": "libx11-6",
    "libXrender.so": "libxrender1",
    "libglib-2.0.so": "libglib2.0-0",
}


def os_error_problem(exc: OSError, path: str | os.PathLike | None = None) -> str | None:
    """Return a one-line message naming the environment problem behind ``exc`` and what to do, or None if it is not one.

    Args:
        exc: the error from writing (or creating) an output.
        path: the output it concerns (default the error's own file name).
    """
    if exc.errno not in _OS_PROBLEMS:
        return None
    what, todo = _OS_PROBLEMS[exc.errno]
    where = path if path is not None else exc.filename
    detail = f" ({exc.strerror})" if exc.strerror else ""
    return f"{where}: {what}{detail}; {todo}" if where else f"{what}{detail}; {todo}"


def missing_library_problem(exc: BaseException) -> str | None:
    """Return a one-line message for an import that failed on a missing system library (``lib*.so``), else None."""
    text = str(exc)
    match = re.search(r"(lib[\w.+-]*?\.so)(\.[\d.]+)?", text)
    if match is None or not isinstance(exc, (ImportError, OSError)):
        return None
    lib = match.group(1) + (match.group(2) or "")
    package = SYSTEM_LIBRARIES.get(match.group(1))
    todo = f"install it (Debian/Ubuntu: apt-get install {package})" if package else "install the system package " \
        "that provides it"
    return f"the system library {lib} is missing ({' '.join(text.split())[:160]}); {todo}"
