"""Generated benchmark scenes on disk: the ``scene.json`` record that ``roodi-toolkit make-scene`` writes.

A generated scene is a Blender dataset (read by :mod:`roodi_toolkit.io.blender`) plus ``scene.json``: the objects
with their ids and names, the extraction targets and the folders of their object-alone views, the lights and the
generator settings (:func:`roodi_toolkit.synth.scene.make_scene` writes it; ``scene_from_record`` rebuilds the scene).

Example:
    >>> is_generated_scene("no/such/folder")
    False
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..errors import DatasetError, RoodiError
from .files import read_json

__all__ = ["SCENE_FILE", "SCENE_FORMAT", "SCENE_FORMAT_VERSION", "is_generated_scene", "read_scene_record"]

SCENE_FILE = "scene.json"
SCENE_FORMAT = "roodi-toolkit-scene"
SCENE_FORMAT_VERSION = 1


def is_generated_scene(data_dir: str | os.PathLike) -> bool:
    """Return whether ``data_dir`` holds a ``scene.json`` (a scene made by ``roodi-toolkit make-scene``)."""
    return (Path(data_dir) / SCENE_FILE).is_file()


def read_scene_record(data_dir: str | os.PathLike) -> dict[str, Any]:
    """Return the ``scene.json`` record of a generated scene folder.

    Raises:
        DatasetError: the file is missing, unreadable, or not a JSON object.
    """
    path = Path(data_dir) / SCENE_FILE
    try:
        record = read_json(path, "scene.json (made by roodi-toolkit make-scene)")
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None
    if not isinstance(record, dict):
        raise DatasetError(f"{path}: expected a JSON object (a scene record made by roodi-toolkit make-scene)")
    return record
