"""Click options made from the settings of config dataclasses (:mod:`roodi_toolkit.settings`), and the configs
built back from the parsed values: a setting's option, type, range, default and help come from its field.

A number's range becomes a ``click.IntRange``/``FloatRange`` (floats are then wrapped to refuse NaN and infinities
by :func:`roodi_toolkit.cli.main._finite_floats`), choices a ``click.Choice``, a ``bool`` a flag, a tuple of numbers
one ``a,b,c`` value, a repeatable setting a ``multiple`` option. The click parameter is named after the field, so
the command function receives the settings under their fields' names.

:class:`Options` makes the options of one config with nested configs (``TrainConfig`` and its MCMC strategy,
``ExtractConfig`` and the configs of its stages): a nested config's options carry its prefix (``--distill-iterations``),
a flag on by default is offered as ``--no-NAME``, ``only=`` picks the settings a command offers (dotted paths, in
``--help``'s order), and ``unset=True`` makes options whose absence means "the config's value" (``train``'s, so that
``--resume`` keeps the resumed run's), with the default shown from the config. Given the config as
``"module:Class"`` (or ``"module:function"`` returning the base config), the options are made when the command is
first used rather than when its module is imported, on a :class:`SettingsCommand`: ``roodi-toolkit --help`` lists the
commands without importing PyTorch, which the pipeline's configs' modules import.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence, TypeVar

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
    if d.kind is tuple or d.meta.joins:
        return SettingText(d)
    if d.kind in (int, float) and (m.low is not None or m.high is not None):
        cls = click.IntRange if d.kind is int else click.FloatRange
        return cls(min=m.low, max=m.high, min_open=m.low_open, max_open=m.high_open)
    return {int: click.INT, float: click.FLOAT, str: click.STRING}[d.kind]


def click_option(d: Declared) -> Callable[[F], F]:
    """Return the click option of setting ``d`` (its parameter named after the field)."""
    option = make_option(Offered((d.name,), d, d.name, d.option, d.default))

    def decorate(func: F) -> F:
        func.__dict__.setdefault("__click_params__", []).append(option)
        return func

    return decorate


def make_option(o: "Offered", unset: bool = False) -> click.Option:
    """Return the click option of ``o``: its default the config's value, or None with ``unset`` (then ``--help``
    shows the config's value as the default)."""
    d, m = o.setting, o.setting.meta
    shown = m.show_default and d.kind is not bool and not (o.default is None or o.default == ())  # 0 is shown
    cls: Any = click.Option
    extra: dict[str, Any] = {}
    if unset:
        cls, extra, shown = UnsetOption, {"shown": _text(o.default, d) if shown else None}, False
    default = None if unset else _text(o.default, d) if d.meta.joins else o.default  # --size's: "200x200"
    if d.kind is bool:
        if d.negated:  # --no-prune: given, the setting is False
            return cls([o.option, o.param], is_flag=True, flag_value=False, default=default, help=m.help, **extra)
        if unset and "/" in o.option and o.option != d.option:  # made two-sided by the command (flags=): the
            # demo's --occluded/--no-occluded shows [default: occluded], its base's side
            extra["shown"] = o.option.split("/")[0 if o.default else 1].lstrip("-")
        return cls([o.option, o.param], is_flag=True, default=default, help=m.help, **extra)
    return cls([o.option, o.param], type=click_type(d), default=default, show_default=shown, help=m.help,
               metavar=m.metavar, multiple=d.repeated, **extra)


def _text(value: Any, d: Declared) -> str:
    """Return a default of ``d`` as ``--help`` writes it (``1,2,3`` for numbers in a tuple, ``200x200`` for
    ``--size``: the setting's ``write``)."""
    if d.meta.write is not None:
        return d.meta.write(value)
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    return str(value)


class UnsetOption(click.Option):
    """An option whose absence (None) means the config's value, which ``--help`` shows as its default."""

    def __init__(self, *args: Any, shown: str | None, **kwargs: Any) -> None:
        self.shown = shown
        super().__init__(*args, **kwargs)

    def get_help_extra(self, ctx: click.Context) -> Any:
        extra = super().get_help_extra(ctx)
        if self.shown is not None:
            extra["default"] = self.shown
        return extra


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


def joined_values(d: Declared, value: Any) -> dict[str, Any]:
    """Return the fields set by the option of ``d`` given ``value``: ``{d.name: value}``, or for a setting that joins
    others (``--size``) each field's part of the parsed tuple."""
    if not d.meta.joins:
        return {d.name: value}
    return dict(zip((d.name, *d.meta.joins), value))


