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
