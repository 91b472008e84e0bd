"""One generic plugin registry over Python entry points.

Groups: ``roodi_toolkit.renderers``, ``roodi_toolkit.inpainters``, ``roodi_toolkit.segmenters``. Built-in backends
register through the same groups (in this package's ``setup.cfg``) as third-party ones.

Discovery happens when asked, never at import time, and each plugin loads inside its own ``try``: a plugin that fails
to import is reported by name with its error and never breaks the others.

To register a plugin during development without installing it, set ``ROODI_PLUGINS`` to a ``;``-separated list of
``group:name=module:attr`` (the group may be the short form ``renderers``, ``inpainters`` or ``segmenters``)::

    ROODI_PLUGINS="inpainters:blur=my_pkg.inpaint:BlurInpainter" roodi-toolkit plugins
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from importlib import metadata
from typing import Any

from .errors import PluginError

GROUPS = ("roodi_toolkit.renderers", "roodi_toolkit.inpainters", "roodi_toolkit.segmenters")
ENV_VAR = "ROODI_PLUGINS"


@dataclass(frozen=True)
class PluginSpec:
    """Where a plugin comes from, before it is loaded.

    Attributes:
        group: the full entry-point group.
        name: the plugin's name within the group (what users pass, e.g. ``--inpainter opencv``).
        target: ``module:attr`` it points to.
        origin: the distribution that registers it (``roodi-toolkit`` for built-ins) or ``$ROODI_PLUGINS``.
    """

    group: str
    name: str
    target: str
    origin: str

    def load(self) -> Any:
        """Import and return the plugin object, or raise PluginError naming the plugin and its error."""
        module_name, _, attr = self.target.partition(":")
        try:
            obj: Any = importlib.import_module(module_name)
            for part in filter(None, attr.split(".")):
                obj = getattr(obj, part)
        except Exception as exc:  # noqa: BLE001 - any import failure is the plugin's, reported by name
            raise PluginError(f"plugin {self.name!r} ({short_group(self.group)}, from {self.origin}) failed to "
                              f"load: {type(exc).__name__}: {exc}") from exc
        return obj


@dataclass(frozen=True)
class PluginStatus:
    """A plugin after an attempt to load it."""

    spec: PluginSpec
    ok: bool
    error: str = ""


def full_group(group: str) -> str:
    """Return the full entry-point group for ``renderers`` or ``roodi_toolkit.renderers``."""
    name = group if group.startswith("roodi_toolkit.") else f"roodi_toolkit.{group}"
    if name not in GROUPS:
        raise PluginError(f"unknown plugin group {group!r}; known: {', '.join(short_group(g) for g in GROUPS)}")
    return name


def short_group(group: str) -> str:
    return group.removeprefix("roodi_toolkit.")


def _env_specs(group: str) -> list[PluginSpec]:
    raw = os.environ.get(ENV_VAR, "").strip()
    specs = []
    for item in filter(None, (s.strip() for s in raw.split(";"))):
        try:
            grp, rest = item.split(":", 1)
            name, target = rest.split("=", 1)
            if ":" not in target:
                raise ValueError
        except ValueError:
            raise PluginError(f"${ENV_VAR}: cannot parse {item!r}; expected group:name=module:attr") from None
        if full_group(grp.strip()) == group:
            specs.append(PluginSpec(group, name.strip(), target.strip(), f"${ENV_VAR}"))
    return specs


def discover(group: str) -> list[PluginSpec]:
    """Return the plugins registered in ``group`` (entry points, then ``$ROODI_PLUGINS``), without loading them.

    A later registration of the same name wins, so ``$ROODI_PLUGINS`` can stand in for an installed plugin.
    """
    group = full_group(group)
    found: dict[str, PluginSpec] = {}
    for ep in metadata.entry_points(group=group):
        dist = getattr(ep, "dist", None)
        origin = dist.metadata["Name"] if dist is not None else "unknown distribution"
        found[ep.name] = PluginSpec(group, ep.name, ep.value, origin)
    for spec in _env_specs(group):
        found[spec.name] = spec
    return sorted(found.values(), key=lambda s: (s.origin != "roodi-toolkit", s.name))


def load_plugin(group: str, name: str) -> Any:
    """Return the loaded plugin object ``name`` of ``group``.

    Raises:
        PluginError: no such plugin (the message lists the available ones) or it failed to load.
    """
    specs = {s.name: s for s in discover(group)}
    if name not in specs:
        available = ", ".join(sorted(specs)) or "none"
        raise PluginError(f"no {short_group(full_group(group))[:-1]} plugin named {name!r}; available: {available}")
    return specs[name].load()


def check_all(groups: tuple[str, ...] = GROUPS) -> list[PluginStatus]:
    """Try to load every plugin of ``groups``; return one status per plugin (failures included, never raised)."""
    statuses = []
    for group in groups:
        for spec in discover(group):
            try:
                spec.load()
            except PluginError as exc:
                cause = exc.__cause__
                statuses.append(PluginStatus(spec, False, f"{type(cause).__name__}: {cause}" if cause else str(exc)))
            else:
                statuses.append(PluginStatus(spec, True))
    return statuses


def instantiate(group: str, name: str, base: type, **options: Any) -> Any:
    """Return an instance of plugin ``name`` of ``group``, which must be a subclass of ``base``, built with ``options``.

    The class's ``available()`` (returning ``(ok, why)``) is asked first, so a backend that cannot run here (no CUDA,
    no local weights) says why instead of failing later.

    Raises:
        PluginError: unknown name, failed import, not a subclass of ``base``, unavailable, or options it does not take.
    """
    kind = short_group(full_group(group))[:-1]
    cls = load_plugin(group, name)
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise PluginError(f"{kind} plugin {name!r} is {cls!r}, not a {base.__module__}.{base.__qualname__} subclass")
    ok, why = cls.available()
    if not ok:
        raise PluginError(f"{kind} {name!r} cannot run here: {why}")
    try:
        return cls(**options)
    except TypeError as exc:
        raise PluginError(f"{kind} {name!r} does not take these options: {exc}") from None
