"""One home per setting: a config dataclass declares each setting once, in its field, with its default, range or
choices, help and command-line name; the CLI options (``roodi_toolkit.cli.settings``) and the checks of the
dataclass (:func:`check_settings`, from its ``__post_init__``) are made from that declaration.

A setting is a dataclass field made by :func:`setting`; its :class:`Setting` sits in the field's metadata. Its value
space comes from the field's annotation: ``bool`` (a flag), ``int``, ``float``, ``str`` (with ``choices``), ``X |
None`` (None: unset), ``tuple[float, float, ...]`` (a fixed number of values, written ``a,b,c`` on the command line)
and ``tuple[X, ...]`` (repeatable, each value read by ``parse``). A ``bool`` whose default is True is offered as
``--no-NAME``. A field holding another config dataclass declares it with ``setting(factory=Config, prefix=...)``: its
settings are offered too, their options prefixed (``prefix="distill"``: ``--distill-iterations``; ``""``: as they
are). Any other value (a dict, a dataclass of no settings) is a library-only setting (``cli=False``), checked by its
type. This module imports no command-line library: the library's configs declare their settings without depending on
how a command line (or a batch manifest) reads them.

Example:
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Blur:
    ...     radius: int = setting(3, "Blur radius in pixels.", low=1)
    ...     def __post_init__(self) -> None:
    ...         check_settings(self)
    >>> Blur(radius=0)
    Traceback (most recent call last):
    ...
    roodi_toolkit.errors.ConfigError: radius must be a whole number >= 1, got 0
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import textwrap
import typing
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .errors import ConfigError

KEY = "roodi_setting"
"""The key of a field's metadata that holds its :class:`Setting`."""


@dataclass(frozen=True)
class Setting:
    """What a setting is, beyond its name and default (which the field holds).

    Attributes:
        help: one or two sentences for ``--help``: what the setting does, in the user's units.
        low, high: the range of a number (None: open on that side); ``low_open``/``high_open`` exclude the bound.
        choices: the values a text setting takes.
        finite: a float must be finite (False: +-inf allowed, NaN never).
        option: the command-line flag (default ``--`` + the field's name with ``-`` for ``_``); None with
            ``cli=False``.
        cli: whether commands offer it (False: a library-only setting, its default on the command line).
        metavar: how ``--help`` names the value (default: from the type).
        parse: turns one command-line or manifest text into the value (one entry of a repeatable setting); raises
            ValueError with what is wrong.
        show_default: whether ``--help`` shows the default (never for None, False or an empty tuple).
        prefix: a nested config's prefix of its settings' options and click parameters (``"distill"``:
            ``--distill-iterations``, ``distill_iterations``; ``""``: none); None for a plain setting.
        joins: the other fields of the config that this setting's option sets with it (``SceneSettings.width``'s
            ``--size 64x48`` sets ``height`` too): ``parse`` returns the values of all, this field's first, and
            ``write`` writes them back as the option's text; the joined fields declare ``cli=False``.
        write: how ``--help`` writes the default of a setting with ``joins`` (the inverse of ``parse``).
    """

    help: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] | None = None
    finite: bool = True
    option: str | None = None
    cli: bool = True
    metavar: str | None = None
    parse: Callable[[str], Any] | None = None
    show_default: bool = True
    prefix: str | None = None
    joins: tuple[str, ...] = ()
    write: Callable[[tuple[Any, ...]], str] | None = None


def setting(default: Any = dataclasses.MISSING, help: str = "", *, factory: Callable[[], Any] | None = None,
            prefix: str | None = None, low: float | None = None, high: float | None = None, low_open: bool = False,
            high_open: bool = False, choices: tuple[str, ...] | None = None, finite: bool = True,
            option: str | None = None, cli: bool = True, metavar: str | None = None,
            parse: Callable[[str], Any] | None = None, show_default: bool = True, joins: tuple[str, ...] = (),
            write: Callable[[tuple[Any, ...]], str] | None = None) -> Any:
    """Return a dataclass field declaring a setting: its default (or ``factory``, which makes it: a nested config or
    a dict) and its :class:`Setting` (the other arguments)."""
    if not help:
        raise TypeError("a setting needs its help")
    if (default is dataclasses.MISSING) == (factory is None):
        raise TypeError("a setting has a default or a factory, one of them")
    meta = Setting(help=help, low=low, high=high, low_open=low_open, high_open=high_open,
                   choices=tuple(choices) if choices is not None else None, finite=finite, option=option, cli=cli,
                   metavar=metavar, parse=parse, show_default=show_default, prefix=prefix, joins=tuple(joins),
                   write=write)
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata={KEY: meta})
    return dataclasses.field(default=default, metadata={KEY: meta})


