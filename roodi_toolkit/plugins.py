"""One generic plugin registry over Python entry points.

Groups: ``roodi_toolkit.renderers``, ``roodi_toolkit.inpainters``, ``roodi_toolkit.segmenters``. Built-in backends
register through the same groups (in this package's ``setup.cfg``) as third-party ones.

Discovery happens when asked, never at import time, and each plugin loads inside its own ``try``: a plugin that fails
to import is reported by name with its error and never breaks the others.

To register a plugin during development without installing it, set ``ROODI_PLUGINS`` to a ``;``-separated list of
``group:name=module:attr`` (the group may be the short form ``renderers``, ``inpainters`` or ``segmenters``)::

    ROODI_PLUGINS="inpainters:blur=my_pkg.inpaint:BlurInpainter" roodi-toolkit plugins

The module is looked up on ``sys.path`` and then in the current folder (as ``python`` finds a script's neighbours; a
console script's ``sys.path`` does not hold it), and ``module`` may also be a ``.py`` file's path
(``inpainters:blur=plugins/blur.py:BlurInpainter``), so no ``PYTHONPATH`` is needed.

What ``roodi-toolkit plugins`` says of each plugin (:func:`plugin_state`): ``installed`` (it loads and can run here),
``needs CUDA``, ``needs weights``, ``needs a package`` (its class's ``status()`` says which, and what to do; a class
without one is ``installed`` or ``unavailable`` as its ``available()`` says), or ``error`` (it does not load).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import os
import sys
import threading
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from .errors import PluginError

GROUPS = ("roodi_toolkit.renderers", "roodi_toolkit.inpainters", "roodi_toolkit.segmenters")
ENV_VAR = "ROODI_PLUGINS"
TIMEOUT_VAR = "ROODI_PLUGIN_TIMEOUT"


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
        """Import and return the plugin object, or raise PluginError naming the plugin and its error.

        The import runs in a worker thread under a time limit (``$ROODI_PLUGIN_TIMEOUT`` seconds, default 300) with
        ``os._exit`` turned into an exception, so a plugin that blocks, exits (``sys.exit``, ``os._exit``) or raises
        ``KeyboardInterrupt`` while importing is reported by name and cannot take the command down with it.
        """
        outcome: dict[str, Any] = {}

        def run() -> None:
            try:
                outcome["obj"] = self._import()
            except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt: the plugin's, reported
                outcome["exc"] = exc

        limit = plugin_timeout()
        real_exit = os._exit
        os._exit = _refuse_exit  # a plugin that hard-exits at import must not end the process
        try:
            worker = threading.Thread(target=run, name=f"load plugin {self.name}", daemon=True)
            worker.start()
            worker.join(limit)
        finally:
            os._exit = real_exit
        if worker.is_alive():
            raise PluginError(f"plugin {self.name!r} ({short_group(self.group)}, from {self.origin}) did not finish "
                              f"importing within {limit:g} s (it blocks at import); fix or uninstall it, or raise "
                              f"${TIMEOUT_VAR}")
        if "exc" in outcome:
            exc = outcome["exc"]
            raise PluginError(f"plugin {self.name!r} ({short_group(self.group)}, from {self.origin}) failed to "
                              f"load: {type(exc).__name__}: {exc}") from exc
        return outcome["obj"]

    def _import(self) -> Any:
        module_name, _, attr = self.target.rpartition(":")
        obj: Any = _import_module(module_name, from_env=self.origin == f"${ENV_VAR}")
        for part in filter(None, attr.split(".")):
            obj = getattr(obj, part)
        return obj


def _import_module(name: str, *, from_env: bool) -> Any:
    """Import a plugin's module; a ``$ROODI_PLUGINS`` one may be a ``.py`` file's path or sit in the current folder."""
    if from_env and name.endswith(".py"):
        path = Path(name).expanduser()
        if not path.is_file():
            raise ModuleNotFoundError(f"no plugin file {name} (from ${ENV_VAR}; relative to {os.getcwd()})")
        module_name = f"roodi_plugin_{path.stem}"
        if module_name in sys.modules:
            return sys.modules[module_name]
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[module_name]
            raise
        return module
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        here = os.getcwd()
        if not from_env or exc.name != name.split(".")[0] or here in sys.path or "" in sys.path:
            raise
        # a console script's sys.path starts at its bin folder, not at the current folder that `python -m` adds
        sys.path.insert(0, here)
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError as again:
            if again.name == name.split(".")[0]:
                raise ModuleNotFoundError(f"No module named {name!r} on sys.path or in the current folder {here}",
                                          name=again.name) from None
            raise


class PluginExit(BaseException):
    """A plugin called ``os._exit`` while being imported (it is turned into this exception, then reported)."""


def _refuse_exit(code: int = 0) -> None:
    raise PluginExit(f"os._exit({code}) called at import")


def plugin_timeout() -> float:
    """Seconds a plugin may take to import: ``$ROODI_PLUGIN_TIMEOUT`` (default 300; a CUDA plugin may compile)."""
    raw = os.environ.get(TIMEOUT_VAR, "300")
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise PluginError(f"${TIMEOUT_VAR} must be a positive number of seconds, got {raw!r}")
    return value


@dataclass(frozen=True)
class PluginStatus:
    """A plugin after an attempt to load it.

    Attributes:
        spec: where it comes from.
        ok: it loads.
        error: why it does not load.
        state: ``installed``, ``needs CUDA``, ``needs weights``, ``needs a package``, ``unavailable`` or ``error``
            (:func:`plugin_state`).
        detail: what is missing and what to do (empty when installed).
    """

    spec: PluginSpec
    ok: bool
    error: str = ""
    state: str = "installed"
    detail: str = ""


INSTALLED, NEEDS_CUDA, NEEDS_WEIGHTS, NEEDS_PACKAGE, UNAVAILABLE = (
    "installed", "needs CUDA", "needs weights", "needs a package", "unavailable")
STATES = (INSTALLED, NEEDS_CUDA, NEEDS_WEIGHTS, NEEDS_PACKAGE, UNAVAILABLE)
"""What a plugin class's optional ``status()`` classmethod returns first, with a line saying what to do."""


