"""``--renderer`` and ``--renderer-option`` of the commands that render: the renderer plugin is built when the
options are read, so a missing or unavailable one fails before any work. Imports the renderers (torch): only the
commands that render import this."""

from __future__ import annotations

from typing import Any, Callable

import click

from roodi_toolkit.render.renderer import get_renderer

from .common import parse_key_values


def _load_renderer(ctx: click.Context, param: click.Parameter, value: str) -> Any:
    """Return the renderer registered as ``value``, built with the ``--renderer-option`` values: a missing or
    unavailable plugin, or an option it does not take, fails before any work."""
    return get_renderer(value, **ctx.meta.get("renderer_options", {}))


def _keep_renderer_options(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> None:
    ctx.meta["renderer_options"] = parse_key_values(value, "--renderer-option")


def renderer_option(func: Callable[..., Any]) -> Callable[..., Any]:
    """``--renderer NAME`` (the command receives the :class:`~roodi_toolkit.render.renderer.Renderer` instance) and
    ``--renderer-option KEY=VALUE`` (repeatable; the renderer's keyword arguments, read first)."""
    func = click.option(
        "--renderer", default="numba", show_default=True, metavar="NAME", callback=_load_renderer,
        help="Renderer plugin for every rendering of the command: numba (built-in, compiled CPU kernels), torch "
             "(built-in, the slower reference) or an installed one such as gsplat (CUDA); see roodi-toolkit plugins.")(func)
    return click.option(
        "--renderer-option", multiple=True, metavar="KEY=VALUE", expose_value=False, is_eager=True,
        callback=_keep_renderer_options,
        help="Renderer option (repeatable), e.g. device=cuda:1 or tile_size=8 for gsplat: the keyword arguments of "
             "the plugin's class.")(func)
