"""Stage records: the settings a finished stage was made with, and whether a re-run may reuse it.

Every stage folder holds the settings that made it (``scene/cfg.json``, ``distill/distill.json``,
``object_<ID>/stage.json``); a re-run reuses a finished stage only when the settings it would use now are the same,
and says which stages it reused and which it made again, and why (into ``report.json``).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

from ..errors import OutputError
from ..io.files import read_json
from ..io.generated import is_generated_scene, read_scene_record
from ..io.model import MODEL_RECORD, model_iterations


def settings(config: Any) -> Any:
    """Return settings as plain JSON values, the form stage records compare."""
    return json.loads(json.dumps(asdict(config) if hasattr(config, "__dataclass_fields__") else config, default=str))


class Stages:
    """Which finished stages a run reused and which it made again, and why (into the report).

    ``replace_changed``: a finished stage made with other settings is made again (the benchmark and batch re-runs);
    False (the ``extract`` command): it is refused, since that would replace an output without ``--overwrite``.
    """

    def __init__(self, report: dict[str, Any], replace_changed: bool = True) -> None:
        self.reused: list[str] = report.setdefault("reused", [])
        self.remade: list[str] = report.setdefault("recomputed", [])
        self.replace_changed = replace_changed

    def fresh(self, name: str, record: dict[str, Any] | None, wanted: dict[str, Any], overwrite: bool,
              where: Path | None = None) -> bool:
        """Return True if the stage's earlier result can be reused (same settings, no ``overwrite``).

        Raises:
            OutputError: other settings, neither ``overwrite`` nor ``replace_changed`` (``where``: the stage's folder).
        """
        if record is None:
            return False
        if overwrite:
            self.remade.append(f"{name} (--overwrite)")
            return False
        changed = sorted(k for k in set(wanted) | set(record) if k in wanted and record.get(k) != wanted[k])
        if changed:
            if not self.replace_changed:
                raise changed_error(where, name, changed)
            self.remade.append(f"{name} ({', '.join(changed)} changed)")
            return False
        self.reused.append(name)
        return True


def changed_error(where: Path | None, name: str, changed: Sequence[str]) -> OutputError:
    """Return the refusal to replace a finished stage made with other settings (it says how to go on)."""
    out = where.parent if where is not None else Path("OUT_DIR")
    return OutputError(f"{where or name}: the {name} there was made with other settings ({', '.join(changed)} "
                       f"changed) and would be replaced; give --overwrite to make every stage again, or another "
                       f"OUT_DIR (with --model {out / 'scene'} --distill {out / 'distill'} it reuses this run's scene)")


def read_record(path: Path, what: str) -> Any:
    """Return the JSON record at ``path``, None where there is none."""
    return read_json(path, what) if path.is_file() else None


def train_record(model_root: Path) -> dict[str, Any] | None:
    """Return the finished training run's record in ``model_root`` (None while unfinished or absent)."""
    record = read_record(model_root / MODEL_RECORD, "training record")
    if not isinstance(record, dict) or int(record.get("iterations", -1)) not in model_iterations(model_root):
        return None
    return record


def scene_labels(data_dir: str | Path) -> dict[int, str]:
    """Return object names by id from a generated scene's ``scene.json`` (empty for other datasets)."""
    if not is_generated_scene(data_dir):
        return {}
    record = read_scene_record(data_dir)
    try:
        return {0: "background", **{int(o["id"]): str(o["name"]) for o in record.get("objects", [])}}
    except (KeyError, TypeError, ValueError, AttributeError):
        return {}
