"""Fuzzing every reader: mutated PLY (binary, ASCII), compressed PLY, SPZ (v3, v4), .splat, .ksplat, SOG, COLMAP
binaries and Blender transforms JSON. Each mutated input must read, or fail with the toolkit's own error
(:class:`~roodi_toolkit.errors.RoodiError`, one line), within a time limit per case; any other exception or a hang
is a failure.

The default suite runs ``DEFAULT_CASES`` cases per reader; the standing figure (5,000 per reader, in
benchmarks/RESULTS.md) comes from the slow test::

    ROODI_FUZZ_CASES=5000 .venv/bin/python -m pytest -q -p no:cacheprovider -m slow -s tests/hostile/test_fuzz.py
"""

from __future__ import annotations

import io
import json
import os
import signal
import time
import zipfile
from collections import Counter
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from roodi_toolkit.errors import RoodiError
from tests.test_formats import encode_ksplat, encode_sog, encode_splat, encode_spz_v4, make_cloud

DEFAULT_CASES = 30
CASE_SECONDS = 5.0  # a reader that needs more than this on a file of a few KiB is hanging


class CaseTimeout(BaseException):
    """A case ran past :data:`CASE_SECONDS` (raised by SIGALRM, so no reader can catch it as an Exception)."""


def _alarm(signum: int, frame: object) -> None:
    raise CaseTimeout()


# ------------------------------------------------------------------------------------------------ the seeds
def _cloud_seeds(tmp: Path) -> dict[str, tuple[str, bytes]]:
    """reader name -> (file name, valid bytes) for every cloud format."""
    from roodi_toolkit.io.splat import write_cloud

    c = make_cloud(40, degree=1)
    seeds = {
        "ply": ("f.ply", Path(write_cloud(c, tmp / "seed.ply")).read_bytes()),
        "compressed_ply": ("f.compressed.ply", Path(write_cloud(c, tmp / "seed.compressed.ply")).read_bytes()),
        "spz": ("f.spz", Path(write_cloud(c, tmp / "seed.spz")).read_bytes()),
        "spz_v4": ("f.spz", encode_spz_v4(c)),
        "splat": ("f.splat", encode_splat(c)),
        "ksplat": ("f.ksplat", encode_ksplat(c, 1)),
    }
    # an ASCII PLY (the writer makes binary ones): the header our writer makes, the rows as text
    binary = seeds["ply"][1]
    end = binary.index(b"end_header\n") + len(b"end_header\n")
    header = binary[:end].replace(b"binary_little_endian", b"ascii")
    names = [line.split()[-1] for line in header.decode().splitlines() if line.startswith("property")]
    rows = np.frombuffer(binary[end:], dtype=np.float32).reshape(len(c), len(names))
    seeds["ply_ascii"] = ("f.ply", header + "\n".join(" ".join(f"{v:.6g}" for v in r) for r in rows).encode()
                          + b"\n")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in encode_sog(make_cloud(40)).items():
            z.writestr(name, data)
    seeds["sog"] = ("f.sog", buf.getvalue())
    return seeds


def _mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """Return (what was done, mutated bytes): flips, truncation, insertion, extreme words, duplicated slices."""
    buf = bytearray(data)
    kind = rng.integers(0, 6)
    hot = min(len(buf), 4096)  # headers, tables of contents and counts sit in the first KiB; corrupt them most
    if kind == 0 or len(buf) < 8:
        for pos in rng.integers(0, max(hot, 1), size=int(rng.integers(1, 9))):
            if buf:
                buf[pos] = int(rng.integers(0, 256))
        return "flip", bytes(buf)
    if kind == 1:
        return "truncate", bytes(buf[: int(rng.integers(0, len(buf)))])
    if kind == 2:
        pos = int(rng.integers(0, len(buf)))
        return "insert", bytes(buf[:pos] + bytes(rng.integers(0, 256, int(rng.integers(1, 64))).astype(np.uint8))
                                + buf[pos:])
    if kind == 3:  # a 4- or 8-byte word set to an extreme: counts of 2^32-1, NaN/inf floats, negative sizes
        width = int(rng.choice([4, 8]))
        pos = int(rng.integers(0, max(hot - width, 1)))
        word = [b"\xff" * width, b"\x00" * width, b"\x7f\xf0" + b"\x00" * (width - 2), b"\xff\xff\xff\x7f"[:width]
                .ljust(width, b"\x00"), b"\x00\x00\xc0\x7f"[:width].ljust(width, b"\x00")][int(rng.integers(0, 5))]
        buf[pos:pos + width] = word
        return "extreme word", bytes(buf)
    if kind == 4:
        a, b = sorted(int(x) for x in rng.integers(0, len(buf), 2))
        return "duplicate slice", bytes(buf[:b] + buf[a:b] + buf[b:])
    text = bytes(buf)
    for old, new in ((b"element vertex ", b"element vertex 9"), (b"float", b"double"), (b"uchar", b"int"),
                     (b"little", b"big"), (b"end_header", b"end_headr")):
        if old in text and rng.random() < 0.5:
            text = text.replace(old, new, 1)
    return "header edit", text


