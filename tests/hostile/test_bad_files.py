"""Bad files of every format, fed to every command that reads a cloud: exit 1, one line naming the file, inputs
untouched, no output left behind."""

from __future__ import annotations

import gzip
import io
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from .conftest import expect_failure


def _ply_header(n: int, props: str = "x y z", fmt: str = "binary_little_endian") -> bytes:
    lines = ["ply", f"format {fmt} 1.0", f"element vertex {n}"] + [f"property float {p}" for p in props.split()]
    return ("\n".join(lines + ["end_header"]) + "\n").encode()


GS_PROPS = "x y z f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3"


def _noise(n: int) -> bytes:
    """``n`` reproducible noise bytes (a case must not pass or fail by chance)."""
    return np.random.default_rng(n).bytes(n)


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


# name -> (file name, bytes); every one must be refused by every reader with one line naming it
BAD_FILES: dict[str, tuple[str, Callable[[Path], bytes]]] = {
    "empty": ("empty.ply", lambda w: b""),
    "random bytes": ("noise.ply", lambda w: _noise(997)),
    "text": ("notes.ply", lambda w: b"hello, I am not a splat\n" * 20),
    "header only": ("header.ply", lambda w: _ply_header(10, GS_PROPS)),
    "no end_header": ("open.ply", lambda w: _ply_header(10, GS_PROPS).replace(b"end_header\n", b"")),
    "count larger than data": ("short.ply", lambda w: _ply_header(1000, GS_PROPS) + b"\x00" * 56 * 3),
    "absurd count": ("huge.ply", lambda w: _ply_header(10 ** 15, GS_PROPS) + b"\x00" * 56),
    "negative count": ("neg.ply", lambda w: _ply_header(-5, GS_PROPS)),
    "missing properties": ("xyz.ply", lambda w: _ply_header(2, "x y z") + b"\x00" * 24),
    "ascii garbage rows": ("ascii.ply", lambda w: _ply_header(2, GS_PROPS, "ascii") + b"a b c\n1 2\n"),
    "unknown encoding": ("enc.ply", lambda w: _ply_header(2, GS_PROPS, "binary_middle_endian") + b"\x00" * 112),
    "truncated PLY": ("trunc.ply", lambda w: w.ply.read_bytes()[: w.ply.stat().st_size * 2 // 3]),
    "truncated SPZ": ("trunc.spz", lambda w: w.spz.read_bytes()[: w.spz.stat().st_size // 2]),
    "gzip of garbage": ("garbage.spz", lambda w: gzip.compress(_noise(300))),
    "corrupt gzip": ("broken.spz", lambda w: b"\x1f\x8b" + _noise(200)),
    "truncated compressed PLY": ("trunc.compressed.ply",
                                 lambda w: w.cply.read_bytes()[: w.cply.stat().st_size * 3 // 4]),
    ".splat of wrong length": ("odd.splat", lambda w: _noise(32 * 5 + 7)),
    "empty .splat": ("nothing.splat", lambda w: b""),
    # a ksplat with every header field 0xff (random bytes may be a headerless .splat: 32 bytes a Gaussian)
    ".ksplat garbage": ("junk.ksplat", lambda w: b"\xff" * 4096),
    "zip without meta.json": ("nometa.sog", lambda w: _zip({"a.txt": b"x"})),
    "SOG meta not JSON": ("badmeta.sog", lambda w: _zip({"meta.json": b"{not json"})),
    "SOG without textures": ("notex.sog", lambda w: _zip({"meta.json": b'{"version": 2, "count": 5, "means": '
                                                          b'{"mins": [0,0,0], "maxs": [1,1,1], "files": ["m.webp"]}}'})),
    "corrupt zip": ("corrupt.sog", lambda w: b"PK\x03\x04" + _noise(300)),
    "unknown extension": ("cloud.xyz", lambda w: w.ply.read_bytes()[:100]),
}


def _args(command: str, f: Path, out: Path, w) -> list:
    return {
        "info": ["info", f],
        "convert": ["convert", f, out / "o.spz"],
        "prune": ["prune", f, out / "o.ply", "-q"],
        "render": ["render", f, out / "r", "--orbit", "1", "--size", "8x8", "-q"],
        "inspect": ["inspect", f, "--histogram", out / "h.png", "-q"],
        "evaluate": ["evaluate", f, w.gen, "--object", "1", "-q"],
    }[command]


COMMANDS = ["info", "convert", "prune", "render", "inspect", "evaluate"]


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("bad", list(BAD_FILES))
def test_bad_file_is_refused_naming_it(bad: str, command: str, world, run_cli, tmp_path: Path) -> None:
    name, make = BAD_FILES[bad]
    f = tmp_path / "in" / name
    f.parent.mkdir()
    f.write_bytes(make(world))
    before = f.read_bytes()
    out = tmp_path / "out"
    out.mkdir()
    res = run_cli(*_args(command, f, out, world))
    expect_failure(res, 1, name)
    assert f.read_bytes() == before
    assert list(out.iterdir()) == []  # nothing written, not even a hidden temporary file
    assert world.unchanged()


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("kind", ["missing", "folder", "dangling link", "link loop"])
def test_no_file_is_refused_naming_it(kind: str, command: str, world, run_cli, tmp_path: Path) -> None:
    f = tmp_path / "thing.ply"
    if kind == "folder":
        f.mkdir()
    elif kind == "dangling link":
        f.symlink_to(tmp_path / "nowhere.ply")
    elif kind == "link loop":
        f.symlink_to(tmp_path / "loop2.ply")
        (tmp_path / "loop2.ply").symlink_to(f)
    out = tmp_path / "out"
    out.mkdir()
    res = run_cli(*_args(command, f, out, world))
    expect_failure(res, 1, "thing.ply")  # render reads a SOG folder, so a folder is no usage error there either
    assert list(out.iterdir()) == []


# ------------------------------------------------------------------------------- models and captures of other tools
def _inria(w, tmp: Path, cfg_args: bytes | None = None, cameras: bytes | None = None) -> Path:
    """An Inria output folder of the world's model trained on the world's data (its files replaceable)."""
    import json
    import shutil

    from roodi_toolkit.io.dataset import load_cameras

    root = tmp / "inria"
    (root / "point_cloud" / "iteration_7").mkdir(parents=True)
    shutil.copy(w.model / "point_cloud" / "iteration_7" / "point_cloud.ply", root / "point_cloud" / "iteration_7")
    (root / "cfg_args").write_bytes(cfg_args if cfg_args is not None else
                                    f"Namespace(source_path={str(w.data)!r}, images='images', resolution=1, "
                                    "eval=False, sh_degree=0)".encode())
    if cameras is None:
        entries = []
        for i, c in enumerate(load_cameras(w.data)):
            c2w = np.linalg.inv(c.world_to_camera)
            entries.append({"id": i, "img_name": c.name, "width": c.width, "height": c.height, "fx": c.K[0, 0],
                            "fy": c.K[1, 1], "position": (c2w[:3, 3] + 0.3).tolist(), "rotation": c2w[:3, :3].tolist()})
        cameras = json.dumps(entries).encode()
    (root / "cameras.json").write_bytes(cameras)
    return root


def _gsplat(w, tmp: Path, ckpt: bytes, cfg: bytes | None = None) -> Path:
    root = tmp / "gsplat"
    (root / "ckpts").mkdir(parents=True)
    (root / "ckpts" / "ckpt_7_rank0.pt").write_bytes(ckpt)
    (root / "cfg.yml").write_bytes(cfg if cfg is not None else f"data_dir: {w.data}\nnormalize_world_space: false\n"
                                   .encode())
    return root / "ckpts" / "ckpt_7_rank0.pt"


class _Code:
    def __reduce__(self):
        return (print, ("code ran",))


def _pickled_code() -> bytes:
    import torch

    buf = io.BytesIO()
    torch.save({"step": 7, "splats": {"means": torch.zeros(3, 3)}, "x": _Code()}, buf)
    return buf.getvalue()


# name -> (build the model in tmp, returning (path given as the model, extra arguments), the text that must be in the
# error line (the file at fault))
BAD_MODELS: dict[str, tuple[Callable, str]] = {
    "gsplat checkpoint of noise": (lambda w, t: (_gsplat(w, t, _noise(2000)), []), "ckpt_7_rank0.pt"),
    "gsplat checkpoint with pickled code": (lambda w, t: (_gsplat(w, t, _pickled_code()), []), "plain tensors"),
    "gsplat cfg.yml not YAML": (lambda w, t: (_gsplat(w, t, _pickled_code(), b"data_dir: [unclosed\n  - x: {"), []),
                                "cfg.yml"),
    "Inria cfg_args code": (lambda w, t: (_inria(w, t, b"Namespace(source_path=__import__('os').getcwd())"), []),
                            "cfg_args"),
    "Inria cameras.json of noise": (lambda w, t: (_inria(w, t, cameras=_noise(300)), []), "cameras.json"),
    "Inria cameras elsewhere": (lambda w, t: (_inria(w, t), []), "cameras.json"),
    "dataparser transforms not JSON": (lambda w, t: (w.ply, ["--dataparser-transforms", _write(t / "dp.json", b"{x")]),
                                       "dp.json"),
    "dataparser transforms mirrored": (lambda w, t: (w.ply, ["--dataparser-transforms", _write(
        t / "dp.json", b'{"transform": [[1,0,0,0],[0,1,0,0],[0,0,-1,0]], "scale": 1}')]), "dp.json"),
    "dataparser transforms scale 0": (lambda w, t: (w.ply, ["--dataparser-transforms", _write(
        t / "dp.json", b'{"transform": [[1,0,0,0],[0,1,0,0],[0,0,1,0]], "scale": 0}')]), "'scale'"),
}


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _model_args(command: str, model: Path, extra: list, w, out: Path) -> list:
    return {
        "extract": ["extract", w.data, out / "x", "--model", model, "--object", "1", *extra, "-q"],
        "distill": ["distill", model, w.data, out / "d", *extra, "-q"],
        "convert": ["convert", model, out / "o.ply", "--data", w.data, *extra],
    }[command]


@pytest.mark.parametrize("command", ["extract", "distill", "convert"])
@pytest.mark.parametrize("bad", list(BAD_MODELS))
def test_bad_model_is_refused_naming_its_file(bad: str, command: str, world, run_cli, tmp_path: Path,
                                              capsys) -> None:
    from tests.object_scene import tree_digest

    build, needle = BAD_MODELS[bad]
    (tmp_path / "in").mkdir()
    model, extra = build(world, tmp_path / "in")
    before = tree_digest(tmp_path / "in")
    out = tmp_path / "out"
    out.mkdir()
    res = run_cli(*_model_args(command, model, extra, world, out))
    expect_failure(res, 1, needle)
    assert "code ran" not in res.stdout
    assert tree_digest(tmp_path / "in") == before and world.unchanged()
    assert list(out.iterdir()) == []


def _capture(tmp: Path, edit: Callable[[dict], object]) -> Path:
    """A nerfstudio capture of 4 frames (per-frame intrinsics, masks, points) after ``edit`` of its transforms.json."""
    import json

    from tests.hostile.test_fuzz import _nerfstudio_seed

    root, doc = _nerfstudio_seed(tmp)
    edit(doc)
    (root / "transforms.json").write_text(json.dumps(doc))
    return root


BAD_CAPTURES: dict[str, tuple[Callable[[dict], object], str]] = {
    "no frames": (lambda d: d.pop("frames"), "'frames'"),
    "a frame without transform_matrix": (lambda d: d["frames"][1].pop("transform_matrix"), "'transform_matrix'"),
    "fl_x a word": (lambda d: d["frames"][0].update(fl_x="wide"), "'fl_x'"),
    "an unknown camera model": (lambda d: d["frames"][2].update(camera_model="EQUIRECTANGULAR"), "'camera_model'"),
    "every image missing": (lambda d: [f.update(file_path=f"gone/{i}.png") for i, f in enumerate(d["frames"])],
                            "0 frames with images"),
    "a mask missing": (lambda d: d["frames"][3].update(mask_path="masks/none.png"), "mask 'masks/none.png'"),
    "points not a PLY": (lambda d: d.update(ply_file_path="images/f0.png"), "f0.png: not a point cloud"),
    "a mirrored applied_transform": (lambda d: d.update(applied_transform=[[1, 0, 0, 0], [0, 1, 0, 0],
                                                                           [0, 0, -1, 0]]), "'applied_transform'"),
    "train_filenames naming nothing": (lambda d: d.update(train_filenames=["x.png"]), "'train_filenames'"),
}


CAMERAS_ONLY = ("no frames", "a frame without transform_matrix", "fl_x a word", "an unknown camera model",
                "every image missing")  # what render --cameras reads (not masks, points, the split)


@pytest.mark.parametrize("bad,command", [(b, "train") for b in BAD_CAPTURES] + [(b, "render") for b in CAMERAS_ONLY])
def test_bad_capture_is_refused_naming_file_and_field(bad: str, command: str, world, run_cli,
                                                      tmp_path: Path) -> None:
    from tests.object_scene import tree_digest

    edit, needle = BAD_CAPTURES[bad]
    capture = _capture(tmp_path / "in", edit)
    before = tree_digest(capture)
    out = tmp_path / "out"
    out.mkdir()
    args = (["train", capture, out / "m", "--iterations", "1", "-q"] if command == "train" else
            ["render", world.ply, out / "r", "--cameras", capture / "transforms.json", "-q"])
    res = run_cli(*args)
    expect_failure(res, 1, needle, "transforms.json")
    assert tree_digest(capture) == before and world.unchanged()
    assert list(out.iterdir()) == []