@dataclass(frozen=True)
class Declared:
    """One setting of a config class, as the option makers and the checks read it.

    Attributes:
        name: the field's name (the click parameter's name too).
        default: the field's default.
        kind: the value's type: ``bool``, ``int``, ``float``, ``str`` or ``tuple`` (of ``size`` floats); a config
            dataclass (a nested config, see :attr:`nested`) or another class (a library-only value).
        optional: None is a value (unset).
        repeated: a ``tuple[X, ...]`` of entries, each read by ``meta.parse``.
        size: the number of floats of a fixed tuple (0 otherwise).
        meta: the field's :class:`Setting`.
    """

    name: str
    default: Any
    kind: type
    optional: bool
    repeated: bool
    size: int
    meta: Setting

    @property
    def option(self) -> str:
        """The command-line flag, e.g. ``--min-opacity``; ``--no-NAME`` for a flag that is on by default."""
        if self.meta.option:
            return self.meta.option
        return ("--no-" if self.negated else "--") + self.name.replace("_", "-")

    @property
    def negated(self) -> bool:
        """A flag on by default: its option (``--no-prune``) turns it off."""
        return self.kind is bool and self.default is True and "/" not in (self.meta.option or "")

    @property
    def nested(self) -> bool:
        """A config dataclass whose own settings are offered (with :attr:`Setting.prefix`)."""
        return self.meta.prefix is not None


def declared(cls: type) -> list[Declared]:
    """Return the settings of the dataclass ``cls`` (an instance works too) in field order, base classes first.

    Raises:
        TypeError: a field of ``cls`` that is no :func:`setting`, or an annotation outside the supported ones (a
            mistake in the declaration, not in a user's input).
    """
    cls = cls if isinstance(cls, type) else type(cls)
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        meta = f.metadata.get(KEY)
        if meta is None:
            raise TypeError(f"{cls.__name__}.{f.name} is not declared with roodi_toolkit.settings.setting()")
        out.append(_declare(cls.__name__, f, hints[f.name], meta))
    return out


def default_of(f: dataclasses.Field) -> Any:
    """Return the default of the dataclass field ``f`` (made by its factory if it has one)."""
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def _declare(owner: str, f: dataclasses.Field, hint: Any, meta: Setting) -> Declared:
    args = typing.get_args(hint)
    optional = type(None) in args
    if optional:
        inner = [a for a in args if a is not type(None)]
        hint = inner[0] if len(inner) == 1 else hint
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    repeated, size, kind = False, 0, hint
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        if meta.parse is None:
            raise TypeError(f"{owner}.{f.name}: a repeatable setting needs parse=")
        repeated, kind = True, tuple
    elif origin is tuple and args and all(a is float for a in args):
        size, kind = len(args), tuple
    if meta.joins and (meta.parse is None or meta.write is None):
        raise TypeError(f"{owner}.{f.name}: a setting that joins others needs parse= and write=")
    if meta.prefix is not None and not (isinstance(kind, type) and dataclasses.is_dataclass(kind)):
        raise TypeError(f"{owner}.{f.name}: prefix= is for a nested config dataclass, not {hint!r}")
    if kind not in (bool, int, float, str, tuple) and not (isinstance(kind, type) and (
            meta.prefix is not None or not meta.cli)):
        raise TypeError(f"{owner}.{f.name}: unsupported setting type {hint!r} (a nested config takes prefix=, "
                        f"another value cli=False)")
    return Declared(f.name, default_of(f), kind, optional, repeated, size, meta)


