"""Matplotlib figures made without pyplot (saved by :func:`roodi_toolkit.io.files.save_figure`)."""

from __future__ import annotations

from typing import Any

from matplotlib.figure import Figure


def new_figure(*args: Any, figsize: tuple[float, float], **subplots: Any) -> tuple[Any, Any]:
    """Return ``(figure, axes)`` like ``plt.subplots`` but without pyplot, so the caller's matplotlib backend (a
    notebook's inline one, say) is neither needed nor changed; save it with
    :func:`roodi_toolkit.io.files.save_figure`."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*args, **subplots)
