"""How much memory a step may ask for: what the machine has available, and one-line refusals of a decode or a
render that would not fit.

A header or an option can ask for any size (a 1 KB PNG that claims 100000x100000 pixels, ``render --size
16384x16384``); such requests are compared with the memory available before anything is allocated, and refused
in one line naming the file or option, what it needs and what there is.

Example:
    >>> human_bytes(5 * 2 ** 30)
    '5.0 GB'
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import InputError

MEMORY_SHARE = 0.8
"""Share of the available memory one allocation may plan to use (the rest is the process's other work)."""


def human_bytes(n: float) -> str:
    """Return a byte count as ``512 KB``, ``3.2 MB``, ``5.0 GB``."""
    for unit, size in (("GB", 2 ** 30), ("MB", 2 ** 20), ("KB", 2 ** 10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
        return None if text == "max" else int(text)
    except (OSError, ValueError):
        return None


def _cgroup_room() -> int | None:
    """Bytes left under this process's cgroup memory limit (v2 ``memory.max``, v1 ``memory.limit_in_bytes``), or
    None if there is none."""
    try:
        lines = Path("/proc/self/cgroup").read_text().strip().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        if parts[0] == "0" and parts[1] == "":
            base, limit_name, usage_name = Path("/sys/fs/cgroup"), "memory.max", "memory.current"
        elif "memory" in parts[1].split(","):
            base, limit_name, usage_name = Path("/sys/fs/cgroup/memory"), "memory.limit_in_bytes", \
                "memory.usage_in_bytes"
        else:
            continue
        for folder in (base / parts[2].lstrip("/"), base):  # inside a container the group is often the root
            limit, used = _read_int(folder / limit_name), _read_int(folder / usage_name)
            if limit is not None and used is not None and limit < 2 ** 60:
                return max(0, limit - used)
    return None


def available_memory() -> int | None:
    """Return the bytes of memory available to this process (Linux ``MemAvailable``, lowered by a cgroup limit; the
    free physical pages elsewhere), or None where the platform does not tell."""
    found = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    room = _cgroup_room()
    return found if room is None else min(found, room)


def check_memory(needed: float, what: str, todo: str, error: type[InputError] = InputError) -> None:
    """Raise ``error`` ("WHAT needs about N GB of memory, more than the 80% of the M GB ...; TODO") if ``needed``
    bytes exceed :data:`MEMORY_SHARE` of the available memory; do nothing where the available memory is unknown."""
    room = available_memory()
    if room is not None and needed > MEMORY_SHARE * room:
        raise error(f"{what} needs about {human_bytes(needed)} of memory, more than the {MEMORY_SHARE:.0%} of the "
                    f"{human_bytes(room)} this machine has available that one step may take; {todo}")
