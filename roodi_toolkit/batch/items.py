"""What a batch works on: items (input, output, per-item options) from a folder, a glob or a manifest.

A manifest is CSV (a header with ``input`` and optionally ``output`` and option columns) or JSON lines (one object a
line with ``input``, optionally ``output`` and ``options``). Relative paths in a manifest are relative to the
manifest's folder. Items from a folder or a glob keep their path relative to the folder (or to the glob's fixed
part) under the output root, with the output's extension.
"""

from __future__ import annotations

import csv
import glob
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ..errors import ConfigError, InputError, OutputError
from ..io.files import parse_json

SPLAT_SUFFIXES = (".compressed.ply", ".ply", ".spz", ".splat", ".ksplat", ".sog")
"""File names a folder is searched for (besides ``meta.json`` of an unpacked SOG)."""

MANIFEST_SUFFIXES = (".csv", ".jsonl", ".ndjson")


@dataclass(frozen=True)
class Item:
    """One unit of batch work.

    Attributes:
        name: a short unique name (the input's path relative to the source), used in the results.
        input: the input file or folder.
        output: where the result goes: a local path or an fsspec URL (None: the task writes no file, e.g. ``info``).
        options: per-item settings that override the batch's (e.g. ``{"k": 32}`` for prune).
        replace: whether the item may replace a file at its output (``--overwrite``, or an output an earlier run of
            the batch wrote, as its results file records); otherwise a file there is left alone and the item fails.
    """

    name: str
    input: str
    output: str | None
    options: dict[str, Any] = field(default_factory=dict)
    replace: bool = False


def _splat_files(folder: Path) -> list[Path]:
    found = []
    for p in sorted(folder.rglob("*")):
        if p.is_file() and (p.name.lower().endswith(SPLAT_SUFFIXES) or p.name == "meta.json"):
            found.append(p)
    return found


def _strip_suffix(name: str) -> str:
    low = name.lower()
    for suffix in SPLAT_SUFFIXES + (".json",):
        if low.endswith(suffix):
            return name[: -len(suffix)]
    return name


def join_output(root: str, relative: str) -> str:
    """Return ``relative`` under the output root, a local folder or an fsspec URL (``s3://bucket/prefix``)."""
    if "://" in root:
        return root.rstrip("/") + "/" + relative.replace(os.sep, "/")
    return str(Path(root) / relative)


def collect_items(source: str, out_root: str | None, *, suffix: str | None) -> list[Item]:
    """Return the items of ``source``: a folder (every splat file in it, recursively), a glob pattern, or a manifest
    (``.csv``, ``.jsonl``). Outputs go under ``out_root`` with ``suffix`` as extension (None: no output file).

    Raises:
        InputError: the source is missing, matches nothing, or the manifest is malformed.
    """
    path = Path(source)
    if path.is_file() and path.name.lower().endswith(MANIFEST_SUFFIXES):
        return _manifest_items(path, out_root, suffix)
    if path.is_dir():
        files, base = _splat_files(path), path
    elif glob.has_magic(source):
        files = [Path(p) for p in sorted(glob.glob(source, recursive=True)) if Path(p).is_file()]
        fixed = source[: min(source.find(c) for c in "*?[" if c in source)]
        base = Path(fixed) if fixed.endswith(os.sep) else Path(fixed).parent
    elif path.is_file():
        files, base = [path], path.parent
    else:
        raise InputError(f"{source}: no such folder, file, glob or manifest")
    if not files:
        raise InputError(f"{source}: no splat files found (looked for {', '.join(SPLAT_SUFFIXES)} and meta.json)")
    items = []
    for f in files:
        rel = f.relative_to(base).as_posix() if f.is_relative_to(base) else f.name
        stem = rel if f.name != "meta.json" else rel.rsplit("/", 1)[0] if "/" in rel else "meta"
        out = None if suffix is None or out_root is None else join_output(out_root, _strip_suffix(stem) + suffix)
        items.append(Item(rel, str(f), out))
    return _unique(items)


