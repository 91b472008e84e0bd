"""The ``extract`` task of a batch: one object of a scene a worker has loaded (its own module: it imports the
pipeline, which the tasks on splat files never need)."""

from __future__ import annotations

from typing import Any

from ..run.extract import extract_object, prepare_scene
from .items import Item

_PREPARED: dict[tuple[str, str], Any] = {}
"""The scene a worker process has loaded (dataset, model, distillation), reused by its next object of that scene."""


def extract_item(item: Item, settings: dict[str, Any]) -> dict[str, Any]:
    """Extract the object ``item.options["object"]`` of the scene ``item.input`` into ``settings["out"]``; return its
    counts and PLY."""
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
