"""Run a batch: items on a local process pool (``jobs`` workers, one item each at a time) or as Ray tasks.

Results are appended to a JSON-lines file as items finish (one line per item: item, status, counts, seconds, error,
and the identity of the output written). A re-run reads that file and skips the items whose output exists and whose
input file, task settings and item options are unchanged (a fingerprint of them is kept in the item's line), so a
killed batch resumes where it stopped. One failing item never stops the others: its error is its line.

Outputs are the user's files once written: an item's output that exists is replaced only with ``overwrite`` or when
this batch's results file records writing it (a worker notes the file's identity in a ``writing`` line just before
putting it in place, so even a batch killed in between knows its own outputs). SIGTERM or Ctrl-C stops the batch at
once: queued items are dropped, running ones unwind (their temporary files removed), and the lines of items that
finished are written before it exits.

The scheduling is the standard library's ``concurrent.futures`` pool or Ray's task API; none of our own.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import multiprocessing
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures import process as pool_process
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from .._version import __version__
from ..errors import ConfigError, EnvironmentProblemError, OutputError
from ..io.files import check_name_lengths, json_text, refuse_inside_inputs, same_file
from ..progress import ProgressFactory, null_progress
from ..signals import deferrable
from .items import Item
from .outputs import file_id, output_exists
from .tasks import TASKS, run_item


@dataclass
class BatchSummary:
    """What a batch did.

    Attributes:
        total: items in the batch.
        ok: items that ran and succeeded.
        failed: items that ran and failed (their lines say why).
        skipped: items left as an earlier run made them (output present, nothing changed).
        seconds: wall time.
        results: the JSON-lines file.
        lines: this run's result lines, in the order items finished.
    """

    total: int
    ok: int
    failed: int
    skipped: int
    seconds: float
    results: str
    lines: list[dict[str, Any]] = field(default_factory=list, repr=False)


def fingerprint(task: str, settings: dict[str, Any], item: Item) -> str:
    """Return a digest of everything an item's output depends on: task, settings, item options, the input file
    (resolved path, size, modification time) and the toolkit's version."""
    path = Path(item.input)
    try:
        st = path.stat()
        stamp = [str(path.resolve()), st.st_size, st.st_mtime_ns]
    except OSError:
        stamp = [str(path), None, None]
    payload = {"task": task, "settings": settings, "options": item.options, "input": stamp, "output": item.output,
               "version": __version__}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def read_results(path: str | Path) -> dict[str, dict[str, Any]]:
    """Return the last result line per item of a results file (a torn last line of a killed run is ignored)."""
    last: dict[str, dict[str, Any]] = {}
    for line in _result_lines(path):
        if line.get("status") not in ("skipped", "writing"):
            last[line["item"]] = line
    return last


def _result_lines(path: str | Path) -> list[dict[str, Any]]:
    p = Path(path)
    if not p.is_file():
        return []
    lines = []
    for text in p.read_text(errors="replace").splitlines():
        try:
            line = json.loads(text)
        except (json.JSONDecodeError, RecursionError):
            continue
        if isinstance(line, dict) and isinstance(line.get("item"), str):
            lines.append(line)
    return lines


