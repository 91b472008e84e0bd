"""Gigabytes from kilobytes: compressed streams and image headers that claim far more than their count or their
memory justifies. Nothing is inflated or decoded past what the header's count needs; a size that does not fit in
memory is refused in one line naming the file or option; dataset photos are decoded at their stored size and reduced
a strip at a time (never as full-size floats); Pillow's decompression-bomb warning never reaches stderr."""

from __future__ import annotations

import gzip
import io
import json
import os
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from .conftest import expect_failure

ROOT = Path(__file__).resolve().parents[2]

# A lossless WebP of 16383x10923 black pixels: 34 bytes that decode to 716 MB (the SOG bomb had five).
HUGE_WEBP = bytes.fromhex("524946461a000000574542505650384c0d0000002ffebfaa1a071011118888fe0700")


def _within_memory(setup: str, work: str, allowance_mb: int) -> tuple[str, str]:
    """Run ``work`` in a fresh Python after ``setup``, allowed ``allowance_mb`` MB of data memory more than it holds
    then (RLIMIT_DATA: private writable memory, whatever the machine's other load; a peak of resident memory is not a
    fair measure there, as the kernel drops the libraries' pages under pressure); return its stdout and stderr. Work
    that needs more gets MemoryError ("raised MemoryError" on stdout)."""
    code = (f"import re, resource, sys\n{setup}\n"
            "held = int(re.search(r'VmData:\\s+(\\d+) kB', open('/proc/self/status').read()).group(1)) * 1024\n"
            f"limit = held + {allowance_mb} * 2 ** 20\n"
            "resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))\n"
            f"try:\n    {work}\nexcept BaseException as exc:\n    print('raised', type(exc).__name__, exc)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"})
    return res.stdout, res.stderr


