"""Click options made from the settings of config dataclasses (:mod:`roodi_toolkit.settings`), and the configs
built back from the parsed values: a setting's option, type, range, default and help come from its field.

A number's range becomes a ``click.IntRange``/``FloatRange`` (floats are then wrapped to refuse NaN and infinities
by :func:`roodi_toolkit.cli.main._finite_floats`), choices a ``click.Choice``, a ``bool`` a flag, a tuple of numbers
one ``a,b,c`` value, a repeatable setting a ``multiple`` option. The click parameter is named after the field, so
the command function receives the settings under their fields' names.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, TypeVar

import click

from roodi_toolkit.settings import Declared, declared, parse_text

F = TypeVar("F", bound=Callable[..., Any])
C = TypeVar("C")


class SettingText(click.ParamType):
    """A setting written as text on the command line (``a,b,c`` numbers, or an entry of a repeatable setting): read
    by :func:`roodi_toolkit.settings.parse_text`; what it refuses is a usage error naming the option (exit 2)."""

    def __init__(self, setting: Declared) -> None:
        self.setting = setting
        self.name = "text"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if not isinstance(value, str):  # a default, already a value
            return value
        try:
            return parse_text(self.setting, value)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)

    def get_metavar(self, param: click.Parameter, *args: Any, **kwargs: Any) -> str | None:
        return self.setting.meta.metavar

    def __repr__(self) -> str:
        return f"SettingText({self.setting.name})"


def click_type(d: Declared) -> Any:
    """Return the click type of setting ``d``."""
    m = d.meta
    if m.choices is not None:
        return click.Choice(list(m.choices))
    if d.kind is tuple:
        return SettingText(d)
    if d.kind in (int, float) and (m.low is not None or m.high is not None):
        cls = click.IntRange if d.kind is int else click.FloatRange
        return cls(min=m.low, max=m.high, min_open=m.low_open, max_open=m.high_open)
    return {int: click.INT, float: click.FLOAT, str: click.STRING}[d.kind]


def click_option(d: Declared) -> Callable[[F], F]:
    """Return the click option of setting ``d`` (its parameter named after the field)."""
    m = d.meta
    shown = m.show_default and d.default not in (None, False, ())
    if d.kind is bool:
        return click.option(d.option, d.name, is_flag=True, default=d.default, help=m.help)
    return click.option(d.option, d.name, type=click_type(d), default=d.default, show_default=shown,
                        help=m.help, metavar=m.metavar, multiple=d.repeated)


def command_settings(*classes: type) -> list[Declared]:
    """Return the settings of ``classes`` that commands offer, in field order, each once."""
    out: dict[str, Declared] = {}
    for cls in classes:
        for d in declared(cls):
            if d.meta.cli and d.name not in out:
                out[d.name] = d
    return list(out.values())


def config_options(*classes: type) -> Callable[[F], F]:
    """Return a decorator adding the options of every command-line setting of ``classes`` to a click command, in
    field order (``--help`` lists them so)."""

    def decorate(func: F) -> F:
        for d in reversed(command_settings(*classes)):
            func = click_option(d)(func)
        return func

    return decorate


def option_names(cls: type) -> tuple[str, ...]:
    """Return the parameter names of the command-line settings of ``cls`` (its fields' names)."""
    return tuple(d.name for d in command_settings(cls))


def config_from_options(cls: type[C], values: Mapping[str, Any]) -> C:
    """Return ``cls`` built from a command's parsed values (``values``: the click parameters, which must hold every
    command-line setting of ``cls``; other keys are ignored); settings without an option keep their defaults.

    Raises:
        ConfigError: values the dataclass refuses (exit 1 with one line).
    """
    return cls(**{name: values[name] for name in option_names(cls)})