def describe_range(d: Declared) -> str:
    """Return the value space of a setting in words, e.g. ``a whole number >= 1`` or ``a number in [0, 1)``."""
    m = d.meta
    if m.choices is not None:
        return "one of " + ", ".join(m.choices)
    if d.kind not in (bool, int, float, str, tuple):
        return f"a {d.kind.__name__}"
    if d.kind is tuple:
        return f"{d.size} finite numbers" if d.size else "a list"
    what = {int: "a whole number", float: "a finite number" if m.finite else "a number", bool: "true or false",
            str: "text"}[d.kind]
    if m.low is not None and m.high is not None:
        return f"{what} in {'(' if m.low_open else '['}{m.low:g}, {m.high:g}{')' if m.high_open else ']'}"
    if m.low is not None:
        return f"{what} {'>' if m.low_open else '>='} {m.low:g}"
    if m.high is not None:
        return f"{what} {'<' if m.high_open else '<='} {m.high:g}"
    return what


def _fits(d: Declared, value: Any) -> bool:
    """Whether ``value`` lies in the declared value space of ``d`` (None aside)."""
    m = d.meta
    if d.kind not in (bool, int, float, str, tuple):  # a nested config (checked by its own class) or a value
        return isinstance(value, d.kind)
    if d.kind is bool:
        return isinstance(value, (bool, np.bool_))
    if d.kind is str:
        return isinstance(value, str) and (m.choices is None or value in m.choices)
    if d.kind is tuple:
        if d.repeated:
            return isinstance(value, tuple)
        try:
            values = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            return False
        return len(values) == d.size and all(math.isfinite(v) for v in values)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    if d.kind is int and not isinstance(value, numbers.Integral):
        return False
    v = float(value)
    if math.isnan(v) or (m.finite and math.isinf(v)):
        return False
    if m.low is not None and (v < m.low or (m.low_open and v == m.low)):
        return False
    return m.high is None or not (v > m.high or (m.high_open and v == m.high))


def check_settings(config: Any) -> None:
    """Check every setting of the dataclass instance ``config`` against its declaration (type, range, choices).

    Raises:
        ConfigError: the first setting outside its value space, named with the space and the value.
    """
    for d in declared(config):
        value = getattr(config, d.name)
        if value is None and d.optional:
            continue
        if not _fits(d, value):
            raise ConfigError(f"{d.name} must be {describe_range(d)}{' or None' if d.optional else ''}, got "
                              f"{value!r}")


def documented(cls: type | None = None, *, given: str | None = None) -> Any:
    """Return the dataclass ``cls`` with its settings listed under ``Attributes:`` in its docstring (name, default,
    value space, help: from the declarations, so ``help(cls)`` and ``--help`` say the same), each wrapped at 116
    characters. A nested config's default is written as its class with the settings that differ from the class's
    own defaults (``MCMCStrategy(cap_max=60000)``). ``given``: how a command line gives each setting of a config
    that has no options of its own (``"--segmenter-option {name}=VALUE"``); then ``@documented(given=...)``."""
    if cls is None:
        return lambda c: documented(c, given=given)
    lines = []
    settings = declared(cls)
    joined = {name: d.option for d in settings if d.meta.cli for name in d.meta.joins}
    for d in settings:
        space = describe_range(d) + (" or None" if d.optional else "")
        option = f"; {d.option}" if d.meta.cli else f"; with {joined[d.name]}" if d.name in joined else "; library only"
        if given is not None and d.meta.cli:
            option = "; " + given.format(name=d.name)
        if d.nested and d.meta.cli:
            option = f"; its settings' options{f' as --{d.meta.prefix}-NAME' if d.meta.prefix else ''}"
        lines.append(textwrap.fill(f"{d.name}: {d.meta.help} (default {_short_repr(d.default)}; {space}{option})",
                                   width=116, initial_indent=" " * 8, subsequent_indent=" " * 12,
                                   break_long_words=False, break_on_hyphens=False))
    cls.__doc__ = (cls.__doc__ or cls.__name__).rstrip() + "\n\n    Attributes:\n" + "\n".join(lines) + "\n"
    return cls


def _short_repr(value: Any) -> str:
    """Return ``repr(value)``; for a dataclass instance whose fields all have defaults, its class with only the fields
    that differ from them (``TrainConfig()``, ``MCMCStrategy(cap_max=60000)``)."""
    if not dataclasses.is_dataclass(value) or isinstance(value, type):
        return repr(value)
    fields = [f for f in dataclasses.fields(value) if f.init]
    if any(f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING for f in fields):
        return repr(value)
    changed = [f"{f.name}={_short_repr(getattr(value, f.name))}" for f in fields
               if getattr(value, f.name) != default_of(f)]
    return f"{type(value).__name__}({', '.join(changed)})"


