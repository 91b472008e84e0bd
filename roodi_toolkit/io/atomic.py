"""Putting outputs in place: a temporary file beside each output, moved into place without ever replacing a file the
command did not see at its start, alone or together with the command's other outputs (:func:`output_group`).

An output that did not exist (checked by :func:`~roodi_toolkit.io.files.check_output` without ``overwrite``, or absent
when :func:`atomic_path` began) is put in place with a hard link, which fails if anything appeared there meanwhile
(another program, a second run to the same path); the command then refuses in one line. Inside :func:`output_group`
(the CLI opens one per command, see ``roodi_toolkit.cli.main``) the finished temporary files wait and are moved into
place together when the group ends, with SIGTERM and Ctrl-C held over the moves (:mod:`roodi_toolkit.signals`): a
command's outputs appear together or not at all, whatever signal or full disk interrupts it.
:mod:`roodi_toolkit.io.files` re-exports what callers use.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

from .. import signals
from ..errors import EnvironmentProblemError, OutputError, os_error_problem

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
        """Put every held output in place (the group stays open for later ones): the new ones first (all refused,
        none placed, if one of their names was taken meanwhile), then the replacements; signals are held until all
        are done."""
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
            # a second signal (Ctrl-C to a batch's process group, then the batch's SIGTERM to its workers) must not
            # cut the removal short: a nested writer's temporary file was left behind, 1 run in many
            held = _hold_signals()
            try:
                with contextlib.suppress(OSError):
                    tmp_path.unlink()
            finally:
                _release_signals(held)  # that signal's handler raises here, once the file is gone
        if isinstance(exc, OSError):
            _raise_environment_problem(exc, dest)
        raise


def _hold_signals() -> bool:
    """Hold SIGTERM and Ctrl-C (see :mod:`roodi_toolkit.signals`); return the token for :func:`_release_signals`."""
    return signals.hold()


def _release_signals(held: bool) -> None:
    """End a hold; a signal that came meanwhile is acted on now (its handler may raise)."""
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
