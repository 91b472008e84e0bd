"""File output helpers: atomic writes and output-path policy. With ``ply.py`` the only modules that open files.

Outputs are written to a temporary file in the destination folder and moved into place, so a reader never sees a
half-written file and an interrupted run leaves any previous output intact. The move never replaces a file the
command did not see at its start, and inside :func:`output_group` a command's outputs appear together or not at all
(:mod:`roodi_toolkit.io.atomic`, whose :func:`atomic_path`, :func:`output_group` and :func:`forget_claims` are
re-exported here). This module says which paths may be written (:func:`check_output`, :func:`prepare_output_dir`)
and writes and reads JSON, images and checkpoints.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import pickle
import sys
import warnings
import zipfile
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from ..errors import InputError, OutputError
from ..limits import check_memory
from .atomic import (NAME_MAX, PATH_MAX, OutputGroup, atomic_path, check_name_lengths,  # noqa: F401
                     forget_claims, output_group)
from .atomic import _CLAIMS, _FOLDER_CLAIMS, _claim_key, _note_created, _raise_environment_problem


def check_output(path: str | os.PathLike, *, overwrite: bool,
                 inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Return ``path`` as a Path after checking it may be written, and record the answer for the final step of
    :func:`atomic_path`: a path found free must still be free when the output is put in place.

    A symbolic link counts as a file there, even a dangling one (replacing it needs ``overwrite`` like any file).

    Raises:
        OutputError: the path is one of the inputs, exists without ``overwrite``, is a folder, or its folder is missing.
    """
    dest = check_name_lengths(path)
    for src in inputs:
        if src is not None and same_file(src, dest):
            raise OutputError(f"{dest}: output is the same file as the input {src}; choose another output path")
    refuse_inside_inputs(dest, inputs)
    if dest.is_dir():
        raise OutputError(f"{dest}: is a folder; give a file path for this output")
    if os.path.lexists(dest) and not overwrite:
        what = "" if not dest.is_symlink() else " (a symbolic link)" if dest.exists() else \
            " (a symbolic link to nothing)"
        raise OutputError(f"{dest}: already exists{what}; pass --overwrite to replace it")
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{dest}: the folder {parent} does not exist; create it first")
    _CLAIMS[_claim_key(dest)] = bool(overwrite)
    return dest


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Return True if ``a`` and ``b`` name the same file, however spelled: ``./o.ply`` and ``o.ply``, a symbolic
    link and its target, two hard links (``os.path.samefile`` when both exist, else the resolved paths)."""
    pa, pb = Path(a), Path(b)
    if pa.exists() and pb.exists():
        return os.path.samefile(pa, pb)
    return os.path.realpath(pa) == os.path.realpath(pb)


def check_outputs(named: Sequence[tuple[str, str | os.PathLike | None]], *, overwrite: bool,
                  inputs: Sequence[str | os.PathLike | None] = ()) -> None:
    """Check several outputs of one command with :func:`check_output`, and that no two of them are the same file.

    Args:
        named: ``(option, path)`` pairs (``path`` None when the output is not asked for); the option names the
            output in the error.
        inputs: the command's input files and folders.
    """
    given = [(name, p) for name, p in named if p is not None]
    for _, p in given:
        check_output(p, overwrite=overwrite, inputs=[i for i in inputs if i is not None])
    for i, (name_a, a) in enumerate(given):
        for name_b, b in given[i + 1:]:
            if same_file(a, b):
                raise OutputError(f"{b}: {name_b} is the same file as {name_a} ({a}); give each output its own path")


def refuse_inside_inputs(dest: str | os.PathLike, inputs: Sequence[str | os.PathLike | None]) -> None:
    """Raise OutputError if ``dest`` is an input folder or lies inside one, however the paths are spelled (symbolic
    links and ``..`` resolved, the same folder by another name found with ``os.path.samefile``)."""
    target = Path(os.path.realpath(dest))
    for src in inputs:
        if src is None or not Path(src).is_dir():
            continue
        folder = Path(os.path.realpath(src))
        probe = target
        while True:  # walk up from the output to the first folder that exists, then compare each ancestor
            if probe.exists() and os.path.samefile(probe, folder):
                raise OutputError(f"{dest}: is inside the input folder {src}; write outputs elsewhere (inputs are "
                                  "never written)")
            if probe.parent == probe:
                break
            probe = probe.parent


def check_output_dir(path: str | os.PathLike, *, overwrite: bool, allow_existing: bool = False,
                     inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Raise what :func:`prepare_output_dir` would refuse, creating nothing (for commands that check their other
    inputs before they make the folder)."""
    out = check_name_lengths(path)
    refuse_inside_inputs(out, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (overwrite or allow_existing):
        raise OutputError(f"{out}: folder exists and is not empty; pass --overwrite to write into it")
    return out


def prepare_output_dir(path: str | os.PathLike, *, overwrite: bool, allow_existing: bool = False,
                       inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Create an output folder and return it.

    An existing non-empty folder is refused unless ``overwrite`` (its contents are then replaced file by file) or
    ``allow_existing`` (a stage-reusing command such as ``extract`` or ``train --resume``); so is a folder that is,
    or lies inside, one of the ``inputs`` folders. Inside :func:`output_group`, a folder made here is removed again
    if the group fails and no file is left in it.
    """
    out = check_output_dir(path, overwrite=overwrite, allow_existing=allow_existing, inputs=inputs)
    _note_created(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _raise_environment_problem(exc, out)
        raise OutputError(f"{out}: cannot create folder ({exc.strerror})") from None
    # what may be replaced in it: the files there now (none in a new or empty folder), never one that appears later
    _FOLDER_CLAIMS[os.path.realpath(out)] = {p.relative_to(out).as_posix() for p in out.rglob("*")
                                              if p.is_file() or p.is_symlink()}
    return out


def json_ready(obj: Any) -> Any:
    """Return ``obj`` with numpy scalars and arrays as Python numbers and lists, paths as strings, and every NaN or
    infinity as None (``null``): JSON has no such numbers, and a bare ``NaN`` makes the file unreadable to strict
    parsers (JavaScript's ``JSON.parse``, ``jq``)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        return json_ready(obj.item())
    if isinstance(obj, dict):
        return {(k.item() if isinstance(k, np.generic) else k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def json_text(obj: Any, **dumps: Any) -> str:
    """Return ``obj`` as strict JSON (:func:`json_ready`; anything else unknown is written as its ``str``)."""
    return json.dumps(json_ready(obj), allow_nan=False, default=str, **dumps)


def write_json(obj: Any, path: str | os.PathLike) -> Path:
    """Write ``obj`` as indented JSON atomically; numpy scalars and arrays are converted, NaN and infinities
    written as ``null`` (:func:`json_ready`)."""

    def default(o: Any) -> Any:
        raise TypeError(f"cannot write {type(o).__name__} as JSON")

    text = json.dumps(json_ready(obj), indent=2, allow_nan=False, default=default) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def parse_json(text: str | bytes, where: str | os.PathLike, what: str = "JSON file") -> Any:
    """Parse JSON text read from ``where``, every failure a one-line :class:`~roodi_toolkit.errors.InputError`:
    malformed text, and nesting too deep for the parser (``[[[[...`` a hundred thousand deep)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: malformed {what}: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{where}: {what} is not UTF-8 text ({exc.reason})") from None
    except RecursionError:
        raise InputError(f"{where}: {what} is nested too deeply to read (lists or objects inside each other "
                         "thousands of levels deep)") from None


def read_json(path: str | os.PathLike, what: str = "JSON file") -> Any:
    """Read a JSON file, turning every failure into a one-line :class:`~roodi_toolkit.errors.RoodiError`."""
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise InputError(f"{p}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{p}: is a folder, expected a {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read {what} ({exc})") from None
    return parse_json(text, p, what)


def file_stems(names: Sequence[str | None]) -> list[str]:
    """Return a file stem for each view name, unique among them: characters other than letters, digits and ``-_.``
    become ``_``, a missing name ``view_###`` (its index), and a name met before gains its index (a Blender set's
    ``test/r_0`` is ``r_0`` as its ``train/r_0`` is, so their files would overwrite each other).

    Example:
        >>> file_stems(["r_0", "r_1", "r_0", None, "cam/a b"])
        ['r_0', 'r_1', 'r_0_002', 'view_003', 'cam_a_b']
    """
    stems: list[str] = []
    seen: set[str] = set()
    for i, name in enumerate(names):
        base = "".join(c if c.isalnum() or c in "-_." else "_" for c in (name or f"view_{i:03d}"))
        stem = base if base not in seen else f"{base}_{i:03d}"
        seen.add(stem)
        stems.append(stem)
    return stems


def pil_image() -> Any:
    """Return Pillow's ``PIL.Image`` module (its readers and writers of PNG, JPEG and WebP)."""
    from PIL import Image  # lazy: prune, info and convert of splat files never read or write an image

    return Image


def _torch() -> Any:
    """Return the ``torch`` module (checkpoints are ``torch.save`` archives)."""
    import torch  # lazy: 2-5 s to import; the commands on splat files never read or write a checkpoint

    return torch


def write_image(image: np.ndarray, path: str | os.PathLike) -> Path:
    """Write an image atomically as PNG (or the format of the extension).

    Args:
        image: ``[H, W]``, ``[H, W, 3]`` or ``[H, W, 4]``; float in [0, 1] becomes 8-bit, uint8/uint16 are kept.
    """
    Image = pil_image()
    arr = np.asarray(image)
    if arr.dtype.kind == "f":
        arr = (np.clip(np.nan_to_num(arr), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    elif arr.dtype == np.bool_:
        arr = arr.astype(np.uint8) * 255
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.dtype == np.uint16:
        img = Image.fromarray(arr)
    else:
        img = Image.fromarray(arr.astype(np.uint8))
    with atomic_path(path) as tmp:
        img.save(tmp)
    return Path(path)


_BYTES_PER_PIXEL = {"1": 2, "L": 2, "P": 8, "I;16": 4, "I;16L": 4, "I;16B": 4, "I;16N": 4, "I": 8, "F": 8}
"""Memory a decoded pixel takes (Pillow's copy and ours), by Pillow mode; others (RGB, RGBA, ...): 8 bytes."""


def image_memory(mode: str, width: int, height: int) -> int:
    """Return about how many bytes reading a ``width`` x ``height`` image of Pillow ``mode`` takes."""
    return _BYTES_PER_PIXEL.get(mode, 8) * int(width) * int(height)


@contextlib.contextmanager
def open_image(path: str | os.PathLike, what: str = "image") -> Iterator[Any]:
    """Open an image file with Pillow (header only: nothing is decoded yet), its failures one-line
    :class:`InputError`; an image too large for the memory available is refused before decoding.

    Pillow's own decompression-bomb guard (a warning on stderr above 89 M pixels, an error above 179 M) is
    replaced by that memory bound, which says what the image needs and what there is.
    """
    Image = pil_image()
    p = Path(path)
    limit = Image.MAX_IMAGE_PIXELS
    try:
        Image.MAX_IMAGE_PIXELS = None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(p)
    except FileNotFoundError:
        raise InputError(f"{p}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{p}: is a folder, expected an {what} file") from None
    except (Image.UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise InputError(f"{p}: cannot read {what} ({' '.join(str(exc).split())[:200]})") from None
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    with img:
        width, height = img.size
        check_memory(image_memory(img.mode, width, height), f"{p}: this {width}x{height} {what}",
                     "make it smaller first")
        yield img


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as a numpy array (uint8 or uint16, channels last), with one-line errors.

    Grey and 1-bit images give ``[H, W]`` uint8, 16-bit ones ``[H, W]`` uint16, others ``[H, W, 3]`` or
    ``[H, W, 4]`` uint8. A 32-bit integer image is read as 16-bit if its values fit, else refused, as are 32-bit
    floating-point images (they would wrap or clip silently).

    Raises:
        InputError: missing, unreadable, corrupt, too large for the memory available, or of 32-bit values.
    """
    p = Path(path)
    with open_image(p) as img:
        try:
            if img.mode in ("I;16", "I;16B", "I;16L", "I;16N"):
                return np.asarray(img).astype(np.uint16)
            if img.mode == "I":
                arr = np.asarray(img)
                lo, hi = (int(arr.min()), int(arr.max())) if arr.size else (0, 0)
                if lo < 0 or hi > 65535:
                    raise InputError(f"{p}: 32-bit integer image with values from {lo} to {hi}; images, masks and "
                                     "depth maps must be 8- or 16-bit (values 0-65535)")
                return arr.astype(np.uint16)
            if img.mode == "F":
                raise InputError(f"{p}: 32-bit floating-point image; images and masks must be 8- or 16-bit "
                                 "(give depth maps as .npy)")
            if img.mode == "1":
                img = img.convert("L")
            elif img.mode not in ("L", "RGB", "RGBA"):
                img = img.convert("RGBA" if "A" in img.mode else "RGB")
            return np.asarray(img).copy()
        except (OSError, SyntaxError, ValueError, EOFError) as exc:  # decoding a corrupt or truncated file
            raise InputError(f"{p}: cannot read image ({' '.join(str(exc).split())[:200]})") from None


def save_figure(fig: Any, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib figure atomically (format from the extension) and release it.

    Figures from :func:`roodi_toolkit.viz.figures.new_figure` are not known to pyplot; ones made with pyplot are closed there too.
    """
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    finally:
        if "matplotlib.pyplot" in sys.modules:
            sys.modules["matplotlib.pyplot"].close(fig)
    return Path(path)


def save_checkpoint(obj: Any, path: str | os.PathLike) -> Path:
    """Write a checkpoint (tensors, numbers, strings, lists, dicts only) atomically with ``torch.save``.

    ``torch.save`` writes through a Python file object: a full disk is then the ``OSError`` it is (named as an
    environment problem), not the zip writer's "enforce fail at inline_container.cc" of a path given to torch.
    """
    torch = _torch()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(obj, f)
    return Path(path)


def check_torch_archive(path: str | os.PathLike, what: str = "checkpoint") -> None:
    """Refuse a ``torch.save`` zip archive whose entries are compressed: ``torch.save`` stores them as they are,
    and ``torch.load`` inflates a compressed entry whole before it checks its size (a 260 KB file took 256 MB).

    Raises:
        InputError: naming the file and the entry.
    """
    p = Path(path)
    try:
        if not zipfile.is_zipfile(p):
            return  # the legacy (pickle) format, or not a checkpoint: torch.load says so
        with zipfile.ZipFile(p) as archive:
            for info in archive.infolist():
                if info.compress_type != zipfile.ZIP_STORED or info.file_size > p.stat().st_size:
                    raise InputError(f"{p}: {what} entry {info.filename!r} is compressed ({info.file_size:,} bytes "
                                     "once inflated); torch.save never compresses: not a PyTorch file, or a "
                                     "decompression bomb")
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise InputError(f"{p}: cannot read {what} ({exc})") from None


def load_checkpoint(path: str | os.PathLike) -> Any:
    """Read a checkpoint written by :func:`save_checkpoint` with ``torch.load(weights_only=True)`` (no code runs;
    a compressed entry is refused first, :func:`check_torch_archive`)."""
    torch = _torch()
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: checkpoint not found")
    check_torch_archive(p)
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, pickle.UnpicklingError, EOFError, OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read checkpoint ({' '.join(str(exc).split())[:200]})") from None
