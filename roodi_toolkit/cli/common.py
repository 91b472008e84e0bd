"""Options and helpers shared by the commands: output flags, progress bars, option types."""

from __future__ import annotations

import functools
import os
import sys
from typing import Any, Callable

import click

from roodi_toolkit import settings
from roodi_toolkit.errors import ConfigError
from roodi_toolkit.limits import check_memory
from roodi_toolkit.progress import null_progress

overwrite_option = click.option("--overwrite", is_flag=True, help="Replace existing output files.")


def progress_factory(quiet: bool = False) -> Callable[..., Any]:
    """Return a tqdm progress factory writing to stderr (a no-op one when quiet)."""
    if quiet:
        return null_progress
    return functools.partial(_tqdm(), file=sys.stderr, leave=False, dynamic_ncols=True, mininterval=0.5)


def _tqdm() -> Any:
    from tqdm import tqdm  # lazy: -q runs (batch workers, scripts) never draw a bar nor write above one

    return tqdm


def say_above_bars(line: str) -> None:
    """Write ``line`` on stderr above a progress bar being drawn, rather than into it."""
    _tqdm().write(line, file=sys.stderr)


def _quiet(ctx: click.Context, param: click.Parameter, value: bool) -> bool:
    """``-q`` given to the command, or anywhere else on the line (``main`` takes it out and puts it in ``ctx.obj``)."""
    return bool(value) or bool(isinstance(ctx.obj, dict) and ctx.obj.get("quiet"))


quiet_option = click.option("-q", "--quiet", is_flag=True, callback=_quiet,
                            help="No progress bars (also before the command: roodi-toolkit -q COMMAND ...).")


def threads_setting() -> int:
    """Return ``--threads N`` / ``$ROODI_THREADS`` (default 1), checked against the machine's cores.

    The renderer's kernels are many small tensor operations; on a 2-core machine that is also running anything else,
    PyTorch's OpenMP threads spin against each other: a 64x64 training step took 637 ms with 2 threads and 58 ms with
    1 (benchmarks/RESULTS.md). One thread is the safe default; raise it on an idle many-core machine.

    Raises:
        ConfigError: the value is not an integer from 1 to the machine's core count.
    """
    value = os.environ.get("ROODI_THREADS", "1")
    try:
        n = int(value)
    except ValueError:
        raise ConfigError(f"ROODI_THREADS / --threads must be a positive integer, got {value!r}") from None
    # more threads than cores only makes OpenMP spin, and a huge count makes PyTorch allocate per-thread state until
    # it crashes (--threads 100000 segfaulted): the machine's core count is the bound
    cores = os.cpu_count() or 1
    if not 1 <= n <= cores:
        raise ConfigError(f"ROODI_THREADS / --threads must be an integer from 1 to {cores} (this machine's cores), "
                          f"got {value!r}")
    return n


def set_torch_threads() -> None:
    """Give PyTorch the threads of :func:`threads_setting` (imports PyTorch)."""
    n = threads_setting()
    import torch  # lazy: 2-5 s to import; only the commands that run torch call this

    torch.set_num_threads(n)


def parse_floats(text: str, n: int, name: str) -> tuple[float, ...]:
    """Parse 'a,b,c' into n finite floats (:func:`roodi_toolkit.settings.parse_floats`) or raise a
    click.BadParameter naming the option."""
    try:
        return settings.parse_floats(text, n)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=name) from None


def parse_key_values(items: tuple[str, ...], name: str) -> dict[str, str]:
    """Return ``{key: value}`` of repeated ``KEY=VALUE`` option values (values stay text; the plugin converts)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise click.BadParameter(f"expected KEY=VALUE, got {item!r}", param_hint=name)
        out[key.strip()] = value
    return out


def parse_size(text: str, name: str = "--size") -> tuple[int, int]:
    """Parse 'WxH' (or a single number for a square) into (width, height)
    (:func:`roodi_toolkit.settings.parse_image_size`); what it refuses is a usage error naming ``name``."""
    try:
        return settings.parse_image_size(text)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=name) from None


RENDER_BYTES_PER_PIXEL = 80
"""Peak memory of rendering one view, per pixel, with the built-in renderer: measured 69 bytes (2,000 Gaussians at
4096x4096: 1.41 GB, of which 0.25 GB is the process before rendering; 8192x8192: 4.5 GB), rounded up."""


def check_render_size(width: int, height: int, where: str) -> None:
    """Refuse, in one line naming ``where`` (an option or a camera file), a view too large to render in the memory
    this machine has available (a header or an option can ask for any size)."""
    check_memory(RENDER_BYTES_PER_PIXEL * int(width) * int(height), f"{where}: rendering a {width}x{height} view",
                 "choose a smaller size", ConfigError)
