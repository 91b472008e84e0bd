"""File output helpers: atomic writes and output-path policy. With ``ply.py`` the only modules that open files.

Outputs are written to a temporary file in the destination folder and moved into place, so a reader never sees a
half-written file and an interrupted run leaves any previous output intact. The move never replaces a file the
command did not see at its start: an output that did not exist (checked by :func:`check_output` without
``overwrite``, or absent when :func:`atomic_path` began) is put in place with a hard link, which fails if anything
appeared there meanwhile (another program, a second run to the same path), and the command then refuses in one line.

Inside :func:`output_group` (the CLI opens one per command, see ``roodi_toolkit.cli.main``) the finished temporary
files wait and are moved into place together when the group ends, with SIGTERM and Ctrl-C held over the moves: a
command's outputs appear together or not at all, whatever signal or full disk interrupts it.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from ..errors import EnvironmentProblemError, InputError, OutputError, os_error_problem

NAME_MAX = 255
"""Longest file name (in bytes) of the usual file systems: the hidden temporary name must fit it too."""

_RANDOM_CHARS = 8  # what tempfile.mkstemp puts between prefix and suffix


def _temp_affixes(dest: Path, suffix: str | None) -> tuple[str, str]:
    """Return mkstemp's (prefix, suffix) for ``dest``: ``.NAME.`` + 8 random characters + the suffix, with NAME cut
    (at a byte boundary of its file-system encoding) so the whole name stays within :data:`NAME_MAX` bytes."""
    sfx = suffix if suffix is not None else dest.suffix
    if len(os.fsencode(sfx)) > 64:  # no format has such an extension: keep the name short instead
        sfx = ""
    room = NAME_MAX - _RANDOM_CHARS - len(os.fsencode(sfx)) - 2  # the two dots
    name = os.fsencode(dest.name)[:room]
    return f".{os.fsdecode(name)}.", sfx


# ------------------------------------------------------------------------------------------ claims and groups

_CLAIMS: dict[str, bool] = {}
"""Output path -> whether its final step may replace a file there: False for a path :func:`check_output` found
free (it must still be free at the end), True for one the user let be replaced (``--overwrite``) or this process
wrote itself. Cleared by :func:`forget_claims` (the CLI does at the start and end of each command)."""


def _claim_key(dest: Path) -> str:
    parent = dest.parent if str(dest.parent) else Path(".")
    return os.path.join(os.path.realpath(parent), dest.name)


def forget_claims() -> None:
    """Forget what earlier :func:`check_output` and :func:`prepare_output_dir` calls recorded (one command's claims
    must not outlive it)."""
    _CLAIMS.clear()
    _FOLDER_CLAIMS.clear()


_FOLDER_CLAIMS: dict[str, set[str]] = {}
"""Output folder (resolved) -> the files in it when :func:`prepare_output_dir` made or checked it (relative paths):
a file written into it may replace one of those (``--overwrite``, a resumed stage), never one that appeared since."""


def _may_replace(dest: Path) -> bool:
    """Whether the final step may replace a file at ``dest``: as claimed for the path, else as its output folder's
    claim says (a file there at the start), else only if one is there now."""
    key = _claim_key(dest)
    claimed = _CLAIMS.get(key)
    if claimed is not None:
        return claimed
    folder = os.path.dirname(key)
    while True:
        present = _FOLDER_CLAIMS.get(folder)
        if present is not None:
            return Path(key).relative_to(folder).as_posix() in present
        parent = os.path.dirname(folder)
        if parent == folder:
            return os.path.lexists(dest)
        folder = parent


_NO_HARD_LINKS = {errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.ENOSYS, errno.EMLINK}


def _appeared(dest: Path) -> OutputError:
    return OutputError(f"{dest}: appeared while this command ran (another program or run wrote it); it was left as "
                       "it is and this output not written: pass --overwrite to replace it, or choose another path")


def _place_new(tmp: Path, dest: Path) -> None:
    """Move ``tmp`` to ``dest`` only if nothing is at ``dest`` (not even a dangling symbolic link): a hard link
    that fails when the name is taken, then the temporary name removed."""
    try:
        os.link(tmp, dest)
    except FileExistsError:
        raise _appeared(dest) from None
    except OSError as exc:
        if exc.errno not in _NO_HARD_LINKS:
            raise
        # a file system without hard links (FAT, some network shares): check, then rename (a tiny window remains)
        if os.path.lexists(dest):
            raise _appeared(dest) from None
        os.replace(tmp, dest)
        return
    os.unlink(tmp)


def _commit(tmp: Path, dest: Path, replace: bool) -> None:
    """Put ``tmp`` at ``dest`` (replacing what is there only if ``replace``), with SIGTERM / Ctrl-C held so the
    step is never cut in two; the path is then this process's own."""
    held = _hold_signals()
    try:
        if replace:
            os.replace(tmp, dest)
        else:
            _place_new(tmp, dest)
        _CLAIMS[_claim_key(dest)] = True
    finally:
        _release_signals(held)


