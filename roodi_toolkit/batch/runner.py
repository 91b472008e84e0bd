"""Run a batch: items on a local process pool (``jobs`` workers, one item each at a time) or as Ray tasks.

Results are appended to a JSON-lines file as items finish (one line per item: item, status, counts, seconds, error).
A re-run reads that file and skips the items whose output exists and whose input file, task settings and item
options are unchanged (a fingerprint of them is kept in the item's line), so a killed batch resumes where it stopped.
One failing item never stops the others: its error is its line.

The scheduling is the standard library's ``concurrent.futures`` pool or Ray's task API; none of our own.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from .._version import __version__
from ..errors import ConfigError, EnvironmentProblemError
from ..progress import ProgressFactory, null_progress
from .items import Item
from .outputs import output_exists
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
    p = Path(path)
    if not p.is_file():
        return last
    for text in p.read_text(errors="replace").splitlines():
        try:
            line = json.loads(text)
        except json.JSONDecodeError:
            continue
        if isinstance(line, dict) and isinstance(line.get("item"), str) and line.get("status") != "skipped":
            last[line["item"]] = line
    return last


def _init_worker() -> None:
    # one item per worker on one core: libraries must not each start a thread per core on top of the pool
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


def _pool_lines(task: str, items: Sequence[Item], settings: dict[str, Any], jobs: int) -> Iterator[dict[str, Any]]:
    """Yield result lines as items finish on a process pool; an item whose worker died is tried once more alone,
    so a crash (out of memory, a segfault in a library) costs that item only."""
    retry: list[Item] = []
    with ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker) as pool:
        futures = {pool.submit(run_item, task, item, settings): item for item in items}
        for fut in as_completed(futures):
            try:
                yield fut.result()
            except BrokenProcessPool:
                retry.append(futures[fut])
    for item in retry:  # each in a pool of its own: the one that kills its worker fails, the others run
        with ProcessPoolExecutor(max_workers=1, initializer=_init_worker) as pool:
            try:
                yield pool.submit(run_item, task, item, settings).result()
            except BrokenProcessPool:
                yield {"item": item.name, "input": item.input, "output": item.output, "status": "failed",
                       "error": "the worker process died (out of memory or a crash in a library)", "seconds": 0.0}


def _ray_lines(task: str, items: Sequence[Item], settings: dict[str, Any], address: str,
               jobs: int) -> Iterator[dict[str, Any]]:
    """Yield result lines as Ray tasks finish (``address``: a cluster's, or ``local`` to start one here)."""
    try:
        import ray
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
        if started:
            ray.shutdown()


def run_batch(task: str, items: Sequence[Item], results: str | Path, *, settings: dict[str, Any] | None = None,
              jobs: int = 1, ray: str | None = None, rerun: bool = False,
              progress: ProgressFactory = null_progress,
              on_line: Callable[[dict[str, Any]], None] | None = None) -> BatchSummary:
    """Run ``task`` over ``items``; append one JSON line per item to ``results``; return the summary.

    Args:
        task: ``prune``, ``convert`` or ``info``.
        items: the work (:func:`~roodi_toolkit.batch.items.collect_items`).
        results: the JSON-lines file (created, or appended to: an earlier run's lines say what to skip).
        settings: the task's settings (:func:`~roodi_toolkit.batch.tasks.settings_for`).
        jobs: local worker processes (with ``ray="local"``: the local Ray's CPUs).
        ray: a Ray cluster address, or ``"local"`` to start one on this machine; None runs a process pool.
        rerun: run every item even if an earlier run made it with the same inputs and settings.
        progress: progress factory (a bar over items).
        on_line: called with each line as it is written.
    """
    if task not in TASKS:
        raise ConfigError(f"unknown batch task {task!r}; choose from {', '.join(TASKS)}")
    if jobs < 1 or jobs > (os.cpu_count() or 1) * 4:
        raise ConfigError(f"--jobs must be between 1 and {(os.cpu_count() or 1) * 4}, got {jobs}")
    settings = settings or {}
    t0 = time.perf_counter()
    earlier = {} if rerun else read_results(results)
    prints = {item.name: fingerprint(task, settings, item) for item in items}
    todo, skipped = [], []
    for item in items:
        old = earlier.get(item.name)
        if (old and old.get("status") == "ok" and old.get("fingerprint") == prints[item.name]
                and (item.output is None or output_exists(item.output))):
            skipped.append(item)
        else:
            todo.append(item)
    summary = BatchSummary(len(items), 0, 0, len(skipped), 0.0, str(results))
    Path(results).parent.mkdir(parents=True, exist_ok=True)
    with open(results, "a", buffering=1) as out, progress(total=len(items), desc=f"batch {task}") as bar:
        def emit(line: dict[str, Any]) -> None:
            out.write(json.dumps(line, default=str) + "\n")
            out.flush()
            os.fsync(out.fileno())  # a killed batch keeps every line it wrote
            summary.lines.append(line)
            if on_line is not None:
                on_line(line)
            bar.update(1)

        for item in skipped:
            emit({"item": item.name, "input": item.input, "output": item.output, "status": "skipped",
                  "reason": "output present and input, settings and options unchanged since the last run"})
        lines = (iter(()) if not todo else _ray_lines(task, todo, settings, ray, jobs) if ray
                 else _pool_lines(task, todo, settings, jobs))
        for line in lines:
            if line["status"] == "ok":
                summary.ok += 1
                line["fingerprint"] = prints[line["item"]]
            else:
                summary.failed += 1
            emit(line)
    summary.seconds = time.perf_counter() - t0
    return summary
