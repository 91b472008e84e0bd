"""Progress reporting without printing: library code takes a progress factory, the CLI passes a real bar.

A progress factory is any callable ``factory(total=int, desc=str)`` returning an object with ``update(n)`` and
``close()`` that also works as a context manager; ``tqdm.tqdm`` is one. The default does nothing.
"""

from __future__ import annotations

from typing import Any, Callable, Optional, Protocol


class ProgressBar(Protocol):
    def update(self, n: int = 1) -> Any: ...

    def close(self) -> Any: ...

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> Any: ...

    def __enter__(self) -> "ProgressBar": ...

    def __exit__(self, *exc: object) -> Any: ...


ProgressFactory = Callable[..., ProgressBar]


class NullProgress:
    """A progress bar that shows nothing."""

    def __init__(self, total: int | None = None, desc: str = "", **_: Any) -> None:
        self.total = total
        self.n = 0
        self.desc = desc

    def update(self, n: int = 1) -> None:
        self.n += n

    def close(self) -> None:
        pass

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def __enter__(self) -> "NullProgress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def null_progress(total: int | None = None, desc: str = "", **kwargs: Any) -> NullProgress:
    """Return a bar that reports nothing; the default progress factory of every library function."""
    return NullProgress(total=total, desc=desc, **kwargs)


_FIRST_COMPILE: list[Callable[[str], None]] = []
"""The callable :func:`tell_first_compile` registered, until a render takes it (:func:`take_first_compile`)."""


def tell_first_compile(notice: Optional[Callable[[str], None]]) -> None:
    """Have ``notice(line)`` called once, before the first render of this process, where that render compiles the
    built-in renderer's kernels for this machine (first use, or after an upgrade: about 40 s for a render and its
    gradients, 20 s for a render alone, on a 2-core machine; numba keeps them in its cache after), with a line saying
    so. None: nobody (the default: the library prints nothing; the command line registers a line on stderr)."""
    _FIRST_COMPILE[:] = [] if notice is None else [notice]


def take_first_compile() -> Optional[Callable[[str], None]]:
    """Return the notice :func:`tell_first_compile` registered and forget it (once: atomic across threads), or None."""
    try:
        return _FIRST_COMPILE.pop()
    except IndexError:
        return None
