"""The work one batch item does: prune, convert or describe one splat file.

Each task is a plain function of (item, settings) that returns a JSON-ready result; it runs in a worker process (or a
Ray worker), so it takes and returns only picklable values. A failure of the item (a corrupt file, a bad option) is
caught here and becomes the item's error line; the other items go on.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import time
import traceback
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Callable, Sequence

from ..errors import ConfigError, RoodiError
from ..io.files import json_text
from ..io.splat import read_cloud, write_cloud
from ..prune.outliers import PruneConfig
from ..prune.scene import prune_cloud
from ..settings import declared, parse_text
from ..stats import describe_cloud
from .items import Item
from .outputs import file_id, write_output

TASK_SUFFIX = {"prune": ".ply", "info": ".json"}
"""Default output extension per task (convert takes it from ``--to``)."""


def _read(path: str):
    return read_cloud(path)


def _write(cloud, path: Path) -> None:
    """Write in the format of the path's extension (``.ply``, ``.compressed.ply``, ``.spz``)."""
    write_cloud(cloud, path)


def _coerce(d: Declared, value: Any) -> Any:
    """Return an item option's value as its setting ``d`` declares it (the field's type; a fixed tuple and each entry
    of a repeatable one also as the command line writes them, ``a,b,c``), or raise ConfigError naming the option.
    Ranges and choices are checked by the config itself."""
    name = d.name
    if value is None and d.optional:
        return None
    if d.kind is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"option {name}: expected true or false, got {value!r}")
    if d.kind in (int, float):
        number = value
        if isinstance(value, str):
            try:
                number = float(value.strip())
            except ValueError:
                number = None
        if isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number):
            what = "a whole number" if d.kind is int else "a finite number"
            raise ConfigError(f"option {name}: expected {what}, got {value!r}")
        if d.kind is int:
            if number != int(number):
                raise ConfigError(f"option {name}: expected a whole number, got {value!r}")
            return int(number)
        return float(number)
    if d.kind is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"option {name}: expected text, got {value!r}")
    try:
        if d.repeated:  # entries as the command line writes them (a CSV cell: ';' between), or a JSON list
            if isinstance(value, str):
                return tuple(parse_text(d, part) for part in value.split(";") if part.strip())
            if not isinstance(value, (list, tuple)):
                raise ValueError(f"expected a list of entries, got {value!r}")
            return tuple(parse_text(d, v) if isinstance(v, str) else _entry(v) for v in value)
        if isinstance(value, str):
            return parse_text(d, value)
        numbers = tuple(float(v) for v in value)
        if len(numbers) != d.size or not all(math.isfinite(v) for v in numbers):
            raise ValueError(f"expected {d.size} finite numbers, got {value!r}")
        return numbers
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"option {name}: {exc}") from None


def _entry(value: Any) -> tuple[str, float, float]:
    """Return a ``[name, low, high]`` entry of a repeatable setting given as a list (a JSON manifest's form)."""
    name, low, high = value
    return str(name), float(low), float(high)