def check_results_file(path: str | Path, items: Sequence[Item], inputs: Sequence[str | None] = ()) -> None:
    """Refuse a results file that is not one: lines are appended to it, so it must be a batch's own results file
    (or new, or empty), and neither an input, an item's output nor inside an input folder.

    Raises:
        OutputError: naming the file and what it is.
    """
    p = check_name_lengths(path)
    if p.is_dir():
        raise OutputError(f"{p}: --results is a folder; give a file path (results are JSON lines)")
    for item in items:
        for role, other in (("the input", item.input), ("the output", item.output)):
            if other is not None and "://" not in other and same_file(other, p):
                raise OutputError(f"{p}: --results is {role} of item {item.name}; give the results their own file")
    for other in inputs:
        if other is not None and Path(other).is_file() and same_file(other, p):
            raise OutputError(f"{p}: --results is the input {other}; give the results their own file")
    refuse_inside_inputs(p, [*inputs, *[i.input for i in items if Path(i.input).is_dir()]])
    if not p.exists():
        if os.path.lexists(p):
            raise OutputError(f"{p}: --results is a symbolic link to nothing; give a file path")
        return
    try:
        with open(p, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise OutputError(f"{p}: cannot read the results file ({exc.strerror or exc})") from None
    for number, raw in enumerate(data.split(b"\n"), 1):
        if not raw.strip() or raw.startswith(_TORN):  # a line a killed run did not finish
            continue
        try:
            line = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
            line = None
        if not (isinstance(line, dict) and isinstance(line.get("item"), str) and "status" in line):
            raise OutputError(f"{p}: exists and is not a batch results file (line {number} is no result line); "
                              "results are appended, so give a new file or one an earlier batch wrote")


_TORN = b'{"item": '
"""How every result line begins: an unparsable line that begins so is one a killed run did not finish."""


def _end_torn_line(path: str | Path) -> None:
    """End a results file's torn last line (a killed run's), so that the next line is not glued to it."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            f.seek(-1, os.SEEK_END)
            last = f.read(1)
    except OSError:  # missing or empty
        return
    if last != b"\n":
        with open(p, "ab") as f:
            f.write(b"\n")


def _own_outputs(path: str | Path) -> set[tuple[str, tuple[int, ...] | None]]:
    """Return what earlier runs recorded writing: (output, its identity, :func:`~.outputs.file_id`) from ``ok`` lines
    and from the
    ``writing`` lines workers add just before an output is put in place (None: an old line without identity)."""
    own = set()
    for line in _result_lines(path):
        if line.get("status") in ("ok", "writing") and isinstance(line.get("output"), str):
            ident = line.get("output_id")
            own.add((line["output"], tuple(ident) if isinstance(ident, list) and len(ident) == 4 else None))
    return own


def _may_replace(item: Item, own: set[tuple[str, Any]]) -> bool:
    """Whether ``item``'s existing output is one an earlier run of this batch wrote (its recorded identity, or an
    ``ok`` line of an older version that recorded none)."""
    if item.output is None:
        return False
    if "://" in item.output:
        return any(out == item.output for out, _ in own)
    ident = file_id(item.output)
    return (item.output, None if ident is None else tuple(ident)) in own or (item.output, None) in own


def _pool(jobs: int) -> ProcessPoolExecutor:
    """A pool of ``jobs`` worker processes, forked from this one where that is safe (the default start method on
    Linux: the workers share what this process imported). A process forked after the compiled kernels' OpenMP threads
    started cannot run the kernels (numba stops it: GNU OpenMP does not survive a fork), so the workers then start
    from a fresh server process (``forkserver``): a batch run from Python after a render in the same process."""
    cores = sys.modules.get("roodi_toolkit.render.cores")  # imported wherever the kernels ran (not here: numba)
    unsafe = multiprocessing.get_start_method() == "fork" and cores is not None and not cores.fork_safe()
    context = multiprocessing.get_context("forkserver") if unsafe else None
    return ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker, mp_context=context)


def _init_worker() -> None:
    # SIGTERM / Ctrl-C: the item under way unwinds (its temporary output removed), then the worker exits; an idle
    # worker exits at once. (The pool would otherwise catch the interruption as the item's error and go on.) First,
    # before the slow imports below: a worker signalled while importing PyTorch printed the command's own handler's
    # traceback as "Exception in initializer".
    for sig in (signal.SIGTERM, signal.SIGINT, getattr(signal, "SIGHUP", None)):
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, deferrable(_worker_signal))  # held while an output is put in place
    # one item per worker on one core: libraries must not each start a thread per core on top of the pool
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch  # lazy: in the workers only; the parent that hands out items never needs torch

    torch.set_num_threads(1)


_IN_ITEM = False


class _WorkerStop(BaseException):
    """The batch is being stopped: unwind the item under way."""


def _worker_signal(signum: int, frame: Any) -> None:
    if _IN_ITEM:
        raise _WorkerStop()
    os._exit(128 + signum)


def _worker_run(task: str, item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    global _IN_ITEM
    try:
        _IN_ITEM = True
        return run_item(task, item, settings)
    except _WorkerStop:
        os._exit(143)
    finally:
        _IN_ITEM = False


class _Pool:
    """Items on a local process pool; :meth:`lines` yields result lines as items finish, :meth:`stop` ends the batch
    early (a signal): queued items are dropped, running ones stopped (their temporary outputs removed), and the lines
    of items that finished but were not yet reported are returned, so that none of their outputs goes unrecorded."""

    def __init__(self, task: str, items: Sequence[Item], settings: dict[str, Any], jobs: int) -> None:
        self.task, self.items, self.settings, self.jobs = task, items, settings, jobs
        self.pool: ProcessPoolExecutor | None = None
        self.futures: dict[Any, Item] = {}
        self.reported: set[Any] = set()

    def lines(self) -> Iterator[dict[str, Any]]:
        """Yield result lines as items finish; an item whose worker died is tried once more alone, so a crash (out
        of memory, a segfault in a library) costs that item only."""
        retry: list[Item] = []
        self.pool = _pool(self.jobs)
        self.futures = {self.pool.submit(_worker_run, self.task, item, self.settings): item for item in self.items}
        for fut in as_completed(self.futures):
            self.reported.add(fut)
            try:
                line = fut.result()
            except BrokenProcessPool:
                retry.append(self.futures[fut])
                continue
            yield line
        self.pool.shutdown(wait=True)
        for item in retry:  # each in a pool of its own: the one that kills its worker fails, the others run
            self.pool = _pool(1)
            fut = self.pool.submit(_worker_run, self.task, item, self.settings)
            self.futures, self.reported = {fut: item}, set()
            try:
                line = fut.result()
            except BrokenProcessPool:
                line = {"item": item.name, "input": item.input, "output": item.output, "status": "failed",
                        "error": "the worker process died (out of memory or a crash in a library)", "seconds": 0.0}
            self.reported.add(fut)
            self.pool.shutdown(wait=True)
            yield line

    def stop(self) -> list[dict[str, Any]]:
        """Stop the pool now; return the lines of items that finished and were not yet reported."""
        pool = self.pool
        if pool is None:
            return []
        workers = list((getattr(pool, "_processes", None) or {}).values())  # the pool offers no public handle
        manager = getattr(pool, "_executor_manager_thread", None)
        # queued items are cancelled by the pool itself (cancelling them here as well made its manager thread set
        # an exception on a cancelled future when the workers went: InvalidStateError on stderr)
        with contextlib.suppress(Exception):
            pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                if proc.is_alive():
                    proc.terminate()  # SIGTERM: the worker removes its temporary output and exits
        for proc in workers:
            with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
                proc.join(timeout=30)
                if proc.is_alive():  # stuck in native code: nothing more can be done cleanly
                    proc.kill()
        with contextlib.suppress(Exception):
            pool.shutdown(wait=True, cancel_futures=True)
        # CPython's exit hook wakes every pool's manager thread through a pipe that this shutdown has closed; at times
        # (a SIGTERM test, 1 run in many) that wrote "Exception ignored ... OSError: Bad file descriptor" to stderr.
        # The thread is joined: nothing is left to wake.
        with contextlib.suppress(Exception):
            pool_process._threads_wakeups.pop(manager, None)
        finished = []
        for fut, item in self.futures.items():
            if fut in self.reported or not fut.done() or fut.cancelled():
                continue
            with contextlib.suppress(BaseException):
                finished.append(fut.result(timeout=0))
        return finished


def _ray_lines(task: str, items: Sequence[Item], settings: dict[str, Any], address: str,
               jobs: int) -> Iterator[dict[str, Any]]:
    """Yield result lines as Ray tasks finish (``address``: a cluster's, or ``local`` to start one here)."""
    try:
        import ray  # lazy: optional (the [ray] extra), for --ray only
    except ImportError:
        raise EnvironmentProblemError("--ray needs Ray: pip install 'roodi-toolkit[ray]'") from None
    started = not ray.is_initialized()
    if started:
        try:
            if address == "local":
                ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False, configure_logging=False)
            else:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise EnvironmentProblemError(f"--ray {address}: cannot connect to a Ray cluster ({exc})") from None
    pending: list[Any] = []
    try:
        remote = ray.remote(num_cpus=1, max_retries=1)(run_item)
        refs = {remote.remote(task, item, settings): item for item in items}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            item = refs[done[0]]
            try:
                yield ray.get(done[0])
            except ray.exceptions.RayError as exc:
                yield {"item": item.name, "input": item.input, "output": item.output, "status": "failed",
                       "error": f"Ray task failed: {str(exc).splitlines()[0]}", "seconds": 0.0}
    finally:
        for ref in pending:  # left unfinished (the batch is being stopped)
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        if started:
            ray.shutdown()


