"""One entry point for every splat format: :func:`read_cloud` detects the format by content, :func:`write_cloud` picks
it from the output's extension.

Readable: 3DGS PLY (Inria, gsplat, nerfstudio; binary or ASCII), PlayCanvas compressed PLY, Niantic SPZ (versions
1-4), PlayCanvas SOG (``.sog`` zip or ``meta.json`` + WebP), antimatter15 ``.splat``, GaussianSplats3D ``.ksplat``.
Writable: PLY, compressed PLY, SPZ (version 3).

Non-finite opacity: the quantised formats store opacity as a byte, and a byte of 255 (0) decodes to a logit of +inf
(-inf); 198 Gaussians of the PlayCanvas biker do. They mean "fully opaque" ("fully transparent"), not "broken", so
:func:`read_cloud` maps them to +-``OPACITY_LOGIT_LIMIT`` = logit(1 - 1e-6) = 13.8155, the clamp splat-transform
itself applies when it turns a byte into a logit (its SOG, .splat and .ksplat readers): sigmoid of it is 0.999999,
the same 8-bit alpha, and every later step (KNN, W2 distances, rendering, writing) sees a finite number. NaN values
and infinities elsewhere are left as they are: they are real damage, counted by ``info`` and dropped by
``--filter-nan`` where a command offers it.
"""

from __future__ import annotations

import gzip
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, RoodiError
from ..gaussians import GaussianCloud
from .compressed_ply import is_compressed, read_compressed_ply, write_compressed_ply
from .ply import _open_checked, read_header, read_ply, write_ply
from .sog import read_sog
from .splat_files import looks_like_ksplat, read_ksplat, read_splat
from .spz import read_spz, write_spz

OPACITY_LOGIT_LIMIT = float(np.log((1 - 1e-6) / 1e-6))
"""|logit| that +-inf opacities are read as: logit(1 - 1e-6) = 13.8155 (splat-transform's own clamp)."""

READ_FORMATS = ("ply", "compressed-ply", "spz", "sog", "splat", "ksplat")
WRITE_SUFFIXES = {".compressed.ply": "compressed-ply", ".ply": "ply", ".spz": "spz"}


@dataclass(frozen=True)
class ReadReport:
    """What :func:`read_cloud` found: the detected format and how many +-inf opacity logits it made finite."""

    path: str
    format: str
    opacity_pos_inf: int
    opacity_neg_inf: int


def _fail(p: Path | str, msg: str) -> FormatError:
    return FormatError(f"{p}: {msg}")


def _check_file(path: str | os.PathLike) -> Path:
    p = Path(path)
    if p.name.lower().endswith(".ply"):  # a PLY name keeps the PLY reader's own errors (PlyError)
        return _open_checked(p)[0]
    if not p.exists():
        raise _fail(p, "no such file")
    if p.is_dir():
        meta = p / "meta.json"
        if meta.is_file():
            return meta
        raise _fail(p, "is a folder; give a splat file (or a folder holding a SOG meta.json)")
    if not p.is_file():
        raise _fail(p, "is not a regular file")
    if not os.access(p, os.R_OK):
        raise _fail(p, "cannot read file: permission denied")
    return p