def parse_floats(text: str, size: int) -> tuple[float, ...]:
    """Return ``size`` finite numbers from ``'a,b,c'`` (spaces and empty parts ignored).

    Raises:
        ValueError: not numbers, not ``size`` of them, or not finite (the message says which).
    """
    parts = [p for p in str(text).replace(" ", "").split(",") if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise ValueError(f"expected {size} comma-separated numbers, got {text!r}") from None
    if len(values) != size:
        raise ValueError(f"expected {size} comma-separated numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"expected finite numbers, got {text!r}")
    return values


MAX_IMAGE_SIDE = 16384
"""The longest image side a size option takes (a config may allow less)."""


def parse_image_size(text: str, low: int = 1, high: int = MAX_IMAGE_SIDE) -> tuple[int, int]:
    """Return ``(width, height)`` from ``'WIDTHxHEIGHT'`` or one number (a square), each ``low`` to ``high``.

    Raises:
        ValueError: not that form, or a side outside that range (the message says which).
    """
    t = str(text).lower().strip()
    try:
        if "x" in t:
            w, h = (int(v) for v in t.split("x", 1))
        else:
            w = h = int(t)
    except ValueError:
        raise ValueError(f"expected WIDTHxHEIGHT such as 256x256, got {text!r}") from None
    if not (low <= w <= high and low <= h <= high):
        raise ValueError(f"size must be between {low} and {high} pixels, got {text!r}")
    return w, h


def write_image_size(size: tuple[int, int]) -> str:
    """Return ``(width, height)`` as :func:`parse_image_size` reads it: ``'WIDTHxHEIGHT'``."""
    return f"{size[0]}x{size[1]}"


def parse_text(d: Declared, text: str) -> Any:
    """Return the value of the tuple setting ``d`` written as ``text`` (one entry of a repeatable setting), as a
    command line writes it (``a,b,c``); its range is checked by the dataclass (:func:`check_settings`).

    Raises:
        ValueError: text that is not a value of the setting (the message says what was expected).
    """
    if d.meta.parse is not None:
        return d.meta.parse(text)
    return parse_floats(text, d.size)


_TRUE, _FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")


def parse_value(d: Declared, text: str) -> Any:
    """Return the value of setting ``d`` written as ``text`` (a ``KEY=VALUE`` option such as ``--segmenter-option``,
    or a manifest cell): a number, ``true``/``false``, text, ``none`` for an unset optional setting, or a tuple as
    :func:`parse_text` reads it. Its range is checked by the dataclass (:func:`check_settings`).

    Raises:
        ValueError: text that is no value of the setting's type (the message says what was expected).
    """
    t = str(text).strip()
    if d.optional and t.lower() in ("none", ""):
        return None
    if d.kind is tuple or d.meta.joins:
        return parse_text(d, t)
    expected = describe_range(d) + (" or none" if d.optional else "")
    if d.kind is bool:
        if t.lower() not in _TRUE + _FALSE:
            raise ValueError(f"expected {expected}")
        return t.lower() in _TRUE
    if d.kind in (int, float):
        try:
            return d.kind(t)
        except ValueError:
            raise ValueError(f"expected {expected}") from None
    if d.kind is str:
        return t
    raise ValueError(f"{d.name} cannot be given as text")


def config_from_text(cls: type, values: dict[str, Any], what: str) -> Any:
    """Return the config dataclass ``cls`` built from ``values`` (field -> value; text is read by
    :func:`parse_value`, other values are taken as they are), each error one line starting with ``what`` (``click
    segmenter option``) and naming the setting.

    Raises:
        ConfigError: a key that is no setting of ``cls`` (the settings listed), text that is no value of its
            setting, or a value outside the setting's range.
    """
    settings = {d.name: d for d in declared(cls)}
    unknown = sorted(set(values) - set(settings))
    if unknown:
        raise ConfigError(f"{what} {', '.join(unknown)}: no setting of {cls.__name__}; its settings are "
                          f"{', '.join(settings)}")
    parsed = {}
    for name, value in values.items():
        if isinstance(value, str):
            try:
                value = parse_value(settings[name], value)
            except ValueError as exc:
                raise ConfigError(f"{what} {name}={value!r}: {exc}") from None
        parsed[name] = value
    try:
        return cls(**parsed)
    except ConfigError as exc:
        raise ConfigError(f"{what}: {exc}") from None