WRITING_TASKS = ("prune", "convert", "info")
"""Tasks whose items write their own output file (``extract`` keeps its stages in the scene's folder)."""


def _present(output: str) -> bool:
    """Whether something is at an item's output: a file, or a symbolic link (even to nothing)."""
    return output_exists(output) if "://" in output else os.path.lexists(output)


def run_batch(task: str, items: Sequence[Item], results: str | Path, *, settings: dict[str, Any] | None = None,
              jobs: int = 1, ray: str | None = None, rerun: bool = False, overwrite: bool = False,
              inputs: Sequence[str] = (), progress: ProgressFactory = null_progress,
              on_line: Callable[[dict[str, Any]], None] | None = None) -> BatchSummary:
    """Run ``task`` over ``items``; append one JSON line per item to ``results``; return the summary.

    An item's output that already exists is replaced only with ``overwrite`` or when an earlier run of this batch
    wrote it (the results file records each output's identity, even from a run killed just after writing it);
    otherwise the batch is refused before any work. A file that appears at an output while the batch runs is left
    alone and that item fails.

    Args:
        task: ``prune``, ``convert``, ``info`` or ``extract``.
        items: the work (:func:`~roodi_toolkit.batch.items.collect_items`).
        results: the JSON-lines file (created, or appended to: an earlier run's lines say what to skip); refused if
            it exists and is not a results file, or is an input or an output (:func:`check_results_file`).
        settings: the task's settings (:func:`~roodi_toolkit.batch.tasks.settings_for`).
        jobs: local worker processes (with ``ray="local"``: the local Ray's CPUs).
        ray: a Ray cluster address, or ``"local"`` to start one on this machine; None runs a process pool.
        rerun: run every item even if an earlier run made it with the same inputs and settings.
        overwrite: replace files at the items' outputs that this batch did not write.
        inputs: the batch's source (a folder or a manifest), guarded like the items' inputs.
        progress: progress factory (a bar over items).
        on_line: called with each line as it is written.

    Raises:
        OutputError: an output exists that this batch did not write (without ``overwrite``), or ``results`` is
            not usable.
    """
    if task not in TASKS:
        raise ConfigError(f"unknown batch task {task!r}; choose from {', '.join(TASKS)}")
    if jobs < 1 or jobs > (os.cpu_count() or 1) * 4:
        raise ConfigError(f"--jobs must be between 1 and {(os.cpu_count() or 1) * 4}, got {jobs}")
    check_results_file(results, items, inputs)
    settings = settings or {}
    t0 = time.perf_counter()
    earlier = {} if rerun else read_results(results)
    own = _own_outputs(results)
    prints = {item.name: fingerprint(task, settings, item) for item in items}
    todo, skipped, taken = [], [], []
    for item in items:
        old = earlier.get(item.name)
        if (old and old.get("status") == "ok" and old.get("fingerprint") == prints[item.name]
                and (item.output is None or output_exists(item.output))):
            skipped.append(item)
            continue
        if task in WRITING_TASKS and item.output is not None and _present(item.output):
            if overwrite or _may_replace(item, own):
                item = dataclasses.replace(item, replace=True)
            else:
                taken.append(item)
        todo.append(item)
    if taken:
        more = f" (and {len(taken) - 1} more of the items' outputs)" if len(taken) > 1 else ""
        raise OutputError(f"{taken[0].output}: already exists and no earlier run of this batch wrote it (no line in "
                          f"{results}){more}; pass --overwrite to replace it")
    summary = BatchSummary(len(items), 0, 0, len(skipped), 0.0, str(results))
    Path(results).parent.mkdir(parents=True, exist_ok=True)
    _end_torn_line(results)
    with open(results, "a", buffering=1) as out, progress(total=len(items), desc=f"batch {task}") as bar:
        def emit(line: dict[str, Any]) -> None:
            if line.get("status") == "ok":
                summary.ok += 1
                line["fingerprint"] = prints[line["item"]]
            elif line.get("status") == "failed":
                summary.failed += 1
            out.write(json_text(line) + "\n")
            out.flush()
            os.fsync(out.fileno())  # a killed batch keeps every line it wrote
            summary.lines.append(line)
            if on_line is not None:
                on_line(line)
            bar.update(1)

        for item in skipped:
            emit({"item": item.name, "input": item.input, "output": item.output, "status": "skipped",
                  "reason": "output present and input, settings and options unchanged since the last run"})
        if todo and ray:
            lines = _ray_lines(task, todo, settings, ray, jobs)
            try:
                for line in lines:
                    emit(line)
            finally:
                lines.close()  # on a signal: the tasks not yet finished are cancelled
        elif todo:
            pool = _Pool(task, todo, {**settings, "_record": str(results)}, jobs)
            try:
                for line in pool.lines():
                    emit(line)
            except BaseException:  # a signal, Ctrl-C, a full disk: stop the workers now, keep what they finished
                for line in pool.stop():
                    emit(line)
                raise
    summary.seconds = time.perf_counter() - t0
    return summary