def detect_format(path: str | os.PathLike) -> str:
    """Return the format of a splat file from its content: one of :data:`READ_FORMATS`.

    Magic bytes decide where a format has them (``ply``, ``NGSP``, gzip, zip, JSON, the ksplat header); a
    ``.splat`` file has no header, so it is recognised by its extension or, without one, by a size that is a multiple
    of 32 bytes and a first record of finite positions and positive scales.

    Raises:
        FormatError: the content matches no readable format (the message names the formats).
    """
    p = _check_file(path)
    size = p.stat().st_size
    if size == 0 and not p.name.lower().endswith(".ply"):
        raise _fail(p, "file is empty")
    with open(p, "rb") as f:
        head = f.read(4096)
    if head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return "compressed-ply" if is_compressed(read_header(p)) else "ply"
    if head[:4] == b"NGSP":
        return "spz"
    if head[:2] == b"\x1f\x8b":
        try:
            with gzip.open(p) as g:
                inner = g.read(4)
        except (OSError, EOFError, zlib.error):
            raise _fail(p, "gzip data is corrupt or truncated (an SPZ file is gzip of an NGSP stream)") from None
        if inner == b"NGSP":
            return "spz"
        raise _fail(p, "gzip file that is not SPZ (no NGSP magic inside)")
    if head[:4] == b"PK\x03\x04" or zipfile.is_zipfile(p):
        return "sog"
    if _is_sog_meta(head):
        return "sog"
    if looks_like_ksplat(head, size):
        return "ksplat"
    if p.suffix.lower() == ".splat":
        return "splat"
    if size % 32 == 0 and len(head) >= 32 and not p.name.lower().endswith(".ply"):
        first = np.frombuffer(head[:24], "<f4")
        if np.all(np.isfinite(first)) and np.all(first[3:6] > 0):
            return "splat"
    if p.name.lower().endswith(".ply"):  # say what is wrong as a PLY (PlyError "not a PLY file ...")
        read_header(p)
    raise _fail(p, "unknown splat format (readable: PLY, compressed PLY, SPZ, SOG .sog/meta.json, .splat, .ksplat)")


def finite_opacity(cloud: GaussianCloud) -> tuple[GaussianCloud, int, int]:
    """Return the cloud with +-inf opacity logits replaced by +-:data:`OPACITY_LOGIT_LIMIT`, and the two counts."""
    o = cloud.opacity_logits
    pos, neg = np.isposinf(o), np.isneginf(o)
    n_pos, n_neg = int(pos.sum()), int(neg.sum())
    if n_pos or n_neg:
        o = o.copy()
        o[pos] = OPACITY_LOGIT_LIMIT
        o[neg] = -OPACITY_LOGIT_LIMIT
        cloud = cloud.with_fields(opacity_logits=o)
    return cloud, n_pos, n_neg


def _read_ply(p: Path) -> GaussianCloud:
    return read_ply(p)


def _read_compressed_ply(p: Path) -> GaussianCloud:
    return read_compressed_ply(p, read_header(p))


def _read_spz(p: Path) -> GaussianCloud:
    return read_spz(p)


def _read_sog(p: Path) -> GaussianCloud:
    return read_sog(p)


def _read_splat(p: Path) -> GaussianCloud:
    return read_splat(p)


def _read_ksplat(p: Path) -> GaussianCloud:
    return read_ksplat(p)


# format -> reader; modules are imported on use so that reading a PLY imports none of the others
_READERS = {"ply": _read_ply, "compressed-ply": _read_compressed_ply, "spz": _read_spz, "sog": _read_sog,
            "splat": _read_splat, "ksplat": _read_ksplat}


def read_cloud_report(path: str | os.PathLike, *, raw: bool = False) -> tuple[GaussianCloud, ReadReport]:
    """Return the Gaussians of a splat file in any readable format, with a :class:`ReadReport`.

    Args:
        path: the file (for SOG, the ``.sog`` zip, the ``meta.json`` or the folder holding it).
        raw: keep +-inf opacity logits as decoded instead of making them finite (the counts are reported either way).
    """
    p = _check_file(path)
    fmt = detect_format(p)
    try:
        # damaged values decode to NaN/Inf, which are counted and reported later: no RuntimeWarnings meanwhile
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            cloud = _READERS[fmt](p)
    except (RoodiError, MemoryError, ImportError):  # ours already name the file; a missing library is no corrupt file
        raise
    except OSError as exc:
        raise _fail(p, f"cannot read file ({exc.strerror or exc})") from None
    except Exception as exc:  # noqa: BLE001 - a corrupt file must give one line naming it, never a traceback
        raise _fail(p, f"corrupt {fmt} file ({type(exc).__name__}: {exc})") from None
    if raw:
        o = cloud.opacity_logits
        n_pos, n_neg = int(np.isposinf(o).sum()), int(np.isneginf(o).sum())
    else:
        cloud, n_pos, n_neg = finite_opacity(cloud)
    return cloud, ReadReport(str(p), fmt, n_pos, n_neg)


