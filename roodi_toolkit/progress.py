"""Progress reporting without printing: library code takes a progress factory, the CLI passes a real bar.

A progress factory is any callable ``factory(total=int, desc=str)`` returning an object with ``update(n)`` and
``close()`` that also works as a context manager; ``tqdm.tqdm`` is one. The default does nothing.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol


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