def plugin_state(obj: Any) -> tuple[str, str]:
    """Return ``(state, detail)`` of a loaded plugin: its class's ``status()`` when it has one (one of
    :data:`STATES` and what to do), else ``installed`` or ``unavailable`` from its ``available()``."""
    try:
        if hasattr(obj, "status"):
            state, detail = obj.status()
            if state not in STATES:
                return UNAVAILABLE, f"status() returned an unknown state {state!r}: {detail}"
            return state, "" if state == INSTALLED else str(detail)
        if hasattr(obj, "available"):
            ok, why = obj.available()
            return (INSTALLED, "") if ok else (UNAVAILABLE, str(why))
    except Exception as exc:  # noqa: BLE001 - a plugin's own check must not break the listing
        return UNAVAILABLE, f"its status check failed: {type(exc).__name__}: {exc}"
    return INSTALLED, ""


def full_group(group: str) -> str:
    """Return the full entry-point group for ``renderers`` or ``roodi_toolkit.renderers``."""
    name = group if group.startswith("roodi_toolkit.") else f"roodi_toolkit.{group}"
    if name not in GROUPS:
        raise PluginError(f"unknown plugin group {group!r}; known: {', '.join(short_group(g) for g in GROUPS)}")
    return name


def short_group(group: str) -> str:
    return group.removeprefix("roodi_toolkit.")


def _env_entries() -> tuple[list[PluginSpec], list[str]]:
    """Return the well-formed ``$ROODI_PLUGINS`` entries as specs and a one-line problem for each malformed one."""
    raw = os.environ.get(ENV_VAR, "").strip()
    specs, problems = [], []
    for item in filter(None, (s.strip() for s in raw.split(";"))):
        try:
            grp, rest = item.split(":", 1)
            name, target = rest.split("=", 1)
            module, _, _ = target.partition(":")
            if ":" not in target or not name.strip() or not module.strip():
                raise ValueError
        except ValueError:
            problems.append(f"${ENV_VAR}: cannot parse {item!r}; expected group:name=module:attr")
            continue
        try:
            group = full_group(grp.strip())
        except PluginError as exc:
            problems.append(f"${ENV_VAR}: {item!r}: {exc}")
            continue
        specs.append(PluginSpec(group, name.strip(), target.strip(), f"${ENV_VAR}"))
    return specs, problems


def env_problems() -> list[str]:
    """Return one line per malformed ``$ROODI_PLUGINS`` entry (such entries are skipped, never fatal on their own)."""
    return _env_entries()[1]


def _env_specs(group: str) -> list[PluginSpec]:
    return [s for s in _env_entries()[0] if s.group == group]


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
        problems = env_problems()  # a malformed entry matters only when the plugin it may have meant is missing
        hint = f" ({problems[0]})" if problems else ""
        raise PluginError(f"no {short_group(full_group(group))[:-1]} plugin named {name!r}; available: "
                          f"{available}{hint}")
    return specs[name].load()


def check_all(groups: tuple[str, ...] = GROUPS) -> list[PluginStatus]:
    """Try to load every plugin of ``groups``; return one status per plugin (failures included, never raised).

    A malformed ``$ROODI_PLUGINS`` entry is listed as a failed plugin named ``?`` in the group ``ROODI_PLUGINS``.
    """
    statuses = [PluginStatus(PluginSpec(ENV_VAR, "?", "", f"${ENV_VAR}"), False, problem)
                for problem in env_problems()]
    for group in groups:
        for spec in discover(group):
            try:
                obj = spec.load()
            except PluginError as exc:
                cause = exc.__cause__
                error = f"{type(cause).__name__}: {cause}" if cause else str(exc)
                statuses.append(PluginStatus(spec, False, error, "error", error))
            else:
                statuses.append(PluginStatus(spec, True, "", *plugin_state(obj)))
    return statuses


def coerce_options(cls: type, options: dict[str, Any], kind: str, name: str) -> dict[str, Any]:
    """Return ``options`` with text values (``KEY=VALUE`` from the command line) turned into the type of the
    constructor's default for that keyword (bool, int, float); other values and unknown keywords are left as given.

    Raises:
        PluginError: a value that is not of its keyword's type.
    """
    try:
        params = inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return dict(options)
    out = dict(options)
    for key, value in options.items():
        param = params.get(key)
        if not isinstance(value, str) or param is None or param.default is inspect.Parameter.empty:
            continue
        want = type(param.default)
        try:
            if want is bool:
                lowered = value.strip().lower()
                if lowered not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(value)
                out[key] = lowered in ("1", "true", "yes", "on")
            elif want in (int, float):
                out[key] = want(value)
        except ValueError:
            raise PluginError(f"{kind} {name!r} option {key}={value!r}: expected {want.__name__}") from None
    return out


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
        return cls(**coerce_options(cls, options, kind, name))
    except TypeError as exc:
        raise PluginError(f"{kind} {name!r} does not take these options: {exc}") from None