def _is_sog_meta(head: bytes) -> bool:
    """Return whether a file's first bytes are a JSON object: a SOG ``meta.json`` (:func:`detect_format`)."""
    return head.lstrip()[:1] == b"{"


def input_paths(path: str | os.PathLike) -> list[str]:
    """Return what a splat input occupies, for the output guards: the path and, for a SOG ``meta.json``, its folder.

    A ``meta.json`` names textures beside it (``means_l.webp`` ...): the folder is the input, so nothing may be
    written into it, as into any input folder (:func:`~roodi_toolkit.io.files.refuse_inside_inputs`). A folder given
    as the input is guarded as a folder already; any other file stands alone.
    """
    p = Path(path)
    if p.is_file() and not zipfile.is_zipfile(p):
        try:
            with open(p, "rb") as f:
                head = f.read(64)
        except OSError:  # the reader says what is wrong with it
            return [str(p)]
        if _is_sog_meta(head):
            return [str(p), str(p.parent)]
    return [str(p)]


def read_cloud(path: str | os.PathLike) -> GaussianCloud:
    """Return the Gaussians of a splat file in any readable format (detected by content).

    +-inf opacity logits become +-:data:`OPACITY_LOGIT_LIMIT` (see the module docstring); everything else is kept
    as decoded.

    Raises:
        FormatError / PlyError: missing, unknown, truncated or corrupt file; one line naming the file and the problem.

    Example:
        >>> import tempfile, pathlib
        >>> c = GaussianCloud.from_activated(np.random.default_rng(0).normal(size=(300, 3)),
        ...     scales=np.full((300, 3), 0.05), opacities=np.full(300, 0.5), rgb=np.full((300, 3), 0.5))
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "scene.spz"
        >>> _ = write_cloud(c, out)
        >>> back = read_cloud(out)
        >>> len(back), bool(np.abs(back.means - c.means).max() < 1e-3)
        (300, True)
    """
    return read_cloud_report(path)[0]


def output_format(path: str | os.PathLike) -> str:
    """Return the format :func:`write_cloud` writes for a path's extension.

    Raises:
        FormatError: an extension no writer handles.
    """
    name = Path(path).name.lower()
    for suffix, fmt in WRITE_SUFFIXES.items():
        if name.endswith(suffix):
            return fmt
    raise _fail(path, "cannot write this format; give an output ending in .ply, .compressed.ply or .spz")


def write_cloud(cloud: GaussianCloud, path: str | os.PathLike, *, comments: tuple[str, ...] = (),
                rows: np.ndarray | None = None) -> Path:
    """Write ``cloud`` atomically in the format its extension names (.ply, .compressed.ply, .spz); return the path.

    ``rows`` (a boolean mask ``[N]`` or an integer index) writes only those Gaussians, as ``cloud.select(rows)``
    would (a PLY gathers them while writing, without that copy). The quantised formats cannot hold NaN/Inf values:
    such rows are refused with a one-line error (drop them first, e.g. ``cloud.select(~cloud.nonfinite_rows())``).

    Raises:
        FormatError: unknown extension, an empty cloud, or non-finite values in a quantised format.
    """
    fmt = output_format(path)
    picked = None if rows is None else np.asarray(rows)
    count = len(cloud) if picked is None else int(picked.sum()) if picked.dtype == np.bool_ else len(picked)
    if count == 0:
        raise _fail(path, "refusing to write a cloud with no Gaussians")
    if fmt == "ply":
        return write_ply(cloud, path, comments=comments, rows=rows)
    if rows is not None:
        cloud = cloud.select(rows)
    cloud, _, _ = finite_opacity(cloud)
    bad = cloud.nonfinite_rows()
    if bad.any():
        raise _fail(path, f"{int(bad.sum())} Gaussians have NaN/Inf values, which {fmt} cannot store; "
                          "drop them first (--filter-nan)")
    if fmt == "compressed-ply":
        return write_compressed_ply(cloud, path)
    return write_spz(cloud, path)