def prune_config(settings: dict[str, Any], options: dict[str, Any]):
    """Return the PruneConfig of an item: the batch's settings with the item's options over them.

    Raises:
        ConfigError: an option that is no pruning setting, a value of the wrong type, or out of range.
    """
    known = {f.name for f in fields(PruneConfig)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"unknown prune option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    declarations = {d.name: d for d in declared(PruneConfig)}
    merged = {**settings, **{k: _coerce(declarations[k], v) for k, v in options.items()}}
    for name, value in merged.items():  # the batch's own settings as JSON carries them to the workers: lists
        d = declarations.get(name)
        if d is not None and d.kind is tuple and isinstance(value, (str, list)):
            merged[name] = _coerce(d, value)
    try:
        return PruneConfig(**merged)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConfigError(f"prune options {options}: {exc}") from None


def check_items(task: str, items: Sequence[Item], settings: dict[str, Any], where: str) -> None:
    """Refuse, before any work, an item whose options the task cannot take (``k=abc``, an unknown option, options
    given to ``convert``): the manifest ``where`` is wrong, not one item's file.

    Raises:
        ConfigError: naming the manifest, the item and the option.
    """
    for item in items:
        try:
            if task == "prune":
                prune_config(settings.get("prune", {}), item.options)
            elif task in ("convert", "info") and item.options:
                raise ConfigError(f"{task} takes no per-item options, got {', '.join(map(str, item.options))}")
        except ConfigError as exc:
            raise ConfigError(f"{where}: item {item.name}: {exc}") from None


def _recorder(item: Item, settings: dict[str, Any]) -> Callable[[Path], None] | None:
    """Return the callback that notes a finished output's identity in the results file before it is put in place
    (a local pool's worker only), so that a batch killed between the two still knows the output as its own."""
    record = settings.get("_record")
    if not record:
        return None

    def ready(tmp: Path) -> None:
        line = {"item": item.name, "output": item.output, "status": "writing", "output_id": file_id(tmp)}
        fd = os.open(record, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            os.write(fd, (json.dumps(line) + "\n").encode())
            os.fsync(fd)
        finally:
            os.close(fd)

    return ready


def _prune(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    config = prune_config(settings.get("prune", {}), item.options)
    cloud = _read(item.input)
    pruned, keep, report = prune_cloud(cloud, config)  # what `roodi-toolkit prune` runs
    write_output(item.output, lambda tmp: _write(pruned, tmp), replace=item.replace, ready=_recorder(item, settings))
    return {"input_count": report.input_count, "kept": report.kept_count,
            "removed": report.input_count - report.kept_count, "mode": report.mode, "threshold": report.threshold}


def _convert(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    if item.options:
        raise ConfigError(f"convert takes no per-item options, got {', '.join(map(str, item.options))}")
    cloud = _read(item.input)
    write_output(item.output, lambda tmp: _write(cloud, tmp), replace=item.replace, ready=_recorder(item, settings))
    return {"count": len(cloud), "sh_degree": cloud.sh_degree}


def _info(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    cloud = _read(item.input)
    stats = describe_cloud(cloud)
    if item.output is not None:
        write_output(item.output, lambda tmp: tmp.write_text(json_text(stats, indent=2) + "\n"), replace=item.replace,
                     ready=_recorder(item, settings))
    return {"count": stats["count"], "sh_degree": stats["sh_degree"], "nonfinite_rows": stats["nonfinite_rows"]}


TASKS: dict[str, Callable[[Item, dict[str, Any]], dict[str, Any]] | str] = {
    "prune": _prune, "convert": _convert, "info": _info,
    # the whole pipeline (torch): imported when an extract item runs, so a batch of splat files starts light
    "extract": "roodi_toolkit.batch.extract_task:extract_item"}


def task_function(task: str) -> Callable[[Item, dict[str, Any]], dict[str, Any]]:
    """Return the function that runs one item of ``task`` (importing its module where :data:`TASKS` names it)."""
    function = TASKS[task]
    if isinstance(function, str):
        module, attr = function.split(":")
        function = getattr(importlib.import_module(module), attr)
    return function


def run_item(task: str, item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    """Return the result line of one item; its own failure is caught and reported in the line, never raised."""
    t0 = time.perf_counter()
    line: dict[str, Any] = {"item": item.name, "input": item.input, "output": item.output}
    try:
        line.update(status="ok", **task_function(task)(item, settings))
        if item.output is not None and "://" not in item.output and task != "extract":
            line["output_id"] = file_id(item.output)  # what a later run recognises as its own output
    except RoodiError as exc:
        line.update(status="failed", error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    except MemoryError:
        line.update(status="failed", error="out of memory")
    except Exception as exc:  # noqa: BLE001 - one broken item must not stop the batch; its line says what broke
        where = traceback.extract_tb(exc.__traceback__)[-1]
        line.update(status="failed", error=f"unexpected {type(exc).__name__}: {exc} "
                                           f"({Path(where.filename).name}:{where.lineno}); please report it")
    line["seconds"] = time.perf_counter() - t0
    line["pid"] = os.getpid()
    return line


def settings_for(task: str, **values: Any) -> dict[str, Any]:
    """Return a task's JSON-ready settings (``prune``: a PruneConfig's fields)."""
    if task == "prune":
        config = values.get("prune_config")
        return {"prune": {k: v for k, v in asdict(config).items()} if config is not None else {}}
    return dict(values)