def _manifest_items(path: Path, out_root: str | None, suffix: str | None) -> list[Item]:
    rows: list[dict[str, Any]] = []
    try:
        text = path.read_text(encoding="utf-8-sig")  # a spreadsheet's CSV often starts with a byte-order mark
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read manifest ({exc})") from None
    if "\0" in text:
        raise InputError(f"{path}: holds NUL bytes: not a text manifest")
    if path.suffix.lower() == ".csv":
        reader = csv.reader(text.splitlines())
        try:
            header = [h.strip() for h in next(reader, [])]
            if "input" not in header:
                raise InputError(f"{path}: a CSV manifest needs a header with an 'input' column")
            twice = sorted({h for h in header if header.count(h) > 1})
            if twice:
                raise InputError(f"{path}: the header names the column(s) {', '.join(map(repr, twice))} more than once")
            for cells in reader:
                if not any(c.strip() for c in cells):
                    continue
                number = reader.line_num
                if len(cells) > len(header):
                    raise InputError(f"{path}:{number}: {len(cells)} cells, the header names {len(header)} columns")
                row = dict(zip(header, cells))
                if not row.get("input", "").strip():
                    raise InputError(f"{path}:{number}: the 'input' cell is empty")
                options = {k: _scalar(v) for k, v in row.items() if k not in ("input", "output") and v != ""}
                rows.append({"input": row["input"], "output": row.get("output") or None, "options": options})
        except csv.Error as exc:
            raise InputError(f"{path}:{reader.line_num}: malformed CSV ({exc})") from None
    else:
        for number, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            row = parse_json(line, f"{path}:{number}", "manifest line")
            if not isinstance(row, dict) or not isinstance(row.get("input"), str) or not row["input"].strip():
                raise InputError(f"{path}:{number}: each line needs an 'input' string")
            if row.get("output") is not None and not isinstance(row["output"], str):
                raise InputError(f"{path}:{number}: 'output' must be a string (or left out), got {row['output']!r}")
            options = row.get("options", {})
            if not isinstance(options, dict):
                raise InputError(f"{path}:{number}: 'options' must be an object")
            rows.append({"input": row["input"], "output": row.get("output"), "options": options})
    if not rows:
        raise InputError(f"{path}: the manifest lists no items")
    items = []
    for row in rows:
        inp = Path(row["input"])
        inp = inp if inp.is_absolute() else path.parent / inp
        output = row["output"]
        if output is not None and "://" not in output and not Path(output).is_absolute():
            output = str(path.parent / output)
        if output is None and suffix is not None and out_root is not None:
            output = join_output(out_root, _strip_suffix(Path(row["input"]).as_posix()) + suffix)
        items.append(Item(row["input"], str(inp), output, dict(row["options"])))
    return _unique(items)


def _scalar(text: str) -> Any:
    """Return a CSV cell as the number or boolean it spells, else the text."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _file_key(path: str) -> tuple[int, int] | str:
    """The identity of a local file: (device, inode) when it exists (hard and symbolic links agree), else its
    resolved path (``./o.ply`` and ``o.ply`` agree)."""
    try:
        st = os.stat(path)
    except OSError:
        return os.path.realpath(path)
    return (st.st_dev, st.st_ino)


def _unique(items: Sequence[Item]) -> list[Item]:
    """Refuse two items that write one file, or an item that writes over an item's input (a manifest's ``output``
    column may name any file): compared as files, not spellings."""
    inputs = {_file_key(item.input): item.name for item in items}
    seen: dict[Any, str] = {}
    for item in items:
        if item.output is None:
            continue
        key = item.output if "://" in item.output else _file_key(item.output)
        if key in inputs:
            raise OutputError(f"{item.output}: the output of item {item.name} is the input of item {inputs[key]}; "
                              "inputs are never written, give another output")
        if key in seen:
            raise ConfigError(f"items {seen[key]} and {item.name} would both write {item.output}; give "
                              "their outputs in a manifest")
        seen[key] = item.name
    names = [i.name for i in items]
    if len(set(names)) != len(names):
        raise ConfigError("two items have the same name; give distinct inputs")
    return list(items)
