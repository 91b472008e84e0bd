"""The compiled kernels' threads: the numba threading layer they run on, and how many threads.

Numba runs every ``prange`` loop (a parallel region) on a threading layer. This module picks numba's OpenMP layer
(``omp``, GNU libgomp), then TBB where it is installed, then numba's own ``workqueue`` (always there), unless
``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY`` say otherwise. Measured on a 2-core machine
(``benchmarks/RESULTS.md``, "The kernels' threading layer"):

- a parallel region takes 1-2 us to start on ``omp`` and 90-105 us on ``workqueue``, whose threads wait by polling
  with naps; a view's forward and backward start about 50 by the times (1.3 ms against 5.2 ms for a tiny view);
- PyTorch's own OpenMP threads spin for about 8 ms after each of its parallel operations (a loss, an optimiser step,
  an image sum), and the kernels' ``workqueue`` threads started late behind them. ``benchmarks/bench_layers.py``, two
  threads of each: a 100k-Gaussian view at 256x256 1.6x faster on ``omp``, a training step at 200 px 1.57x, 500k
  Gaussians at 800x800 1.3x; one thread 1.2x.

PyTorch is imported first (here), so its libgomp is loaded before numba's layer starts, and numba's OpenMP layer binds
to that same library (``LD_DEBUG=bindings``: numba's ``omppool`` resolves ``GOMP_parallel`` in PyTorch's
``torch/lib/libgomp.so.1``): the kernels and PyTorch's operations share one OpenMP runtime and its wait policy, so the
threads PyTorch leaves spinning take the kernels' next region at once instead of competing with them for the cores.

The runtime's wait is PyTorch's default (spin about 8 ms after a region, then sleep), the fastest alone; beside busy
jobs a passive wait is faster (``OMP_WAIT_POLICY=PASSIVE`` before Python starts, which PyTorch's operations obey
too), or the previous layer (``NUMBA_THREADING_LAYER=workqueue``): ``docs/rendering.md``, "Threads".

GNU OpenMP does not survive ``fork``: a process forked from one whose kernels' threads were started is stopped by
numba when it runs a kernel. :func:`fork_safe` says whether that is the case; the batch runner then starts its workers
from a fresh server process (``forkserver``).
"""

from __future__ import annotations

import importlib
import os

import numba

importlib.import_module("torch")  # before numba's OpenMP layer starts: the layer then binds to PyTorch's libgomp

_PRIORITY = ["omp", "tbb", "workqueue"]

if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
    numba.config.THREADING_LAYER = "default"  # the first of the priority list that loads
    numba.config.THREADING_LAYER_PRIORITY = list(_PRIORITY)


def workers() -> int:
    """Return the number of threads the kernels run on: ``$ROODI_THREADS`` (what ``--threads`` sets) when set, else
    every core numba sees. Results do not depend on it."""
    value = os.environ.get("ROODI_THREADS", "")
    n = int(value) if value.isdigit() and int(value) > 0 else numba.config.NUMBA_NUM_THREADS
    return max(1, min(n, numba.config.NUMBA_NUM_THREADS))


def set_workers() -> int:
    """Give the kernels :func:`workers` threads (numba's setting is per Python thread: call before a kernel) and return
    that number."""
    n = workers()
    numba.set_num_threads(n)
    return n


def layer() -> str:
    """Return the threading layer the kernels run on (starts it)."""
    numba.get_num_threads()  # starts the layer
    return numba.threading_layer()


def uncompiled(*dispatchers) -> list[str]:
    """Return the names of ``dispatchers`` (``@njit(cache=True)`` functions) that their next call compiles: nothing
    compiled for them in this process, and nothing in numba's cache on disk for their source as it stands (first use
    on a machine, or after an upgrade; a render's kernels then compile for about 40 s, once). Reads numba's cache
    index through numba's internals: where those have moved, returns [] (tells nothing rather than guess)."""
    names = []
    for dispatcher in dispatchers:
        if dispatcher.overloads:
            continue
        try:
            index = dispatcher._cache._cache_file._load_index()
        except Exception:  # not a cached function, or numba's internals moved
            return []
        if not index:
            names.append(dispatcher.__name__)
    return names


def fork_safe() -> bool:
    """Whether a process forked from this one can run the kernels: not once they have started on GNU OpenMP."""
    try:
        return numba.threading_layer() != "omp"
    except ValueError:  # no threading layer started in this process
        return True