class OutputGroup:
    """Finished outputs waiting to be put in place together (see :func:`output_group`)."""

    def __init__(self) -> None:
        self.pending: list[tuple[Path, Path, bool]] = []  # (temporary file, destination, may replace)
        self.created: list[Path] = []  # folders this group made: removed on failure if no file is left in them

    def add(self, tmp: Path, dest: Path, replace: bool) -> None:
        """Hold ``tmp`` for ``dest``; a later write of the same destination supersedes an earlier one."""
        key = _claim_key(dest)
        for entry in [e for e in self.pending if _claim_key(e[1]) == key]:
            self.pending.remove(entry)
            with contextlib.suppress(OSError):
                entry[0].unlink()
            replace = replace and entry[2]
        self.pending.append((tmp, dest, replace))

    def holds(self, path: str | os.PathLike) -> bool:
        """Whether an output for ``path`` is waiting in the group."""
        key = _claim_key(Path(path))
        return any(_claim_key(dest) == key for _, dest, _ in self.pending)

    def commit(self) -> None:
        """Put every held output in place (the group stays open for later ones): the new ones first (all refused, none placed, if one of their names was
        taken meanwhile), then the replacements; signals are held until all are done."""
        held = _hold_signals()
        try:
            fresh = [(t, d) for t, d, r in self.pending if not r]
            for _, dest in fresh:
                if os.path.lexists(dest):
                    raise _appeared(dest)
            placed: list[Path] = []
            try:
                for tmp, dest in fresh:
                    _place_new(tmp, dest)
                    placed.append(dest)
            except BaseException:
                for dest in placed:  # new files of ours: taken back, so that none of the outputs appears
                    with contextlib.suppress(OSError):
                        dest.unlink()
                raise
            for tmp, dest, replace in self.pending:
                if replace:
                    os.replace(tmp, dest)
            for _, dest, _ in self.pending:
                _CLAIMS[_claim_key(dest)] = True
            self.pending = []
        finally:
            _release_signals(held)

    def rollback(self) -> None:
        """Remove the held temporary files, and the folders this group made if no file is left in them."""
        for tmp, _, _ in self.pending:
            with contextlib.suppress(OSError):
                tmp.unlink()
        self.pending = []
        for folder in reversed(self.created):
            if folder.is_dir() and not folder.is_symlink() and not any(p.is_file() or p.is_symlink()
                                                                        for p in folder.rglob("*")):
                for sub in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: len(p.parts),
                                  reverse=True):
                    with contextlib.suppress(OSError):
                        sub.rmdir()
                with contextlib.suppress(OSError):
                    folder.rmdir()


_GROUP: contextvars.ContextVar[OutputGroup | None] = contextvars.ContextVar("roodi_output_group", default=None)


@contextlib.contextmanager
def output_group() -> Iterator[OutputGroup]:
    """Hold every output :func:`atomic_path` finishes inside the block, and put them all in place when it ends
    without an error; on an error, a signal or a full disk, remove them (and the folders made for them) instead.

    Nested groups join the outermost one. Do not read an output back inside the group: it is not in place yet.
    """
    outer = _GROUP.get()
    if outer is not None:
        yield outer
        return
    group = OutputGroup()
    token = _GROUP.set(group)
    try:
        yield group
    except BaseException:
        _GROUP.reset(token)
        group.rollback()
        raise
    _GROUP.reset(token)
    try:
        group.commit()
    except BaseException as exc:
        group.rollback()
        if isinstance(exc, OSError):
            raise OutputError(f"cannot put the outputs in place ({exc})") from None
        raise