def option_names(cls: type) -> tuple[str, ...]:
    """Return the parameter names of the command-line settings of ``cls`` (its fields' names)."""
    return tuple(d.name for d in command_settings(cls))


def config_from_options(cls: type[C], values: Mapping[str, Any]) -> C:
    """Return ``cls`` built from a command's parsed values (``values``: the click parameters, which must hold every
    command-line setting of ``cls``; other keys are ignored); settings without an option keep their defaults.

    Raises:
        ConfigError: values the dataclass refuses (exit 1 with one line).
    """
    fields: dict[str, Any] = {}
    for d in command_settings(cls):
        fields.update(joined_values(d, values[d.name]))
    return cls(**fields)


@dataclass(frozen=True)
class Offered:
    """One option of a command: the setting at ``path`` in a config.

    Attributes:
        path: field names from the top config down, e.g. ``("strategy", "cap_max")``.
        setting: the setting's declaration.
        param: the click parameter's name (the field's, after its nested configs' prefixes).
        option: the flag(s), e.g. ``--distill-iterations``, ``--no-prune``.
        default: the setting's value in the base config (which may differ from the field's default: the cap of
            ``TrainConfig``'s strategy is 60,000, the strategy's own 1,000,000); a tuple of its fields' values for a
            setting that joins others (``--size``: width and height).
    """

    path: tuple[str, ...]
    setting: Declared
    param: str
    option: str
    default: Any


def _prefixed(option: str, prefix: str) -> str:
    """Return ``option`` (``--iterations``, ``--no-prune``, ``--a/--b``) with ``prefix`` after its ``--`` (and
    ``no-``)."""
    if not prefix:
        return option
    out = []
    for part in option.split("/"):
        name = part[2:]
        out.append("--no-" + prefix + "-" + name[3:] if name.startswith("no-") else "--" + prefix + "-" + name)
    return "/".join(out)


def offered_settings(config: Any, only: Sequence[str] | None = None) -> list[Offered]:
    """Return the options of the config dataclass instance ``config``: every command-line setting, those of its
    nested configs included (their options prefixed), in field order; or those named in ``only`` (dotted paths such
    as ``"train.iterations"``), in its order.

    Raises:
        TypeError: a name of ``only`` that is no command-line setting of ``config``, or two settings that would be
            the same click parameter (mistakes in the command or the declarations).
    """
    found: dict[str, Offered] = {}

    def walk(obj: Any, path: tuple[str, ...], prefix: str) -> None:
        for d in declared(obj):
            if not d.meta.cli:
                continue
            value = getattr(obj, d.name)
            if d.nested:
                inner = "-".join(p for p in (prefix, d.meta.prefix) if p)
                walk(value, path + (d.name,), inner)
                continue
            param = "_".join(p for p in (prefix.replace("-", "_"), d.name) if p)
            twin = next((o for o in found.values() if o.param == param), None)
            if twin is not None:
                raise TypeError(f"{type(config).__name__}: {'.'.join(twin.path)} and {'.'.join(path + (d.name,))} "
                                f"would both be the parameter {param!r} (give a nested config another prefix)")
            if d.meta.joins:
                value = tuple(getattr(obj, name) for name in (d.name, *d.meta.joins))
            found[".".join(path + (d.name,))] = Offered(path + (d.name,), d, param, _prefixed(d.option, prefix),
                                                        value)

    walk(config, (), "")
    if only is None:
        return list(found.values())
    unknown = [name for name in only if name not in found]
    if unknown:
        raise TypeError(f"{type(config).__name__} has no command-line setting {', '.join(unknown)}")
    return [found[name] for name in only]


def _replaced(config: Any, changes: Mapping[tuple[str, ...], Any]) -> Any:
    """Return ``config`` with the values of ``changes`` (path -> value) set, nested configs rebuilt (and checked)."""
    top = {path[0]: value for path, value in changes.items() if len(path) == 1}
    inner: dict[str, dict[tuple[str, ...], Any]] = {}
    for path, value in changes.items():
        if len(path) > 1:
            inner.setdefault(path[0], {})[path[1:]] = value
    for name, sub in inner.items():
        top[name] = _replaced(getattr(config, name), sub)
    return dataclasses.replace(config, **top) if top else config


class _Later:
    """Where an :class:`Options` whose config is named by text puts its options once the command is used."""

    def __init__(self, options: "Options") -> None:
        self.options = options


