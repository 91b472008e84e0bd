"""The work one batch item does: prune, convert or describe one splat file.

Each task is a plain function of (item, settings) that returns a JSON-ready result; it runs in a worker process (or a
Ray worker), so it takes and returns only picklable values. A failure of the item (a corrupt file, a bad option) is
caught here and becomes the item's error line; the other items go on.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Callable

from ..errors import ConfigError, RoodiError
from .items import Item
from .outputs import write_output

TASK_SUFFIX = {"prune": ".ply", "info": ".json"}
"""Default output extension per task (convert takes it from ``--to``)."""


def _read(path: str):
    from ..io.splat import read_cloud

    return read_cloud(path)


def _write(cloud, path: Path) -> None:
    """Write in the format of the path's extension (``.ply``, ``.compressed.ply``, ``.spz``)."""
    from ..io.splat import write_cloud

    write_cloud(cloud, path)


def prune_config(settings: dict[str, Any], options: dict[str, Any]):
    """Return the PruneConfig of an item: the batch's settings with the item's options over them.

    Raises:
        ConfigError: an option that is no pruning setting, or a value out of range.
    """
    from ..prune.outliers import PruneConfig

    known = {f.name for f in fields(PruneConfig)}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"unknown prune option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    merged = {**settings, **options}
    for name in ("box", "sphere"):
        if isinstance(merged.get(name), str):
            merged[name] = tuple(float(v) for v in merged[name].split(","))
        elif merged.get(name) is not None:
            merged[name] = tuple(merged[name])
    return PruneConfig(**merged)


def _prune(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    from ..prune.scene import prune_cloud

    config = prune_config(settings.get("prune", {}), item.options)
    cloud = _read(item.input)
    pruned, keep, report = prune_cloud(cloud, config)  # what `roodi-toolkit prune` runs
    write_output(item.output, lambda tmp: _write(pruned, tmp))
    return {"input_count": report.input_count, "kept": report.kept_count,
            "removed": report.input_count - report.kept_count, "mode": report.mode, "threshold": report.threshold}


def _convert(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    if item.options:
        raise ConfigError(f"convert takes no per-item options, got {', '.join(item.options)}")
    cloud = _read(item.input)
    write_output(item.output, lambda tmp: _write(cloud, tmp))
    return {"count": len(cloud), "sh_degree": cloud.sh_degree}


def _info(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    import json

    from ..stats import describe_cloud

    cloud = _read(item.input)
    stats = describe_cloud(cloud)
    if item.output is not None:
        write_output(item.output, lambda tmp: tmp.write_text(json.dumps(stats, indent=2, default=str) + "\n"))
    return {"count": stats["count"], "sh_degree": stats["sh_degree"], "nonfinite_rows": stats["nonfinite_rows"]}


_PREPARED: dict[tuple[str, str], Any] = {}
"""The scene a worker process has loaded (dataset, model, distillation), reused by its next object of that scene."""


def _extract(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    from ..pipeline.extract import extract_object, prepare_scene

    config = settings["config"]
    key = (item.input, settings["out"])
    if key not in _PREPARED:
        _PREPARED.clear()  # one scene held per worker
        # the shared stages are made by the batch before its items start: here they are only reused
        _PREPARED[key] = prepare_scene(item.input, settings["out"], model_dir=settings.get("model_dir"),
                                       distill_dir=settings.get("distill_dir"), config=config,
                                       replace_changed=settings.get("replace_changed", True))
    entry = extract_object(_PREPARED[key], int(item.options["object"]), config=config)
    return {k: entry[k] for k in ("gaussians", "gaussians_selected_and_pruned", "object_ply") if k in entry}


TASKS: dict[str, Callable[[Item, dict[str, Any]], dict[str, Any]]] = {
    "prune": _prune, "convert": _convert, "info": _info, "extract": _extract}


def run_item(task: str, item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    """Return the result line of one item; its own failure is caught and reported in the line, never raised."""
    t0 = time.perf_counter()
    line: dict[str, Any] = {"item": item.name, "input": item.input, "output": item.output}
    try:
        line.update(status="ok", **TASKS[task](item, settings))
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
