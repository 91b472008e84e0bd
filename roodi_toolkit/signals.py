"""Hold SIGTERM and Ctrl-C over a step that must not be cut in two: putting a command's outputs in place.

Python runs a signal's handler in the main thread, between two bytecodes, whichever thread the operating system gave
the signal to; blocking the signal in the main thread (``pthread_sigmask``) does not stop that when the process has
other threads (PyTorch's, a progress bar's). So the handlers the CLI installs are wrapped with :func:`deferrable`:
while :func:`hold` is in force they only note the signal, and :func:`release` runs the handler once the step is done
(raising ``Terminated`` or ``KeyboardInterrupt`` there). A process whose handlers are not wrapped (a notebook's
Ctrl-C) is interrupted as usual.

Example:
    >>> held = hold()
    >>> release(held)
"""

from __future__ import annotations

import threading
from typing import Any, Callable

Handler = Callable[[int, Any], Any]

_depth = 0
_pending: list[tuple[Handler, int]] = []


def deferrable(handler: Handler) -> Handler:
    """Return a signal handler that runs ``handler`` at once, or, while signals are held, when they are released."""

    def wrapper(signum: int, frame: Any) -> None:
        if _depth > 0:
            _pending.append((handler, signum))
            return
        handler(signum, frame)

    wrapper.__wrapped__ = handler  # type: ignore[attr-defined]
    return wrapper


def hold() -> bool:
    """Start holding signals (in the main thread; elsewhere no handler can run anyway); return whether it did."""
    global _depth
    if threading.current_thread() is not threading.main_thread():
        return False
    _depth += 1
    return True


def release(held: bool) -> None:
    """End a :func:`hold`; at the outermost one, run the handler of a signal that came meanwhile (it may raise)."""
    global _depth
    if not held:
        return
    _depth = max(0, _depth - 1)
    if _depth == 0 and _pending:
        handler, signum = _pending[0]
        _pending.clear()
        handler(signum, None)