def _note_created(out: Path) -> None:
    """Record, in the open group, the topmost folder that making ``out`` will create (removed if the group fails)."""
    group = _GROUP.get()
    if group is None or out.exists():
        return
    top = Path(os.path.abspath(out))
    while not top.parent.exists() and top.parent != top:
        top = top.parent
    group.created.append(top)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None, *, replace: bool | None = None,
                ready: Any = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path``, on failure remove it.

    Args:
        path: the final destination.
        suffix: the temporary file's suffix (defaults to the destination's, so writers that pick a format from the
            extension keep working).
        replace: whether the final step may replace a file at ``path``. Default: as :func:`check_output` recorded
            for the path, else only if a file is there when this begins; a file that appears at a path that may not
            be replaced is left alone and :class:`OutputError` raised.
        ready: called with the finished temporary file just before it is put in place (batch workers record its
            identity first, so that a run killed in between still knows the output as its own).

    Inside :func:`output_group` the finished file waits for the group's end.
    """
    dest = check_name_lengths(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{dest}: the folder {parent} does not exist")
    may_replace = _may_replace(dest) if replace is None else replace
    prefix, sfx = _temp_affixes(dest, suffix)
    # SIGTERM / Ctrl-C between creating the temporary file and entering the ``try`` below would leave it behind:
    # hold them until it is known (a held signal is acted on at the release, inside the ``try``)
    held = _hold_signals()
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=sfx, dir=parent)
    except OSError as exc:
        _release_signals(held)
        _raise_environment_problem(exc, dest)
        raise
    except BaseException:
        _release_signals(held)
        raise
    tmp_path = Path(tmp)
    handed_over = False
    try:
        try:
            os.close(fd)
        finally:
            _release_signals(held)  # a signal that came meanwhile raises here, inside the ``try``: tmp is removed
        yield tmp_path
        # mkstemp creates the file 0600; an output is a normal file, readable as the user's umask allows
        with contextlib.suppress(FileNotFoundError):
            os.chmod(tmp_path, 0o666 & ~_umask())
        if ready is not None:
            ready(tmp_path)
        group = _GROUP.get()
        if group is not None:
            group.add(tmp_path, dest, may_replace)
            handed_over = True
        else:
            _commit(tmp_path, dest, may_replace)
    except BaseException as exc:
        if not handed_over:
            with contextlib.suppress(OSError):
                tmp_path.unlink()
        if isinstance(exc, OSError):
            _raise_environment_problem(exc, dest)
        raise


def _hold_signals() -> bool:
    """Hold SIGTERM and Ctrl-C (see :mod:`roodi_toolkit.signals`); return the token for :func:`_release_signals`."""
    from .. import signals

    return signals.hold()


def _release_signals(held: bool) -> None:
    """End a hold; a signal that came meanwhile is acted on now (its handler may raise)."""
    from .. import signals

    signals.release(held)


def _umask() -> int:
    """Return the process's umask (reading it means setting it: set it straight back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _raise_environment_problem(exc: OSError, path: Path) -> None:
    """Raise :class:`EnvironmentProblemError` if ``exc`` is a full disk, a read-only folder or a denied write."""
    message = os_error_problem(exc, path)
    if message is not None:
        raise EnvironmentProblemError(message) from exc


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


PATH_MAX = 4095
"""Longest path (in bytes) Linux accepts."""


def check_name_lengths(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path, refusing a name longer than :data:`NAME_MAX` bytes in it (or a path longer than
    :data:`PATH_MAX`): the system would refuse to create it, as "File name too long"."""
    dest = Path(path)
    for part in dest.parts:
        if len(os.fsencode(part)) > NAME_MAX:
            raise OutputError(f"{dest}: the name {part[:24]}... is {len(os.fsencode(part))} bytes long, more than the "
                              f"{NAME_MAX} file systems allow; choose a shorter name")
    if len(os.fsencode(str(dest))) > PATH_MAX:
        raise OutputError(f"{dest}: the path is {len(os.fsencode(str(dest)))} bytes long, more than the {PATH_MAX} "
                          "the system allows; choose a shorter one")
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


def write_image(image: np.ndarray, path: str | os.PathLike) -> Path:
    """Write an image atomically as PNG (or the format of the extension).

    Args:
        image: ``[H, W]``, ``[H, W, 3]`` or ``[H, W, 4]``; float in [0, 1] becomes 8-bit, uint8/uint16 are kept.
    """
    from PIL import Image

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
    import warnings

    from PIL import Image, UnidentifiedImageError

    from ..limits import check_memory

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
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
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


def new_figure(*args: Any, figsize: tuple[float, float], **subplots: Any) -> tuple[Any, Any]:
    """Return ``(figure, axes)`` like ``plt.subplots`` but without pyplot, so the caller's matplotlib backend (a
    notebook's inline one, say) is neither needed nor changed; save it with :func:`save_figure`."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*args, **subplots)


def save_figure(fig: Any, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib figure atomically (format from the extension) and release it.

    Figures from :func:`new_figure` are not known to pyplot; ones made with pyplot are closed there too.
    """
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    finally:
        import sys

        if "matplotlib.pyplot" in sys.modules:
            sys.modules["matplotlib.pyplot"].close(fig)
    return Path(path)


def save_checkpoint(obj: Any, path: str | os.PathLike) -> Path:
    """Write a checkpoint (tensors, numbers, strings, lists, dicts only) atomically with ``torch.save``.

    ``torch.save`` writes through a Python file object: a full disk is then the ``OSError`` it is (named as an
    environment problem), not the zip writer's "enforce fail at inline_container.cc" of a path given to torch.
    """
    import torch

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(obj, f)
    return Path(path)


def check_torch_archive(path: str | os.PathLike, what: str = "checkpoint") -> None:
    """Refuse a ``torch.save`` zip archive whose entries are compressed: ``torch.save`` stores them as they are,
    and ``torch.load`` inflates a compressed entry whole before it checks its size (a 260 KB file took 256 MB).

    Raises:
        InputError: naming the file and the entry.
    """
    import zipfile

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
    import pickle

    import torch

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: checkpoint not found")
    check_torch_archive(p)
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, pickle.UnpicklingError, EOFError, OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read checkpoint ({' '.join(str(exc).split())[:200]})") from None
