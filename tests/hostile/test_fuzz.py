"""Fuzzing every reader: mutated PLY (binary, ASCII), compressed PLY, SPZ (v3, v4), .splat, .ksplat, SOG, COLMAP
binaries, Blender transforms JSON, nerfstudio / instant-ngp transforms.json (its images, masks and SfM points
read too), and the records of other tools' models: Inria cfg_args and cameras.json, gsplat checkpoints (bytes and
tensors) and cfg.yml, nerfstudio's dataparser_transforms.json. Each mutated input must read, or fail with the toolkit's own error
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
import shutil
import signal
import time
import warnings
import zipfile
from collections import Counter
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from roodi_toolkit.errors import RoodiError
from tests.io.test_formats import encode_ksplat, encode_sog, encode_splat, encode_spz_v4, make_cloud

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


def _nerfstudio_seed(tmp: Path) -> tuple[Path, dict]:
    """A small nerfstudio capture using every key the reader takes: per-frame intrinsics, a lens, masks, SfM points,
    split lists and applied_transform."""
    from roodi_toolkit.cameras import orbit_cameras, w2c_to_opengl_c2w
    from roodi_toolkit.io.files import write_image

    root = tmp / "ns_seed"
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    cams = orbit_cameras([0, 0, 0], 3.0, 4, width=16, height=12)
    frames = []
    for i, cam in enumerate(cams):
        write_image(np.full((12, 16, 3), 0.5), root / "images" / f"f{i}.png")
        write_image(np.full((12, 16), 255, np.uint8), root / "masks" / f"f{i}.png")
        frames.append({"file_path": f"images/f{i}", "transform_matrix": w2c_to_opengl_c2w(cam.world_to_camera).tolist(),
                       "fl_x": 14.0, "fl_y": 14.0, "cx": 8.0, "cy": 6.0, "w": 16, "h": 12, "mask_path": f"masks/f{i}.png",
                       "camera_model": "OPENCV", "k1": -0.05, "k2": 0.01, "p1": 0.0, "p2": 0.0})
    (root / "pc.ply").write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                                 "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                                 "end_header\n0 0 0 1 2 3\n0.1 0.2 0.3 4 5 6\n")
    doc = {"frames": frames, "ply_file_path": "pc.ply", "applied_transform": [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]],
           "train_filenames": ["images/f0.png", "images/f1.png", "images/f2.png"], "val_filenames": ["images/f3.png"]}
    return root, doc


def _other_model_seeds(tmp: Path) -> dict[str, bytes]:
    """Valid records of other tools' models: Inria cfg_args and cameras.json, a gsplat checkpoint and cfg.yml, a
    nerfstudio dataparser_transforms.json."""
    import torch

    from roodi_toolkit.cameras import orbit_cameras

    cams = orbit_cameras([0, 0, 0], 3.0, 3, width=16, height=12)
    entries = [{"id": i, "img_name": f"v{i}", "width": 16, "height": 12,
                "position": np.linalg.inv(c.world_to_camera)[:3, 3].tolist(),
                "rotation": np.linalg.inv(c.world_to_camera)[:3, :3].tolist(), "fy": c.K[1, 1], "fx": c.K[0, 0]}
               for i, c in enumerate(cams)]
    rng = np.random.default_rng(0)
    splats = {"means": torch.from_numpy(rng.normal(size=(30, 3)).astype(np.float32)),
              "quats": torch.from_numpy(rng.normal(size=(30, 4)).astype(np.float32)),
              "scales": torch.full((30, 3), -3.0), "opacities": torch.zeros(30), "sh0": torch.zeros(30, 1, 3),
              "shN": torch.zeros(30, 3, 3)}
    buf = io.BytesIO()
    torch.save({"step": 99, "splats": splats}, buf)
    return {
        "cfg_args": b"Namespace(data_device='cuda', eval=True, images='images', model_path='./output/x', "
                    b"resolution=-1, sh_degree=3, source_path='/data/x', white_background=False)",
        "inria_cameras": json.dumps(entries).encode(),
        "gsplat_ckpt": buf.getvalue(),
        "gsplat_cfg": b"data_dir: data/360_v2/garden\ndata_factor: 4\nnormalize_world_space: true\ntest_every: 8\n"
                      b"strategy: !!python/object:gsplat.strategy.default.DefaultStrategy\n  refine_every: 100\n"
                      b"ply_steps:\n- 7000\n- 30000\n",
        "dataparser_transforms": json.dumps({"transform": [[1, 0, 0, 0.1], [0, 0, 1, 0.2], [0, -1, 0, 0.3]],
                                             "scale": 0.25}).encode(),
    }


def _mutate_tensors(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """Return a gsplat checkpoint whose splats were changed in kind rather than in bytes: a tensor dropped, reshaped,
    retyped or filled with NaN, a wrong container."""
    import torch

    state = torch.load(io.BytesIO(data), weights_only=True)
    splats = state["splats"]
    name = list(splats)[int(rng.integers(0, len(splats)))]
    kind = int(rng.integers(0, 6))
    if kind == 0:
        del splats[name]
    elif kind == 1:
        splats[name] = splats[name].reshape(-1)[: max(1, splats[name].numel() // 2)]
    elif kind == 2:
        splats[name] = splats[name].to(torch.int64)
    elif kind == 3:
        splats[name] = torch.full_like(splats[name], float("nan"))
    elif kind == 4:
        splats[name] = [1, 2, 3]
    else:
        state = {"step": 1, "splats": [t for t in splats.values()]}
    buf = io.BytesIO()
    torch.save(state, buf)
    return f"tensor edit {kind} on {name}", buf.getvalue()


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
    elif reader == "nerfstudio_json":
        root, doc = _nerfstudio_seed(tmp)

        def cases(i: int) -> tuple[str, Callable[[], object], Path]:
            from roodi_toolkit.io.dataset import load_dataset

            path = root / f"c{i}.json"
            if rng.random() < 0.2:
                what, text = _mutate(json.dumps(doc).encode(), rng)
                path.write_bytes(text)
            else:
                what = "json value"
                path.write_text(json.dumps(_mutate_json(doc, rng)))

            def read() -> object:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # missing images are expected here; errors are what is checked
                    load_cameras(path)
                    return load_dataset(path, 2)
            return what, read, path
    elif reader in ("cfg_args", "inria_cameras", "gsplat_ckpt", "gsplat_cfg", "dataparser_transforms"):
        from roodi_toolkit.cameras import orbit_cameras
        from roodi_toolkit.io import gsplat, other_models as om

        data = _other_model_seeds(tmp)[reader]
        data_cams = [c.__class__(c.world_to_camera, c.K, c.width, c.height, name=f"v{i}")
                     for i, c in enumerate(orbit_cameras([0, 0, 0], 3.0, 3, width=16, height=12))]

        def cases(i: int) -> tuple[str, Callable[[], object], Path]:
            folder = work / f"c{i}"
            folder.mkdir()
            if reader in ("inria_cameras", "dataparser_transforms") and rng.random() >= 0.2:
                what, out = "json value", json.dumps(_mutate_json(json.loads(data), rng)).encode()
            elif reader == "gsplat_ckpt" and rng.random() < 0.4:
                what, out = _mutate_tensors(data, rng)
            else:
                what, out = _mutate(data, rng)
            name = {"cfg_args": "cfg_args", "inria_cameras": "cameras.json", "gsplat_ckpt": "ckpt_99_rank0.pt",
                    "gsplat_cfg": "cfg.yml", "dataparser_transforms": "dataparser_transforms.json"}[reader]
            path = folder / name
            path.write_bytes(out)

            def read() -> object:
                if reader == "cfg_args":
                    return om.inria_settings(folder, om.read_cfg_args(path), 1000)
                if reader == "inria_cameras":
                    return om.check_inria_cameras(path, data_cams, folder)
                if reader == "gsplat_ckpt":
                    return gsplat.read_gsplat_checkpoint([path])
                if reader == "gsplat_cfg":
                    return gsplat.gsplat_settings(gsplat.read_gsplat_config(folder), path)
                return om.read_dataparser_transforms(path)
            return what, read, folder
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
            escaped = len(failures)
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
            if len(failures) == escaped and path.is_dir():  # only the cases that escaped stay on disk (5,000 a
                shutil.rmtree(path)                              # reader kept 20-80 MB)
            elif len(failures) == escaped:
                path.unlink(missing_ok=True)
    finally:
        signal.signal(signal.SIGALRM, previous)
    print(f"\nfuzz {reader}: {n} cases, {outcomes['read']} read, {outcomes['toolkit error']} toolkit errors, "
          f"{outcomes['other exception']} other exceptions, {outcomes['hang']} hangs, "
          f"{outcomes['seconds'] / max(n, 1) * 1000:.1f} ms per case")
    assert not failures, f"{len(failures)} of {n} {reader} cases escaped: " + "; ".join(failures[:5])
    return outcomes


READERS = ["ply", "ply_ascii", "compressed_ply", "spz", "spz_v4", "splat", "ksplat", "sog", "colmap",
           "transforms_json", "nerfstudio_json", "cfg_args", "inria_cameras", "gsplat_ckpt", "gsplat_cfg",
           "dataparser_transforms"]


@pytest.mark.parametrize("reader", READERS)
def test_fuzz_reader(reader: str, tmp_path: Path) -> None:
    outcomes = _run_cases(reader, int(os.environ.get("ROODI_FUZZ_CASES_DEFAULT", DEFAULT_CASES)), tmp_path, seed=1)
    assert outcomes["toolkit error"] > 0  # the mutations do break files: a fuzzer that never fails tests nothing


@pytest.mark.slow
@pytest.mark.parametrize("reader", READERS)
def test_fuzz_reader_many(reader: str, tmp_path: Path) -> None:
    _run_cases(reader, int(os.environ.get("ROODI_FUZZ_CASES", 5000)), tmp_path, seed=2)
