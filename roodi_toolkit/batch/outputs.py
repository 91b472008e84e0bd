"""One output function for batch results: a local path (atomic rename) or any fsspec URL (``s3://``, ``gs://``,
``memory://`` ...) where the user has the driver installed.

Writers in this package take a local file path (formats pick their encoding from the extension), so a result is
first written to a temporary file beside a local destination, or in a temporary folder for a URL, and then moved or
uploaded whole: a reader never sees half an output, and a killed batch leaves none under the final name.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Callable

from ..errors import EnvironmentProblemError, OutputError
from ..io.files import atomic_path


def is_url(path: str) -> bool:
    """Return True for an fsspec URL (``scheme://...``), False for a local path (``file://`` counts as a URL)."""
    return "://" in str(path)


def _filesystem(url: str):
    try:
        import fsspec  # lazy: optional (not a dependency); only outputs at URLs need it
    except ImportError:
        raise EnvironmentProblemError(f"{url}: writing to URLs needs fsspec (pip install fsspec)") from None
    try:
        fs, path = fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as exc:
        raise EnvironmentProblemError(f"{url}: no fsspec driver for this URL ({exc}); install the driver (for example "
                                      "s3fs or gcsfs)") from None
    return fs, path


def output_exists(dest: str) -> bool:
    """Return whether ``dest`` (a path or URL) exists."""
    if is_url(dest):
        fs, path = _filesystem(dest)
        return bool(fs.exists(path))
    return Path(dest).is_file()


def file_id(path: str | os.PathLike) -> list[int] | None:
    """Return a local file's identity ``[device, inode, size, modification time in ns]`` (all kept by the rename or
    link that puts an output in place), or None if it is not there. The inode alone is not enough: a file the user
    writes just after deleting an output often gets the freed inode back."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns]


def write_output(dest: str, write: Callable[[Path], None], *, replace: bool = False,
                 ready: Callable[[Path], None] | None = None) -> str:
    """Call ``write(tmp_path)`` and put what it wrote at ``dest`` whole; return ``dest``.

    The temporary file keeps ``dest``'s name (hence its extension, which writers read the format from). Without
    ``replace``, a file at ``dest`` (one that appeared while the item ran) is left alone and the item fails.
    ``ready`` is called with the finished local temporary file before it is put in place.
    """
    if not is_url(dest):
        Path(dest).parent.mkdir(parents=True, exist_ok=True)
        suffix = "".join(Path(dest).suffixes[-2:]) if dest.lower().endswith(".compressed.ply") else None
        with atomic_path(dest, suffix=suffix, replace=replace, ready=ready) as tmp:
            write(tmp)
        return dest
    fs, path = _filesystem(dest)
    with tempfile.TemporaryDirectory(prefix="roodi-batch-") as folder:
        tmp = Path(folder) / Path(path).name
        write(tmp)
        try:
            parent = path.rsplit("/", 1)[0] if "/" in path else ""
            if parent:
                fs.makedirs(parent, exist_ok=True)
            fs.put_file(str(tmp), path + ".part")
            if fs.exists(path):
                if not replace:
                    with contextlib.suppress(OSError, FileNotFoundError):
                        fs.rm_file(path + ".part")
                    raise OutputError(f"{dest}: appeared while the batch ran (another program or run wrote it); "
                                      "it was left as it is: pass --overwrite to replace it")
                fs.rm_file(path)
            fs.mv(path + ".part", path)
        except OSError as exc:
            raise OutputError(f"{dest}: upload failed ({exc})") from None
    return dest
