"""A model folder's record, read without its data: this toolkit's ``cfg.json`` (``roodi-toolkit train`` writes it)
or an Inria output's ``cfg_args`` (with its ``cameras.json``). :func:`roodi_toolkit.io.model.open_model` checks the
record against the data; reading it here needs neither torch nor the dataset readers (the prune's photo check asks
where a model's photos are before loading any)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .files import read_json
from .other_models import INRIA_ARGS, INRIA_CAMERAS, inria_settings, load_inria_cameras, read_cfg_args

MODEL_RECORD = "cfg.json"


def model_record(root: str | Path) -> tuple[dict[str, Any], Path | None]:
    """Return a model folder's record in this toolkit's keys and the data folder it names (None if it names none),
    reading only the record: ``cfg.json``, or an Inria folder's ``cfg_args`` (its ``cameras.json`` gives the photos'
    width for its resolution). Nothing is checked against the data (:func:`open_model` does that).

    Raises:
        InputError: an unreadable record.
    """
    root = Path(root)
    if (root / MODEL_RECORD).is_file() or not (root / INRIA_ARGS).is_file():
        record = read_json(root / MODEL_RECORD, "training record")
        record = record if isinstance(record, dict) else {}
        value = record.get("data_dir")
    else:
        args = read_cfg_args(root / INRIA_ARGS)
        width = None
        if (root / INRIA_CAMERAS).is_file():
            width = max(c.width for c in load_inria_cameras(root / INRIA_CAMERAS))
        value = args.get("source_path")
        record = inria_settings(root, args, width)
    if not value:
        return record, None
    data = Path(str(value))
    for cand in (data, root / data):
        if cand.exists():
            return record, cand
    return record, data
