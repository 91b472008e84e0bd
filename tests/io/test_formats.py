"""Splat formats: writers round-trip through our readers, readers decode files built here from each format's spec,
detection goes by content, bad files give one line, real files agree with each other and with splat-transform."""

from __future__ import annotations

import gzip
import io
import json
import os
import shutil
import struct
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit import FormatError, GaussianCloud, PlyError, read_cloud, write_cloud
from roodi_toolkit.gaussians import SH_C0
from roodi_toolkit.io.compare import cloud_differences
from roodi_toolkit.io.compressed_ply import morton_order
from roodi_toolkit.io.splat import OPACITY_LOGIT_LIMIT, detect_format, read_cloud_report

from ..paths import REPO, SHARED_DATA

DATA = SHARED_DATA  # the shared real data: $ROODI_DATA, else ../shared/data from the repo root


def make_cloud(n: int = 700, degree: int = 0, seed: int = 0) -> GaussianCloud:
    """A small random cloud with values inside every format's range."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianCloud(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=rng.uniform(-6, -1, size=(n, 3)).astype(np.float32),
        opacity_logits=rng.uniform(-4, 4, size=n).astype(np.float32),
        sh_dc=rng.uniform(-1.5, 1.5, size=(n, 3)).astype(np.float32),
        sh_rest=rng.uniform(-0.9, 0.9, size=(n, k, 3)).astype(np.float32))


# ----------------------------------------------------------------------------------------------- encoders from the specs
def encode_splat(c: GaussianCloud) -> bytes:
    """antimatter15 .splat: pos f32 x3, linear scale f32 x3, RGBA u8, quaternion w,x,y,z u8 ((q + 1) * 127.5)."""
    rec = np.zeros(len(c), dtype=[("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    rec["pos"] = c.means
    rec["scale"] = np.exp(c.log_scales)
    rgba = np.concatenate([c.rgb, c.opacities[:, None]], axis=1)
    rec["rgba"] = np.clip(np.round(rgba * 255), 0, 255)
    rec["rot"] = np.clip(np.round((c.quats_normalized + 1) * 127.5), 0, 255)
    return rec.tobytes()


def encode_ksplat(c: GaussianCloud, mode: int, bucket: int = 256) -> bytes:
    """GaussianSplats3D .ksplat with one section: mode 0 (float32) or 1 (uint16 positions in buckets, float16)."""
    n, degree = len(c), c.sh_degree
    per_sh = [0, 9, 24, 45][degree]
    qrange = 32767
    buckets = -(-n // bucket)
    full = n // bucket
    partial = buckets - full
    centres = np.stack([c.means[i * bucket:(i + 1) * bucket].mean(axis=0) for i in range(buckets)]).astype("<f4")
    block = float(2.02 * np.abs(c.means - np.repeat(centres, bucket, axis=0)[:n]).max())  # every offset fits
    # ksplat SH order: per band, per channel (band 1: R0-2, G0-2, B0-2; band 2: R3-7, ...)
    order = []
    for lo, cnt in ((0, 3), (3, 5), (8, 7))[:degree]:
        for ch in range(3):
            order += [(lo + j) * 3 + ch for j in range(cnt)]
    sh = np.ascontiguousarray(c.sh_rest.reshape(n, -1)[:, order] if per_sh else np.zeros((n, 0)))
    rgba = np.clip(np.round(np.concatenate([c.rgb, c.opacities[:, None]], axis=1) * 255), 0, 255).astype(np.uint8)
    if mode == 0:
        rows = [c.means.astype("<f4").view(np.uint8).reshape(n, 12), np.exp(c.log_scales).astype("<f4").view(
            np.uint8).reshape(n, 12), c.quats_wxyz.astype("<f4").view(np.uint8).reshape(n, 16), rgba,
            sh.astype("<f4").view(np.uint8).reshape(n, -1)]
    else:
        scale = block / 2.0 / qrange
        rel = np.round((c.means - np.repeat(centres, bucket, axis=0)[:n]) / scale + qrange)
        rows = [np.clip(rel, 0, 65535).astype("<u2").view(np.uint8).reshape(n, 6),
                np.exp(c.log_scales).astype("<f2").view(np.uint8).reshape(n, 6),
                c.quats_wxyz.astype("<f2").view(np.uint8).reshape(n, 8), rgba,
                sh.astype("<f2").view(np.uint8).reshape(n, -1)]
    body = np.concatenate(rows, axis=1).tobytes()
    main = bytearray(4096)
    main[0], main[1] = 0, 1
    struct.pack_into("<I", main, 4, 1)
    struct.pack_into("<I", main, 16, n)
    struct.pack_into("<H", main, 20, mode)
    sec = bytearray(1024)
    bucket_bytes = 12  # one float32 centre per bucket
    struct.pack_into("<IIIIfH", sec, 0, n, n, bucket, buckets, block, bucket_bytes)
    struct.pack_into("<I", sec, 24, qrange)
    struct.pack_into("<II", sec, 32, full, partial)
    struct.pack_into("<H", sec, 40, degree)
    partial_sizes = np.array([n - full * bucket] if partial else [], dtype="<u4")
    return bytes(main) + bytes(sec) + partial_sizes.tobytes() + centres.tobytes() + body


def _webp(pixels: np.ndarray, width: int) -> bytes:
    from PIL import Image

    h = -(-len(pixels) // width)
    img = np.zeros((h * width, 4), dtype=np.uint8)
    img[:len(pixels)] = pixels
    buf = io.BytesIO()
    Image.fromarray(img.reshape(h, width, 4), "RGBA").save(buf, "WEBP", lossless=True, exact=True)
    return buf.getvalue()


def encode_sog(c: GaussianCloud) -> dict[str, bytes]:
    """SOG version 2 (degree 0): meta.json and its WebP textures, quantised as the spec says."""
    n, w = len(c), 32
    lg = np.sign(c.means) * np.log(np.abs(c.means.astype(np.float64)) + 1)
    mins, maxs = lg.min(axis=0), lg.max(axis=0)
    q = np.round((lg - mins) / (maxs - mins) * 65535).astype(np.int64)
    pad = np.full((n, 1), 255)
    q_n = c.quats_normalized.astype(np.float64)
    largest = np.argmax(np.abs(q_n), axis=1)
    q_n = np.where(q_n[np.arange(n), largest][:, None] < 0, -q_n, q_n)
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[largest]
    small = np.take_along_axis(q_n, others, axis=1) * np.sqrt(2)
    quats = np.concatenate([np.round((small + 1) / 2 * 255), 252 + largest[:, None]], axis=1)
    scode = np.linspace(-7, 0, 256).astype(np.float32)
    ccode = np.linspace(-2, 2, 256).astype(np.float32)
    si = np.abs(c.log_scales[..., None] - scode).argmin(axis=-1)
    ci = np.abs(c.sh_dc[..., None] - ccode).argmin(axis=-1)
    alpha = np.round(c.opacities * 255)[:, None]
    meta = {"version": 2, "count": n,
            "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"codebook": scode.tolist(), "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]}, "sh0": {"codebook": ccode.tolist(), "files": ["sh0.webp"]}}
    u8 = lambda a: np.clip(a, 0, 255).astype(np.uint8)  # noqa: E731
    return {"meta.json": json.dumps(meta).encode(),
            "means_l.webp": _webp(u8(np.concatenate([q & 255, pad], axis=1)), w),
            "means_u.webp": _webp(u8(np.concatenate([q >> 8, pad], axis=1)), w),
            "quats.webp": _webp(u8(quats), w), "scales.webp": _webp(u8(np.concatenate([si, pad], axis=1)), w),
            "sh0.webp": _webp(u8(np.concatenate([ci, alpha], axis=1)), w)}


def encode_spz_v4(c: GaussianCloud) -> bytes:
    """SPZ version 4: our version-3 payload split into zstd streams behind a 32-byte header and a TOC."""
    import zstandard

    from roodi_toolkit.io.spz import encode_spz

    body = gzip.decompress(encode_spz(c))
    magic, _, n, degree, frac, flags, _ = struct.unpack_from("<IIIBBBB", body)
    dim = (degree + 1) ** 2 - 1
    sizes = [9 * n, n, 3 * n, 3 * n, 4 * n] + ([3 * dim * n] if dim else [])
    streams, off = [], 16
    for s in sizes:
        streams.append(body[off:off + s])
        off += s
    comp = [zstandard.ZstdCompressor().compress(s) for s in streams]
    header = struct.pack("<IIIBBBBI", magic, 4, n, degree, frac, flags, len(comp), 32) + bytes(12)
    toc = b"".join(struct.pack("<QQ", len(z), len(s)) for z, s in zip(comp, streams))
    return header + toc + b"".join(comp)


# ----------------------------------------------------------------------------------------------- writer round trips
@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("suffix", [".ply", ".compressed.ply", ".spz"])
def test_writer_round_trip(tmp_path: Path, suffix: str, degree: int) -> None:
    c = make_cloud(degree=degree)
    out = write_cloud(c, tmp_path / f"scene{suffix}")
    back, report = read_cloud_report(out)
    assert report.format == {".ply": "ply", ".compressed.ply": "compressed-ply", ".spz": "spz"}[suffix]
    assert len(back) == len(c) and back.sh_degree == degree
    d = cloud_differences(c.select(morton_order(c.means)) if suffix == ".compressed.ply" else c, back)
    # tolerances: the formats' quantisation steps (SPZ: 1/4096 positions, 1/16 log-scale, 10-bit quaternion
    # components, 1/(255*0.15) DC; compressed PLY: 11/10-bit positions and scales per 256-chunk, 8-bit colour)
    tol = {".ply": dict(position_rel=0, log_scale=0, rotation=1e-6, sh_dc=0, alpha=0, sh_rest=0),
           ".compressed.ply": dict(position_rel=1e-3, log_scale=5e-3, rotation=2e-3, sh_dc=0.02, alpha=3e-3,
                                   sh_rest=0.02),
           ".spz": dict(position_rel=1e-4, log_scale=0.04, rotation=2e-3, sh_dc=0.015, alpha=3e-3, sh_rest=0.07)}
    for key, limit in tol[suffix].items():
        assert d[key] <= limit, (key, d[key])


def test_written_files_do_not_depend_on_the_clock(tmp_path: Path, monkeypatch) -> None:
    """The same splat written at two moments gives the same bytes (gzip stamps the time unless told not to)."""
    import time

    c = make_cloud()
    for suffix in (".ply", ".compressed.ply", ".spz"):
        first = write_cloud(c, tmp_path / f"a{suffix}").read_bytes()
        monkeypatch.setattr(time, "time", lambda: 2_000_000_000.0)
        second = write_cloud(c, tmp_path / f"b{suffix}").read_bytes()
        monkeypatch.undo()
        assert first == second, suffix


def test_compressed_ply_decodes_the_same_in_blocks_threads_and_one_pass(tmp_path: Path, monkeypatch) -> None:
    # more than one block of chunks (the last one partial, its last chunk too), SH bytes among them; the same values
    # with one thread, with several, and with the SH bytes decoded one property at a time (the general path, taken
    # when the properties are not the plain bytes f_rest_0..M-1 in order)
    from roodi_toolkit.io import compressed_ply

    c = make_cloud(compressed_ply.BLOCK_CHUNKS * compressed_ply.CHUNK + 300, degree=1)
    path = write_cloud(c, tmp_path / "big.compressed.ply")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    one = read_cloud(path)
    monkeypatch.setattr(compressed_ply, "decode_threads", lambda: 2)
    two = read_cloud(path)
    # the same file with its SH properties listed in reverse (and their bytes swapped to match): decoded per property
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    original = raw[:end].decode().split("\n")
    at = [i for i, line in enumerate(original) if line.startswith("property uchar f_rest_")]
    lines = list(original)
    for i, j in zip(at, at[::-1]):
        lines[i] = original[j]
    body = np.frombuffer(raw[end:], dtype=np.uint8)
    sh = body[len(body) - len(c) * len(at):].reshape(len(c), len(at))[:, ::-1]  # the sh element comes last
    swapped = tmp_path / "swapped.compressed.ply"
    swapped.write_bytes("\n".join(lines).encode() + body[:len(body) - sh.size].tobytes() + sh.tobytes())
    for a, b in ((one, two), (one, read_cloud(swapped))):
        for field in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    # and the values are the cloud's, within the format's steps (SH: channel-major bytes in the right place)
    d = cloud_differences(c.select(compressed_ply.morton_order(c.means)), one)
    assert d["position_rel"] <= 1e-3 and d["sh_rest"] <= 0.02 and d["alpha"] <= 3e-3


def test_write_refuses_unknown_extension_and_nan(tmp_path: Path) -> None:
    c = make_cloud(10)
    with pytest.raises(FormatError, match="cannot write"):
        write_cloud(c, tmp_path / "x.splat")
    c.means[3, 0] = np.nan
    with pytest.raises(FormatError, match="1 Gaussians have NaN"):
        write_cloud(c, tmp_path / "x.spz")
    assert not (tmp_path / "x.spz").exists()


# ----------------------------------------------------------------------------------------------- readers on spec-built files
def test_read_splat_file(tmp_path: Path) -> None:
    c = make_cloud(300)
    f = tmp_path / "a.splat"
    f.write_bytes(encode_splat(c))
    back = read_cloud(f)
    d = cloud_differences(c, back)
    assert d["position_rel"] < 1e-6 and d["log_scale"] < 1e-6
    assert d["sh_dc"] < 0.5 / 255 / SH_C0 + 1e-6 and d["alpha"] < 0.5 / 255 + 1e-6 and d["rotation"] < 0.01


@pytest.mark.parametrize("mode,degree", [(0, 0), (0, 2), (1, 0), (1, 1)])
def test_read_ksplat_file(tmp_path: Path, mode: int, degree: int) -> None:
    c = make_cloud(600, degree=degree)  # 600 = 2 full buckets of 256 + a partial one of 88
    f = tmp_path / "a.ksplat"
    f.write_bytes(encode_ksplat(c, mode))
    back, report = read_cloud_report(f)
    assert report.format == "ksplat" and back.sh_degree == degree
    d = cloud_differences(c, back)
    block = struct.unpack_from("<f", f.read_bytes(), 4096 + 16)[0]
    pos, half = (1e-6, 1e-6) if mode == 0 else (block / 2 / 32767 / np.ptp(c.means, axis=0).max(), 2e-3)
    assert d["position_rel"] <= pos + 1e-7 and d["log_scale"] < 2e-3 and d["rotation"] < 2e-3
    assert d["sh_rest"] <= half * (0 if mode == 0 else 1) + 1e-6
    assert d["alpha"] < 0.5 / 255 + 1e-6


def test_read_sog_meta_zip_and_folder(tmp_path: Path) -> None:
    c = make_cloud(500)
    files = encode_sog(c)
    folder = tmp_path / "sog"
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    with zipfile.ZipFile(tmp_path / "a.sog", "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    for path in (folder / "meta.json", folder, tmp_path / "a.sog"):
        back, report = read_cloud_report(path)
        assert report.format == "sog" and len(back) == 500
        d = cloud_differences(c, back)
        assert d["position_rel"] < 1e-4 and d["log_scale"] < 0.015 and d["sh_dc"] < 0.01
        assert d["rotation"] < 6e-3 and d["alpha"] < 0.5 / 255 + 1e-6


@pytest.mark.parametrize("degree", [0, 2])
def test_read_spz_v4(tmp_path: Path, degree: int) -> None:
    c = make_cloud(400, degree=degree)
    f = tmp_path / "a.spz"
    f.write_bytes(encode_spz_v4(c))
    v3 = tmp_path / "b.spz"
    write_cloud(c, v3)
    d = cloud_differences(read_cloud(v3), read_cloud(f))
    assert all(v == 0 for k, v in d.items() if k != "count"), d


def test_detection_is_by_content(tmp_path: Path) -> None:
    c = make_cloud(256)
    sources = {"compressed-ply": ".compressed.ply", "spz": ".spz", "ply": ".ply"}
    for fmt, suffix in sources.items():
        f = write_cloud(c, tmp_path / f"a{suffix}")
        renamed = tmp_path / f"{fmt}.bin"
        shutil.copy(f, renamed)
        assert detect_format(renamed) == fmt
    (tmp_path / "k.bin").write_bytes(encode_ksplat(c, 1))
    assert detect_format(tmp_path / "k.bin") == "ksplat"
    (tmp_path / "s.bin").write_bytes(encode_splat(c))
    assert detect_format(tmp_path / "s.bin") == "splat"


def test_infinite_opacity_becomes_finite(tmp_path: Path) -> None:
    c = make_cloud(300)
    c.opacity_logits[:5] = np.inf
    c.opacity_logits[5:7] = -np.inf
    f = write_cloud(c, tmp_path / "a.ply")
    back, report = read_cloud_report(f)
    assert (report.opacity_pos_inf, report.opacity_neg_inf) == (5, 2)
    assert np.all(back.opacity_logits[:5] == np.float32(OPACITY_LOGIT_LIMIT))
    assert np.all(back.opacity_logits[5:7] == np.float32(-OPACITY_LOGIT_LIMIT))
    assert not back.nonfinite_rows().any()
    raw, _ = read_cloud_report(f, raw=True)
    assert np.isposinf(raw.opacity_logits[:5]).all()


# ----------------------------------------------------------------------------------------------- bad input
def _bad_files(tmp_path: Path) -> dict[str, Path]:
    c = make_cloud(600)
    out = {}
    for name, data in {
        "compressed.ply": Path(write_cloud(c, tmp_path / "g.compressed.ply")).read_bytes(),
        "spz": Path(write_cloud(c, tmp_path / "g.spz")).read_bytes(),
        "spz4": encode_spz_v4(c),
        "ply": Path(write_cloud(c, tmp_path / "g.ply")).read_bytes(),
        "splat": encode_splat(c),
        "ksplat": encode_ksplat(c, 1),
    }.items():
        f = tmp_path / f"truncated.{name}"
        f.write_bytes(data[: len(data) * 2 // 3 + 1])
        out[f"truncated {name}"] = f
    sog = tmp_path / "bad.sog"
    sog.write_bytes(b"PK\x03\x04" + os.urandom(200))
    out["corrupt sog"] = sog
    meta = tmp_path / "meta.json"
    meta.write_text('{"version": 2, "count": 10, "means": {')
    out["corrupt meta.json"] = meta
    missing = tmp_path / "m2"
    missing.mkdir()
    (missing / "meta.json").write_text(json.dumps({"version": 2, "count": 5, "means": {
        "mins": [0, 0, 0], "maxs": [1, 1, 1], "files": ["means_l.webp", "means_u.webp"]}}))
    out["sog without textures"] = missing / "meta.json"
    garbage = tmp_path / "noise.bin"
    garbage.write_bytes(os.urandom(1001))
    out["unknown"] = garbage
    gz = tmp_path / "c.spz"
    gz.write_bytes(b"\x1f\x8b" + os.urandom(300))
    out["corrupt gzip"] = gz
    return out


def test_bad_files_give_one_line_naming_the_file(tmp_path: Path) -> None:
    for what, f in _bad_files(tmp_path).items():
        with pytest.raises((FormatError, PlyError)) as err:
            read_cloud(f)
        msg = str(err.value)
        assert str(f) in msg and "\n" not in msg, (what, msg)


def test_cli_bad_file_exit_1_and_convert(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from roodi_toolkit.cli.main import main

    bad = _bad_files(tmp_path)["truncated spz"]
    assert main(["info", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and str(bad) in err and "\n" not in err
    src = write_cloud(make_cloud(300, degree=1), tmp_path / "in.ply")
    for suffix in (".spz", ".compressed.ply", ".ply"):
        assert main(["convert", str(src), str(tmp_path / f"out{suffix}")]) == 0
    assert main(["convert", str(src), str(tmp_path / "out.spz")]) == 1  # exists, no --overwrite
    assert main(["convert", str(src), str(tmp_path / "out.spz"), "--overwrite"]) == 0
    assert main(["convert", str(src), str(src), "--overwrite"]) == 1  # never over its input
    assert main(["convert", str(tmp_path / "out.spz"), str(tmp_path / "out.txt")]) == 1
    capsys.readouterr()
    assert main(["info", str(tmp_path / "out.spz"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["file"]["format"] == "spz" and info["count"] == 300 and info["sh_degree"] == 1


# ----------------------------------------------------------------------------------------------- real files
def _real(name: str) -> Path:
    f = DATA / name
    if not f.exists():
        pytest.skip(f"real data {f} is absent (set ROODI_DATA to the shared data folder)")
    return f


def test_real_biker_both_encodings_agree() -> None:
    cp, rc = read_cloud_report(_real("biker/biker.compressed.ply"))
    sp, rs = read_cloud_report(_real("biker/biker.spz"))
    assert len(cp) == len(sp) == 152_746 and rc.format == "compressed-ply" and rs.format == "spz"
    assert rc.opacity_pos_inf == rs.opacity_pos_inf == 198
    assert not cp.nonfinite_rows().any() and not sp.nonfinite_rows().any()
    d = cloud_differences(cp, sp)
    # data/README: the two encodings agree to 5.6e-5 of the scene's size and 0.013 in SH DC; in log-scale to 1/32
    # (SPZ's 1/16 step) except where SPZ clamps log-scales at its floor of -10 (101 Gaussians lie below it)
    assert d["position_rel"] < 6e-5 and d["sh_dc"] < 0.014
    above = cp.log_scales.min(axis=1) > -9.9
    assert np.abs(cp.log_scales - sp.log_scales)[above].max() <= 1 / 32 + 1e-6


def test_real_donut_reads_and_converts(tmp_path: Path) -> None:
    c = read_cloud(_real("donut/point_cloud.ply"))
    assert len(c) == 45_624 and c.sh_degree == 0
    for suffix in (".compressed.ply", ".spz"):
        back = read_cloud(write_cloud(c, tmp_path / f"d{suffix}"))
        d = cloud_differences(c.select(morton_order(c.means)) if suffix == ".compressed.ply" else c, back)
        # compressed PLY: 8-bit colour over each chunk's range (half a step of a range of 4 is 0.028 in SH DC)
        assert d["position_rel"] < 1e-3 and d["alpha"] < 3e-3 and d["rotation"] < 2e-3
        if suffix == ".spz":  # SPZ's colour byte holds SH DC in [-3.33, 3.33] only (the reference clamps too)
            inside = np.abs(c.sh_dc).max(axis=1) < 3.3
            assert np.abs(c.sh_dc - back.sh_dc)[inside].max() < 0.5 / 255 / 0.15 + 1e-4
        else:
            assert d["sh_dc"] < 0.05


# ----------------------------------------------------------------------------------------------- splat-transform oracle
def _splat_transform() -> str:
    repo = REPO
    for cand in (os.environ.get("ROODI_SPLAT_TRANSFORM"), repo / ".oracle" / "node_modules" / ".bin" / "splat-transform",
                 shutil.which("splat-transform")):
        if cand and Path(cand).exists():
            return str(cand)
    pytest.skip("splat-transform not found (set ROODI_SPLAT_TRANSFORM, or npm install "
                "@playcanvas/splat-transform@2.7.1 --prefix .oracle, as scripts/test.sh does)")


def _st(tool: str, src: Path, dst: Path) -> Path:
    run = subprocess.run([tool, "-q", "-w", "-g", "cpu", str(src), str(dst)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    return dst


@pytest.mark.parametrize("degree", [0, 3])
def test_oracle_reads_our_writers(tmp_path: Path, degree: int) -> None:
    tool = _splat_transform()
    from roodi_toolkit.io.ply import read_ply

    c = make_cloud(1000, degree=degree)
    for suffix in (".compressed.ply", ".spz"):
        ours = write_cloud(c, tmp_path / f"ours{suffix}")
        theirs = read_ply(_st(tool, ours, tmp_path / f"ours_st{suffix}.ply"))
        d = cloud_differences(read_cloud(ours), theirs)  # same rows, same order: decoders must agree
        assert d["position_rel"] < 1e-6 and d["log_scale"] < 1e-5 and d["rotation"] < 1e-5, (suffix, d)
        assert d["sh_dc"] < 1e-5 and d["sh_rest"] < 1e-5 and d["alpha"] < 1e-6, (suffix, d)


@pytest.mark.parametrize("kind", ["splat", "ksplat0", "ksplat1", "sog"])
def test_oracle_decodes_like_us(tmp_path: Path, kind: str) -> None:
    tool = _splat_transform()
    from roodi_toolkit.io.ply import read_ply

    c = make_cloud(600, degree=1 if kind.startswith("ksplat") else 0)
    if kind == "splat":
        f = tmp_path / "a.splat"
        f.write_bytes(encode_splat(c))
    elif kind == "sog":
        f = tmp_path / "a.sog"
        with zipfile.ZipFile(f, "w") as z:
            for name, data in encode_sog(c).items():
                z.writestr(name, data)
    else:
        f = tmp_path / "a.ksplat"
        f.write_bytes(encode_ksplat(c, int(kind[-1])))
    ours, _ = read_cloud_report(f, raw=True)
    d = cloud_differences(read_ply(_st(tool, f, tmp_path / "st.ply")), ours)
    assert d["position_rel"] < 1e-6 and d["log_scale"] < 1e-5 and d["rotation"] < 1e-5, d
    assert d["sh_dc"] < 1e-5 and d["sh_rest"] < 1e-5 and d["opacity_logit"] < 1e-4, d


@pytest.mark.parametrize("suffix", [".spz", ".compressed.ply", ".sog"])
def test_oracle_files_with_sh_read_like_splat_transform(tmp_path: Path, suffix: str) -> None:
    """splat-transform's own SPZ 4, compressed PLY and SOG (SH palette) of a degree-3 cloud: we decode them as it does."""
    tool = _splat_transform()
    from roodi_toolkit.io.ply import read_ply

    src = write_cloud(make_cloud(800, degree=3), tmp_path / "src.ply")
    made = tmp_path / f"st{suffix}"
    run = subprocess.run([tool, "-q", "-w", "-g", "cpu", "-i", "1", str(src), str(made)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    ours, _ = read_cloud_report(made, raw=True)
    assert ours.sh_degree == 3
    d = cloud_differences(read_ply(_st(tool, made, tmp_path / "decoded.ply")), ours)
    assert d["position_rel"] < 1e-6 and d["log_scale"] < 1e-5 and d["rotation"] < 1e-5, d
    assert d["sh_dc"] < 1e-5 and d["sh_rest"] < 1e-5 and d["opacity_logit"] < 1e-4, d


def test_info_counts_bad_values(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from roodi_toolkit.cli.main import main

    c = make_cloud(200)
    c.means[:3, 1] = np.nan
    c.sh_dc[4, 0] = np.nan
    c.log_scales[5] = np.inf
    c.opacity_logits[6:9] = np.inf
    c.opacity_logits[9] = -np.inf
    c.log_scales[10] = np.log(100.0)  # 100 units wide in a scene of about 6
    f = write_cloud(c, tmp_path / "bad.ply")
    assert main(["info", str(f), "--json"]) == 0
    bad = json.loads(capsys.readouterr().out)["bad_values"]
    assert bad["nan"]["means"] == 3 and bad["nan"]["sh_dc"] == 1 and bad["nan_rows"] == 4
    assert bad["inf"]["log_scales"] == 3 and (bad["opacity_pos_inf"], bad["opacity_neg_inf"]) == (3, 1)
    assert bad["absurd_scale_rows"] == 1
    out = tmp_path / "clean.spz"
    assert main(["convert", str(f), str(out)]) == 1  # NaN rows refused by a quantised format
    assert main(["convert", str(f), str(out), "--filter-nan", "--filter-absurd-scales"]) == 0
    assert len(read_cloud(out)) == 200 - 5 - 1


def test_flipped_bytes_never_escape_as_other_errors(tmp_path: Path) -> None:
    """Random byte corruption of each format: the file reads, or fails with one FormatError/PlyError line."""
    c = make_cloud(300, degree=1)
    sources = {
        "a.compressed.ply": Path(write_cloud(c, tmp_path / "s.compressed.ply")).read_bytes(),
        "a.spz": Path(write_cloud(c, tmp_path / "s.spz")).read_bytes(),
        "b.spz": encode_spz_v4(c),
        "a.splat": encode_splat(c),
        "a.ksplat": encode_ksplat(c, 1),
    }
    rng = np.random.default_rng(7)
    for name, data in sources.items():
        for trial in range(12):
            buf = bytearray(data)
            # corrupt the first 4 KiB (headers, TOCs, chunk bounds) where a bad value does the most harm
            for pos in rng.integers(0, min(len(buf), 4096), size=4):
                buf[pos] = int(rng.integers(0, 256))
            f = tmp_path / f"{trial}_{name}"
            f.write_bytes(bytes(buf))
            try:
                read_cloud(f)
            except (FormatError, PlyError) as exc:
                assert "\n" not in str(exc) and str(f) in str(exc), (name, str(exc))