def _zeros_deflated(size: int) -> bytes:
    """``size`` zero bytes, raw-deflated (about 1000:1)."""
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    chunk = bytes(1 << 24)
    out = [comp.compress(chunk) for _ in range(size // len(chunk))]
    return b"".join(out) + comp.flush()


# ------------------------------------------------------------------------------------------ SPZ
def _spz_with_tail(cloud_spz: Path, tail: int) -> bytes:
    """An SPZ whose gzip stream holds the cloud's data and then ``tail`` zero bytes (one gzip member)."""
    body = gzip.decompress(cloud_spz.read_bytes())
    comp = zlib.compressobj(9, zlib.DEFLATED, 31)
    chunk = bytes(1 << 24)
    parts = [comp.compress(body)] + [comp.compress(chunk) for _ in range(tail // len(chunk))]
    return b"".join(parts) + comp.flush()


def test_spz_stream_past_the_count_is_never_inflated(world, tmp_path: Path, run_cli) -> None:
    f = tmp_path / "tail.spz"
    f.write_bytes(_spz_with_tail(world.spz, 512 << 20))  # ~500 KB that inflate to 512 MB past the 60 Gaussians
    out, err = _within_memory("from roodi_toolkit.io.spz import read_spz", f"print('count', len(read_spz({str(f)!r})))",
                              64)
    assert "count 60" in out, out + err
    res = run_cli("info", f)
    assert res.exit_code == 0 and res.stderr == ""


@pytest.mark.parametrize("count", [1 << 20, 1 << 27])
def test_spz_count_the_file_cannot_hold_is_refused_before_inflating(count: int, tmp_path: Path, run_cli) -> None:
    f = tmp_path / "lie.spz"
    f.write_bytes(gzip.compress(struct.pack("<IIIBBBB", 0x5053474E, 3, count, 3, 12, 0, 0) + bytes(4096)))
    res = run_cli("info", f)
    expect_failure(res, 1, "lie.spz", "too few")


# ------------------------------------------------------------------------------------------ SOG
@pytest.fixture
def sog_files() -> dict[str, bytes]:
    from tests.conftest import make_cloud
    from tests.io.test_formats import encode_sog

    return encode_sog(make_cloud(300, seed=4))


def _zip(files: dict[str, bytes], compress: int = zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=compress) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


def test_sog_zip_entry_that_inflates_past_the_count_is_refused(sog_files, tmp_path: Path, run_cli) -> None:
    """The entry's header says 256 MB (a texture of 300 Gaussians is kilobytes): refused from the header."""
    f = tmp_path / "bomb.sog"
    f.write_bytes(_zip({**sog_files, "means_l.webp": bytes(256 << 20)}, zipfile.ZIP_DEFLATED))
    out, err = _within_memory("from roodi_toolkit.io.sog import read_sog", f"read_sog({str(f)!r})", 64)
    assert "raised FormatError" in out and "means_l.webp" in out and "BytesIO" not in out, out + err
    expect_failure(run_cli("info", f), 1, "bomb.sog", "means_l.webp", "decompression bomb")


def test_sog_zip_entry_whose_header_lies_is_inflated_no_further(sog_files, tmp_path: Path, run_cli) -> None:
    """The central directory says a few bytes, the deflate stream holds 256 MB: reading stops at the header's size
    (and the CRC then tells the entry is corrupt)."""
    data = _zip({**sog_files, "means_l.webp": b"x" * 1000}, zipfile.ZIP_DEFLATED)
    bomb = _zeros_deflated(256 << 20)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        info = z.getinfo("means_l.webp")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    # rebuild the zip with the bomb in place of the entry's data, its headers still claiming 1000 bytes
    patched = data[:start] + bomb + data[start + info.compress_size:]
    shift = len(bomb) - info.compress_size
    patched = bytearray(patched)
    lh = info.header_offset
    patched[lh + 18:lh + 22] = struct.pack("<I", len(bomb))  # local header: compressed size
    eocd = patched.rfind(b"PK\x05\x06")
    cd_offset = struct.unpack_from("<I", patched, eocd + 16)[0] + shift
    patched[eocd + 16:eocd + 20] = struct.pack("<I", cd_offset)
    pos = cd_offset
    while patched[pos:pos + 4] == b"PK\x01\x02":
        name_len, extra_len, comment_len = struct.unpack_from("<HHH", patched, pos + 28)
        name = bytes(patched[pos + 46:pos + 46 + name_len])
        offset = struct.unpack_from("<I", patched, pos + 42)[0]
        if name == b"means_l.webp":
            patched[pos + 20:pos + 24] = struct.pack("<I", len(bomb))
        elif offset > lh:
            patched[pos + 42:pos + 46] = struct.pack("<I", offset + shift)
        pos += 46 + name_len + extra_len + comment_len
    f = tmp_path / "liar.sog"
    f.write_bytes(bytes(patched))
    out, err = _within_memory("from roodi_toolkit.io.sog import read_sog", f"read_sog({str(f)!r})", 64)
    assert "raised FormatError" in out, out + err
    expect_failure(run_cli("info", f), 1, "liar.sog", "means_l.webp")


def test_sog_texture_whose_header_claims_too_many_pixels_is_refused_before_decoding(sog_files, tmp_path: Path,
                                                                                   run_cli) -> None:
    f = tmp_path / "huge.sog"
    f.write_bytes(_zip({**sog_files, **{name: HUGE_WEBP for name in sog_files if name.endswith(".webp")}}))
    out, err = _within_memory("from roodi_toolkit.io.sog import read_sog", f"read_sog({str(f)!r})", 64)
    assert "raised FormatError" in out and "16383x10923" in out, out + err
    assert "DecompressionBomb" not in err
    res = run_cli("convert", f, tmp_path / "o.ply")
    expect_failure(res, 1, "huge.sog", "16383x10923")
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize("what", ["a 5 GB sparse texture", "a 1 GB sparse meta.json", "a 16383x10923 texture"])
def test_sog_folder_files_larger_than_the_count_justifies(what: str, sog_files, tmp_path: Path, run_cli) -> None:
    folder = tmp_path / "scene"
    folder.mkdir()
    for name, data in sog_files.items():
        (folder / name).write_bytes(data)
    if what.endswith("sparse texture"):
        with open(folder / "quats.webp", "r+b") as fh:
            fh.truncate(5 << 30)
        needle = "quats.webp"
    elif what.endswith("meta.json"):
        with open(folder / "meta.json", "r+b") as fh:
            fh.truncate(1 << 30)
        needle = "meta.json"
    else:
        (folder / "scales.webp").write_bytes(HUGE_WEBP)
        needle = "16383x10923"
    res = run_cli("info", folder / "meta.json")
    expect_failure(res, 1, "meta.json", needle)


def test_sog_count_beyond_memory_is_refused(sog_files, tmp_path: Path, run_cli, monkeypatch) -> None:
    import roodi_toolkit.limits as limits

    meta = json.loads(sog_files["meta.json"])
    meta["count"] = 1 << 27
    f = tmp_path / "many.sog"
    f.write_bytes(_zip({**sog_files, "meta.json": json.dumps(meta).encode()}))
    monkeypatch.setattr(limits, "available_memory", lambda: 8 << 30)
    expect_failure(run_cli("info", f), 1, "many.sog", "134,217,728 Gaussians", "memory")


# ------------------------------------------------------------------------------------------ images
def _png_header_only(width: int, height: int, mode: int = 0, depth: int = 1) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` and holds no pixels (a header is all a bomb needs)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, depth, mode, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


def _dataset(root: Path, images: list[Path | bytes], size: int = 48, **frame_extra) -> Path:
    """A Blender dataset of the given images (paths copied, bytes written) with three cameras around the origin."""
    root.mkdir(parents=True, exist_ok=True)
    frames = []
    for i, image in enumerate(images):
        name = f"v{i}.png"
        if isinstance(image, bytes):
            (root / name).write_bytes(image)
        else:
            name = f"v{i}{image.suffix}"
            (root / name).write_bytes(image.read_bytes())
        a = 2 * np.pi * i / len(images)
        eye = np.array([4 * np.cos(a), 4 * np.sin(a), 0.5])
        back = eye / np.linalg.norm(eye)
        right = np.cross([0, 0, 1], back)
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
        frame = {"file_path": name, "transform_matrix": c2w.tolist()}
        frame.update({k: v[i] if isinstance(v, list) else v for k, v in frame_extra.items()})
        frames.append(frame)
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": frames}))
    return root


def _image(tmp_path: Path, name: str, array: np.ndarray) -> Path:
    from PIL import Image

    path = tmp_path / name
    Image.fromarray(array).save(path)
    return path


def test_a_huge_1_bit_photo_is_decoded_at_its_stored_size(tmp_path: Path) -> None:
    """A 4000x4000 1-bit PNG (a few KB) trained at --downscale 40: its 16 MB of stored pixels and strips of floats,
    not 600 MB of full-size float images (the issue's 13300x13300 ones took 4.8 GB)."""
    from PIL import Image

    big = tmp_path / "big.png"
    Image.new("1", (4000, 4000), 1).save(big)
    data = _dataset(tmp_path / "data", [big, big])
    out, err = _within_memory("from roodi_toolkit.io.dataset import load_dataset",
                              f"d = load_dataset({str(data)!r}, 40); print('shape', list(d.images.shape))", 150)
    assert "shape [2, 100, 100, 3]" in out, out + err
    assert err == "", err


@pytest.mark.parametrize("where", ["image", "mask"])
def test_a_photo_header_beyond_memory_is_refused_naming_it(where: str, world, tmp_path: Path, run_cli) -> None:
    ok = _image(tmp_path, "ok.png", np.zeros((48, 48, 3), np.uint8))
    bomb = _png_header_only(100_000, 100_000)
    if where == "image":
        data = _dataset(tmp_path / "data", [ok, bomb, ok])
        needle = "v1.png"
    else:
        (tmp_path / "data").mkdir()
        (tmp_path / "data" / "m.png").write_bytes(bomb)
        data = _dataset(tmp_path / "data", [ok, ok, ok], mask_path="m.png")
        needle = "m.png"
    res = run_cli("train", data, tmp_path / "t", "--iterations", "1", "-q")
    expect_failure(res, 1, needle, "100000x100000", "memory")
    assert not (tmp_path / "t").exists()


def test_pillow_never_warns_on_stderr(tmp_path: Path) -> None:
    """A 9500x9500 mask PNG (past Pillow's 89 M-pixel warning): read without a word on stderr."""
    from PIL import Image

    Image.new("L", (9500, 9500), 0).save(tmp_path / "m.png")
    res = subprocess.run([sys.executable, "-c", "from roodi_toolkit.io.files import read_image; "
                          f"print(read_image({str(tmp_path / 'm.png')!r}).shape)"],
                         capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert "(9500, 9500)" in res.stdout and res.stderr == "", res.stderr


@pytest.mark.parametrize("kind", ["claims 100000x100000", "1-D", "3 channels", "an .npz", "complex", "objects"])
def test_bad_depth_arrays_are_refused_naming_them(kind: str, tmp_path: Path, run_cli) -> None:
    ok = _image(tmp_path, "ok.png", np.zeros((48, 48, 3), np.uint8))
    depth = tmp_path / "data" / "d.npy"
    depth.parent.mkdir()
    if kind.startswith("claims"):
        header = {"descr": "<f8", "fortran_order": False, "shape": (100_000, 100_000)}
        buf = io.BytesIO()
        np.lib.format.write_array_header_1_0(buf, header)
        depth.write_bytes(buf.getvalue() + bytes(64))
    elif kind == "1-D":
        np.save(depth, np.zeros(48 * 48, np.float32))
    elif kind == "3 channels":
        np.save(depth, np.zeros((48, 48, 3), np.float32))
    elif kind == "an .npz":
        with open(depth, "wb") as fh:
            np.savez(fh, a=np.zeros((48, 48)))
    elif kind == "complex":
        np.save(depth, np.zeros((48, 48), np.complex64))
    else:
        np.save(depth, np.array([[None] * 48] * 48, dtype=object), allow_pickle=True)
    data = _dataset(tmp_path / "data", [ok, ok, ok], depth_path="d.npy")
    res = run_cli("train", data, tmp_path / "t", "--iterations", "1", "-q")
    expect_failure(res, 1, "d.npy")


# ------------------------------------------------------------------------------------------ image values and sizes
@pytest.mark.parametrize("kind", ["32-bit values over 65535", "32-bit float"])
def test_32_bit_photos_are_refused_not_wrapped(kind: str, tmp_path: Path, run_cli) -> None:
    ok = _image(tmp_path, "ok.png", np.zeros((48, 48, 3), np.uint8))
    values = np.full((48, 48), 70_000, np.int32) if kind.startswith("32-bit values") else \
        np.full((48, 48), 0.5, np.float32)
    tif = _image(tmp_path, "v.tif", values)
    data = _dataset(tmp_path / "data", [ok, tif, ok])
    res = run_cli("train", data, tmp_path / "t", "--iterations", "1", "-q")
    expect_failure(res, 1, "v1.tif", "32-bit")


def test_a_32_bit_photo_within_16_bits_is_read(tmp_path: Path) -> None:
    from roodi_toolkit.io.dataset import load_dataset

    ok = _image(tmp_path, "ok.png", np.full((48, 48), 65535, np.uint16))
    tif = _image(tmp_path, "v.tif", np.full((48, 48), 65535, np.int32))
    data = load_dataset(_dataset(tmp_path / "data", [ok, tif]))
    assert float(data.images[1].min()) == 1.0


def test_an_odd_sized_photo_is_the_one_named(tmp_path: Path, run_cli) -> None:
    ok = _image(tmp_path, "ok.png", np.zeros((48, 48, 3), np.uint8))
    small = _image(tmp_path, "small.png", np.zeros((8, 8, 3), np.uint8))
    data = _dataset(tmp_path / "data", [ok, ok, small, ok])
    res = run_cli("train", data, tmp_path / "t", "--iterations", "1", "-q")
    line = expect_failure(res, 1, "v2.png", "8x8", "48x48")
    assert "v0.png" not in line and "v1.png" not in line


# ------------------------------------------------------------------------------------------ render sizes
def test_render_size_is_bounded_by_memory(world, tmp_path: Path, run_cli, monkeypatch) -> None:
    import roodi_toolkit.limits as limits

    monkeypatch.setattr(limits, "available_memory", lambda: 2 << 30)
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8192x8192", "-q")
    expect_failure(res, 1, "--size 8192x8192", "memory")
    assert not (tmp_path / "r").exists()
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "16x16", "-q")
    assert res.exit_code == 0, res.stderr


def test_render_of_cameras_claiming_a_huge_image_is_refused(world, tmp_path: Path, run_cli, monkeypatch) -> None:
    import roodi_toolkit.limits as limits

    doc = json.loads((world.data / "transforms_train.json").read_text())
    doc.update(w=100_000, h=100_000, fl_x=50_000.0, fl_y=50_000.0, cx=50_000.0, cy=50_000.0)
    cams = tmp_path / "transforms_train.json"
    cams.write_text(json.dumps(doc))
    monkeypatch.setattr(limits, "available_memory", lambda: 64 << 30)
    res = run_cli("render", world.ply, tmp_path / "r", "--cameras", cams, "-q")
    expect_failure(res, 1, "transforms_train.json", "100000x100000")
    assert not (tmp_path / "r").exists()


# ------------------------------------------------------------------------------------------ PyTorch archives
def _deflated_torch_file(src: Path, dst: Path, size: int = 64 << 20) -> Path:
    """``src`` (a torch.save zip) rebuilt with its first tensor record deflated and grown to ``size`` bytes."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        grown = False
        for info in zin.infolist():
            data = zin.read(info.filename)
            if not grown and "/data/" in info.filename and not info.filename.endswith(".pkl"):
                zout.writestr(info.filename, bytes(size), compress_type=zipfile.ZIP_DEFLATED)
                grown = True
            else:
                zout.writestr(info, data)
    return dst


@pytest.mark.parametrize("where", ["train --resume", "select", "--lpips-weights"])
def test_a_compressed_torch_archive_is_refused_before_loading(where: str, world, tmp_path: Path, run_cli) -> None:
    import shutil

    if where == "train --resume":
        model = tmp_path / "t"
        assert run_cli("train", world.data, model, "--iterations", "1", "--eval-every", "0", "-q").exit_code == 0
        ckpt = model / "checkpoints" / "latest.pt"
        _deflated_torch_file(ckpt, tmp_path / "bomb.pt").replace(ckpt)
        res = run_cli("train", world.data, model, "--resume", "--iterations", "2", "-q")
        expect_failure(res, 1, "latest.pt", "never compresses")
    elif where == "select":
        dist = tmp_path / "dist"
        shutil.copytree(world.dist, dist)
        ckpt = dist / "object_classifier.pt"
        _deflated_torch_file(ckpt, tmp_path / "bomb.pt").replace(ckpt)
        res = run_cli("select", dist, tmp_path / "o.ply", "--object", "1", "-q")
        expect_failure(res, 1, "object_classifier.pt", "never compresses")
    else:
        import torch

        torch.save({"w": torch.zeros(4)}, tmp_path / "w.pth")
        bomb = _deflated_torch_file(tmp_path / "w.pth", tmp_path / "lpips.pth")
        res = run_cli("evaluate", world.ply, world.gen, "--object", "1", "--lpips-weights", bomb, "-q")
        expect_failure(res, 1, "lpips.pth", "never compresses")
    assert world.unchanged()


def test_a_compressed_checkpoint_is_never_inflated(tmp_path: Path) -> None:
    import torch

    torch.save({"w": torch.zeros(10)}, tmp_path / "small.pt")
    bomb = _deflated_torch_file(tmp_path / "small.pt", tmp_path / "bomb.pt", 256 << 20)
    out, err = _within_memory("import torch\nfrom roodi_toolkit.io.files import load_checkpoint",
                              f"load_checkpoint({str(bomb)!r})", 64)
    assert "raised InputError" in out and "never compresses" in out, out + err