def _colmap_seed(tmp: Path) -> dict[str, bytes]:
    from roodi_toolkit.cameras import orbit_cameras
    from roodi_toolkit.io.colmap import ColmapPoints, colmap_model_from_cameras, write_colmap_model

    cams = orbit_cameras([0, 0, 0], 3.0, 3, width=16, height=12)
    rng = np.random.default_rng(0)
    points = ColmapPoints(ids=np.arange(1, 21), xyz=rng.normal(size=(20, 3)),
                          rgb=rng.integers(0, 256, (20, 3)).astype(np.uint8), errors=rng.random(20),
                          tracks=[np.array([[1, i], [2, i]], dtype=np.int64) for i in range(20)])
    model = colmap_model_from_cameras(cams, [f"v{i}.png" for i in range(3)], points)
    (tmp / "colmap_seed").mkdir()
    folder = write_colmap_model(model, tmp / "colmap_seed", binary=True)
    return {name: (Path(folder) / name).read_bytes() for name in ("cameras.bin", "images.bin", "points3D.bin")}


def _transforms_seed(tmp: Path) -> tuple[Path, dict]:
    from roodi_toolkit.cameras import orbit_cameras
    from roodi_toolkit.io.blender import write_blender_transforms
    from roodi_toolkit.io.files import write_image

    root = tmp / "blender_seed"
    (root / "train").mkdir(parents=True)
    cams = orbit_cameras([0, 0, 0], 3.0, 3, width=16, height=12)
    for i in range(3):
        write_image(np.zeros((12, 16, 3)), root / "train" / f"r_{i}.png")
    path = write_blender_transforms(root / "transforms_train.json", cams, [f"./train/r_{i}" for i in range(3)])
    return root, json.loads(Path(path).read_text())


_ODD_VALUES = [None, "", "x", -1, 0, 1e308, -1e308, float("nan"), float("inf"), [], {}, [[]], [1, 2], True,
               2 ** 63, "../../../etc/passwd", "\x00", [[0] * 4] * 4, [[float("nan")] * 4] * 4]


def _mutate_json(obj: object, rng: np.random.Generator) -> object:
    """Replace, delete or retype one value somewhere in a JSON document."""
    import copy

    doc = copy.deepcopy(obj)
    paths: list[tuple[object, object]] = []

    def walk(node: object) -> None:
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else []
        for key, child in list(items):
            paths.append((node, key))
            walk(child)

    walk(doc)
    if not paths:
        return _ODD_VALUES[int(rng.integers(0, len(_ODD_VALUES)))]
    for _ in range(int(rng.integers(1, 4))):
        parent, key = paths[int(rng.integers(0, len(paths)))]
        try:
            if rng.random() < 0.2 and isinstance(parent, dict):
                parent.pop(key, None)
            else:
                parent[key] = _ODD_VALUES[int(rng.integers(0, len(_ODD_VALUES)))]
        except (IndexError, KeyError):
            pass
    return doc


