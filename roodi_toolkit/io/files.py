"""File output helpers: atomic writes and output-path policy. With ``ply.py`` the only modules that open files.

Outputs are written to a temporary file in the destination folder and renamed into place, so a reader never sees a
half-written file and an interrupted run leaves any previous output intact.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import tempfile
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from ..errors import EnvironmentProblemError, InputError, OutputError, os_error_problem


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``, on failure remove it.

    Args:
        path: the final destination.
        suffix: the temporary file's suffix (defaults to the destination's, so writers that pick a format from the
            extension keep working).
    """
    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{dest}: the folder {parent} does not exist")
    # SIGTERM / Ctrl-C between creating the temporary file and entering the ``try`` below would leave it behind:
    # hold them until it is known (a held signal is delivered on unblocking, inside the ``try``)
    held = _hold_signals()
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=suffix if suffix is not None else dest.suffix,
                                   dir=parent)
    except OSError as exc:
        _release_signals(held)
        _raise_environment_problem(exc, dest)
        raise
    except BaseException:
        _release_signals(held)
        raise
    tmp_path = Path(tmp)
    try:
        os.close(fd)
        _release_signals(held)
        yield tmp_path
        # mkstemp creates the file 0600; an output is a normal file, readable as the user's umask allows
        with contextlib.suppress(FileNotFoundError):
            os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, dest)
    except BaseException as exc:
        _release_signals(held)  # (again, if os.close failed before the release)
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        if isinstance(exc, OSError):
            _raise_environment_problem(exc, dest)
        raise


_HELD = (signal.SIGTERM, signal.SIGINT)


def _hold_signals() -> Any:
    """Block SIGTERM and SIGINT in this thread; return the previous mask (None where the platform cannot)."""
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)


def _release_signals(previous: Any) -> None:
    if previous is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


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
    """Return ``path`` as a Path after checking it may be written.

    Raises:
        OutputError: the path is one of the inputs, exists without ``overwrite``, is a folder, or its folder is missing.
    """
    dest = Path(path)
    for src in inputs:
        if src is not None and same_file(src, dest):
            raise OutputError(f"{dest}: output is the same file as the input {src}; choose another output path")
    refuse_inside_inputs(dest, inputs)
    if dest.is_dir():
        raise OutputError(f"{dest}: is a folder; give a file path for this output")
    if dest.exists() and not overwrite:
        raise OutputError(f"{dest}: already exists; pass --overwrite to replace it")
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{dest}: the folder {parent} does not exist; create it first")
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
    out = Path(path)
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
    or lies inside, one of the ``inputs`` folders.
    """
    out = check_output_dir(path, overwrite=overwrite, allow_existing=allow_existing, inputs=inputs)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _raise_environment_problem(exc, out)
        raise OutputError(f"{out}: cannot create folder ({exc.strerror})") from None
    return out


def write_json(obj: Any, path: str | os.PathLike) -> Path:
    """Write ``obj`` as indented JSON atomically; numpy scalars and arrays are converted."""

    def default(o: Any) -> Any:
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"cannot write {type(o).__name__} as JSON")

    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=default) + "\n")
    return Path(path)


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
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}: malformed {what}: {exc.msg} at line {exc.lineno} column {exc.colno}") from None


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


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as a numpy array (uint8 or uint16, channels last), with one-line errors."""
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    try:
        with Image.open(p) as img:
            if img.mode in ("I;16", "I;16B", "I;16L", "I"):
                return np.asarray(img).astype(np.uint16)
            if img.mode not in ("L", "RGB", "RGBA"):
                img = img.convert("RGBA" if "A" in img.mode else "RGB")
            return np.asarray(img).copy()
    except FileNotFoundError:
        raise InputError(f"{p}: image not found") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"{p}: cannot read image ({exc})") from None


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
    """Write a checkpoint (tensors, numbers, strings, lists, dicts only) atomically with ``torch.save``."""
    import torch

    with atomic_path(path) as tmp:
        torch.save(obj, tmp)
    return Path(path)


def load_checkpoint(path: str | os.PathLike) -> Any:
    """Read a checkpoint written by :func:`save_checkpoint` with ``torch.load(weights_only=True)`` (no code runs)."""
    import pickle

    import torch

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: checkpoint not found")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, pickle.UnpicklingError, EOFError, OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read checkpoint ({' '.join(str(exc).split())[:200]})") from None