class Options:
    """The options of a config dataclass (nested configs included) and the config made back from parsed values.

    Args:
        config: the config class (its defaults are the options' defaults), or ``"module:name"`` of a class or of a
            function returning the base config: then the options are made when the command is first used (the
            command must be a :class:`SettingsCommand`), so that its module can be imported without the config's.
        only: the dotted paths of the settings offered, in ``--help``'s order (default: every command-line setting).
        unset: options default to None, meaning "the base config's value" (shown as the default in ``--help``).
        within: a dotted path of fields to the config the options are made from, inside the target's base (the
            demo's ``"extract"``: the ExtractConfig of ``ExtractDemoConfig()``, whose defaults are the demo's own).
        flags: the command's own flag of a setting (dotted path -> flag), where it differs from the declared one:
            the demo's ``{"train.seed": "--train-seed"}`` (its ``--seed`` is the scene's) or ``{"occluded":
            "--occluded/--no-occluded"}`` (on by default there); the click parameter is named after the flag.

    Example:
        >>> from roodi_toolkit.prune.config import StatisticalSettings
        >>> rule = Options(StatisticalSettings, only=("rule", "k"))
        >>> [o.option for o in rule.offered()]
        ['--rule', '--k']
        >>> rule.config({"rule": "paper", "k": 8}) == StatisticalSettings(rule="paper", k=8)
        True
    """

    def __init__(self, config: type | str, *, only: Sequence[str] | None = None, unset: bool = False,
                 within: str = "", flags: Mapping[str, str] | None = None) -> None:
        self.target = config
        self.flags = dict(flags or {})
        self.only = tuple(only) if only is not None else None
        self.unset = unset
        self.within = within
        self._offered: list[Offered] | None = None

    @property
    def deferred(self) -> bool:
        """Whether the config is named by text (options made on first use)."""
        return isinstance(self.target, str)

    def base(self) -> Any:
        """Return the base config: the class's defaults, or what the named function returns (then the config at
        ``within`` in it)."""
        target = self.target
        if isinstance(target, str):
            module, _, name = target.partition(":")
            target = getattr(importlib.import_module(module), name)
        config = target()
        for name in filter(None, self.within.split(".")):
            config = getattr(config, name)
        return config

    def offered(self) -> list[Offered]:
        """Return the options offered (see :func:`offered_settings`)."""
        if self._offered is None:
            offered = offered_settings(self.base(), self.only)
            unknown = set(self.flags) - {".".join(o.path) for o in offered}
            if unknown:
                raise TypeError(f"flags= of settings not offered: {', '.join(sorted(unknown))}")
            self._offered = [dataclasses.replace(o, option=flag, param=flag.split("/")[0][2:].replace("-", "_"))
                             if (flag := self.flags.get(".".join(o.path))) else o for o in offered]
        return self._offered

    def click_options(self) -> list[click.Option]:
        """Return the click options, in order."""
        return [make_option(o, self.unset) for o in self.offered()]

    def __call__(self, func: F) -> F:
        """Add the options to a click command's function (or a placeholder the :class:`SettingsCommand` fills)."""
        params = func.__dict__.setdefault("__click_params__", [])
        if self.deferred:
            params.append(_Later(self))
        else:
            params.extend(reversed(self.click_options()))  # click reverses the decorators' list
        return func

    def config(self, values: Mapping[str, Any], base: Any = None) -> Any:
        """Return the config of a command's parsed ``values`` (the click parameters, which must hold every option;
        other keys are ignored): ``base`` (default: :meth:`base`) with the options' values set; with ``unset``, an
        option left None keeps the base's value.

        Raises:
            ConfigError: values the config refuses (exit 1 with one line).
        """
        changes = {}
        for o in self.offered():
            value = values[o.param]
            if not (self.unset and value is None):
                changes.update((o.path[:-1] + (name,), v) for name, v in joined_values(o.setting, value).items())
        return _replaced(self.base() if base is None else base, changes)


class SettingsCommand(click.Command):
    """A click command with :class:`Options` made on first use of its parameters (``--help`` of the command,
    parsing), not when its module is imported; ``finishers`` run on the command once they are made (the CLI's
    float and seed types, :func:`roodi_toolkit.cli.main._finite_floats`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.finishers: list[Callable[[click.Command], Any]] = []
        super().__init__(*args, **kwargs)

    @property
    def params(self) -> list[click.Parameter]:  # type: ignore[override]
        if any(isinstance(p, _Later) for p in self._params):
            made: list[Any] = []
            for p in self._params:
                made.extend(p.options.click_options() if isinstance(p, _Later) else [p])
            self._params = made
            for finish in self.finishers:
                finish(self)
        return self._params

    @params.setter
    def params(self, value: list[click.Parameter]) -> None:
        self._params = list(value)

    @property
    def made_params(self) -> list[click.Parameter]:
        """The parameters made so far (reading them makes none)."""
        return [p for p in self._params if not isinstance(p, _Later)]