# ------------------------------------------------------------------------------------------------ the runs
def _run_cases(reader: str, n: int, tmp: Path, seed: int = 0) -> Counter:
    """Run ``n`` mutated inputs through ``reader``; return outcome counts; fail on anything but RoodiError."""
    from roodi_toolkit.io.colmap import load_colmap_cameras, read_colmap_model
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.io.splat import read_cloud

    rng = np.random.default_rng(seed)
    work = tmp / f"fuzz_{reader}"
    work.mkdir()
    cases: Callable[[int], tuple[str, Callable[[], object], Path]]
    if reader == "colmap":
        files = _colmap_seed(tmp)

        def cases(i: int) -> tuple[str, Callable[[], object], Path]:
            folder = work / f"c{i}"
            folder.mkdir()
            victim = list(files)[int(rng.integers(0, 3))]
            for name, data in files.items():
                what, out = _mutate(data, rng) if name == victim else ("", data)
                (folder / name).write_bytes(out)

            def read() -> object:
                read_colmap_model(folder)
                return load_colmap_cameras(folder)
            return f"{victim}: {what}", read, folder
    elif reader == "transforms_json":
        root, doc = _transforms_seed(tmp)

        def cases(i: int) -> tuple[str, Callable[[], object], Path]:
            path = root / f"transforms_c{i}.json"
            if rng.random() < 0.2:
                what, text = _mutate(json.dumps(doc).encode(), rng)
                path.write_bytes(text)
            else:
                what = "json value"
                path.write_text(json.dumps(_mutate_json(doc, rng)))
            return what, lambda: load_cameras(path), path
    else:
        name, data = _cloud_seeds(tmp)[reader]

        def cases(i: int) -> tuple[str, Callable[[], object], Path]:
            what, out = _mutate(data, rng)
            path = work / f"{i}_{name}"
            path.write_bytes(out)
            return what, lambda: read_cloud(path), path

    outcomes: Counter = Counter()
    failures: list[str] = []
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for i in range(n):
            what, read, path = cases(i)
            t = time.perf_counter()
            signal.setitimer(signal.ITIMER_REAL, CASE_SECONDS)
            try:
                read()
                outcomes["read"] += 1
            except RoodiError as exc:
                outcomes["toolkit error"] += 1
                if "\n" in str(exc) or not str(exc).strip():
                    failures.append(f"case {i} ({what}): not one line: {exc!r}")
            except CaseTimeout:
                outcomes["hang"] += 1
                failures.append(f"case {i} ({what}): no answer within {CASE_SECONDS} s ({path})")
            except Exception as exc:  # noqa: BLE001 - exactly what the fuzzer hunts
                outcomes["other exception"] += 1
                failures.append(f"case {i} ({what}): {type(exc).__name__}: {exc} ({path})")
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            outcomes["seconds"] += time.perf_counter() - t
    finally:
        signal.signal(signal.SIGALRM, previous)
    print(f"\nfuzz {reader}: {n} cases, {outcomes['read']} read, {outcomes['toolkit error']} toolkit errors, "
          f"{outcomes['other exception']} other exceptions, {outcomes['hang']} hangs, "
          f"{outcomes['seconds'] / max(n, 1) * 1000:.1f} ms per case")
    assert not failures, f"{len(failures)} of {n} {reader} cases escaped: " + "; ".join(failures[:5])
    return outcomes


READERS = ["ply", "ply_ascii", "compressed_ply", "spz", "spz_v4", "splat", "ksplat", "sog", "colmap",
           "transforms_json"]


@pytest.mark.parametrize("reader", READERS)
def test_fuzz_reader(reader: str, tmp_path: Path) -> None:
    outcomes = _run_cases(reader, int(os.environ.get("ROODI_FUZZ_CASES_DEFAULT", DEFAULT_CASES)), tmp_path, seed=1)
    assert outcomes["toolkit error"] > 0  # the mutations do break files: a fuzzer that never fails tests nothing


@pytest.mark.slow
@pytest.mark.parametrize("reader", READERS)
def test_fuzz_reader_many(reader: str, tmp_path: Path) -> None:
    _run_cases(reader, int(os.environ.get("ROODI_FUZZ_CASES", 5000)), tmp_path, seed=2)
