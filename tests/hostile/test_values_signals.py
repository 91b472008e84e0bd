"""Non-finite and extreme values in files, degenerate cameras and masks, a resumed run on other settings, a hostile
machine (full disk, read-only folder, missing system library) and commands killed mid-write."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from .conftest import expect_failure


# ------------------------------------------------------------------------------------------ values in files
def _cloud_with(field: str, value: float, tmp_path: Path) -> Path:
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    c = make_cloud(40, seed=2)
    getattr(c, field)[3] = value
    return write_ply(c, tmp_path / f"{field}_{value}.ply".replace("-", "m"))


VALUES = [("means", np.nan), ("means", np.inf), ("means", 1e38), ("means", -1e38), ("log_scales", 1e30),
          ("log_scales", np.nan), ("log_scales", -1e30), ("quats_wxyz", 0.0), ("quats_wxyz", np.nan),
          ("opacity_logits", np.inf), ("opacity_logits", -np.inf), ("opacity_logits", np.nan), ("sh_dc", 1e30),
          ("sh_dc", np.nan)]


VALUE_CASES = [pytest.param(f, v, c, id=f"{f}={v}-{c}") for f, v in VALUES for c in ("info", "convert", "prune", "render")]


@pytest.mark.parametrize("field,value,command", VALUE_CASES)
def test_extreme_values_are_handled_or_named(field: str, value: float, command: str, run_cli,
                                             tmp_path: Path) -> None:
    f = _cloud_with(field, value, tmp_path)
    before = f.read_bytes()
    args = {"info": ["info", f], "convert": ["convert", f, tmp_path / "o.spz"],
            "prune": ["prune", f, tmp_path / "o.ply", "-q"],
            "render": ["render", f, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q"]}[command]
    res = run_cli(*args)
    if res.exit_code != 0:  # refused: one line naming the file, or the option that would let it through
        line = expect_failure(res, 1)
        assert f.name in line or "--filter-nan" in line or "o.spz" in line, line
    assert f.read_bytes() == before
    assert not [p for p in tmp_path.rglob(".*")]  # no temporary file left behind


def test_info_shows_an_overflowing_scale(run_cli, tmp_path: Path) -> None:
    f = _cloud_with("log_scales", 1e30, tmp_path)  # finite in the file, exp() is infinite
    res = run_cli("info", f, "--json")
    assert json.loads(res.stdout)["bad_values"]["absurd_scale_rows"] == 1


# ------------------------------------------------------------------------------------------ cameras, masks
def _transforms(world, tmp_path: Path, edit) -> Path:
    data = tmp_path / "cams"
    data.mkdir()
    doc = json.loads((world.data / "transforms_train.json").read_text())
    for frame in doc["frames"]:
        frame["file_path"] = str(world.data / frame["file_path"])
        if "mask_path" in frame:
            frame["mask_path"] = str(world.data / frame["mask_path"])
    edit(doc)
    path = data / "transforms_train.json"
    path.write_text(json.dumps(doc))
    return path


DEGENERATE = {
    "zero fov": lambda d: d.update(camera_angle_x=0.0),
    "zero focal": lambda d: d.update(fl_x=0.0),
    "negative focal": lambda d: d.update(fl_x=-20.0),
    "scaled rotation": lambda d: d["frames"][0].update(transform_matrix=(2 * np.eye(4)).tolist()),
    "sheared rotation": lambda d: d["frames"][1].update(transform_matrix=[[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4],
                                                                          [0, 0, 0, 1]]),
    "mirrored rotation": lambda d: d["frames"][0].update(transform_matrix=np.diag([-1.0, 1, 1, 1]).tolist()),
    "nan matrix": lambda d: d["frames"][0].update(transform_matrix=[[float("nan")] * 4] * 4),
    "no frames": lambda d: d.update(frames=[]),
    "w zero": lambda d: d.update(w=0, h=0, fl_x=10.0),
}


@pytest.mark.parametrize("kind", list(DEGENERATE))
def test_degenerate_cameras_are_refused(kind: str, world, run_cli, tmp_path: Path) -> None:
    path = _transforms(world, tmp_path, DEGENERATE[kind])
    res = run_cli("render", world.ply, tmp_path / "r", "--cameras", path, "-q")
    expect_failure(res, 1, "transforms_train.json")
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").iterdir())


@pytest.mark.parametrize("top", [65535, 1024])
def test_a_mask_id_above_the_bound_is_refused(top: int, world, run_cli, tmp_path: Path) -> None:
    from roodi_toolkit.io.files import read_image, write_image

    masks = tmp_path / "masks"
    masks.mkdir()
    for f in sorted((world.data / "train" / "masks").glob("*.png")):
        m = read_image(f).astype(np.uint16)
        m[0, 0] = top
        write_image(m, masks / f.name)
    res = run_cli("distill", world.model, world.data, tmp_path / "d", "--masks", masks, "--iterations", "1", "-q")
    expect_failure(res, 1, str(top), "masks")
    assert not (tmp_path / "d").exists() or not any((tmp_path / "d").rglob("*.pt"))
    assert world.unchanged()


@pytest.mark.parametrize("command", ["distill", "extract"])
def test_a_mask_folder_names_the_file_at_fault(command: str, world, run_cli, tmp_path: Path) -> None:
    """The run layer reads --masks (the files segmenter takes arrays): missing files are listed, a mis-sized or colour
    mask is named, as when the segmenter read the folder itself."""
    from roodi_toolkit.io.files import read_image, write_image

    masks = tmp_path / "masks"
    masks.mkdir()
    found = sorted((world.data / "train" / "masks").glob("*.png"))
    for f in found[2:]:
        write_image(read_image(f), masks / f.name)

    def run(out: str):
        if command == "distill":
            return run_cli("distill", world.model, world.data, tmp_path / out, "--masks", masks, "--iterations", "1",
                           "-q")
        return run_cli("extract", world.data, tmp_path / out, "--model", world.model, "--object", "1", "--masks",
                       masks, "--distill-iterations", "1", "-q")

    expect_failure(run("a"), 1, str(masks), f"no mask for 2 of {len(found)} views: {found[0].name}, {found[1].name}")
    write_image(np.zeros((5, 16), np.uint8), masks / found[0].name)
    write_image(np.zeros((16, 16, 3), np.uint8) + np.array([255, 0, 0], np.uint8), masks / found[1].name)
    expect_failure(run("b"), 1, str(masks / found[0].name), "mask is 16x5 but its view is 16x16")
    write_image(read_image(found[0]), masks / found[0].name)
    expect_failure(run("c"), 1, str(masks / found[1].name), "colour image")
    assert world.unchanged()


@pytest.mark.parametrize("change", ["downscale", "data"])
def test_resume_refuses_other_settings(change: str, world, run_cli, tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "t"
    res = run_cli("train", world.data, out, "--iterations", "2", "--checkpoint-every", "1", "--eval-every", "0",
                  "-q")
    assert res.exit_code == 0, res.stderr
    data = world.data
    if change == "data":
        data = tmp_path / "other"
        shutil.copytree(world.data, data)
    res = run_cli("train", data, out, "--resume", "--iterations", "3", "-q",
                  *(["--downscale", "2"] if change == "downscale" else []))
    expect_failure(res, 1, "--downscale" if change == "downscale" else str(world.data))
    assert world.unchanged()


# ------------------------------------------------------------------------------------------ a hostile machine
@pytest.mark.parametrize("code,words", [(errno.ENOSPC, "disk is full"), (errno.EROFS, "read-only"),
                                        (errno.EACCES, "permission denied"), (errno.EDQUOT, "quota")])
@pytest.mark.parametrize("command", ["convert", "prune", "render"])
def test_environment_failures_are_named(code: int, words: str, command: str, world, run_cli, tmp_path: Path,
                                        monkeypatch) -> None:
    import tempfile

    def refuse(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    args = {"convert": ["convert", world.ply, tmp_path / "o.spz"], "prune": ["prune", world.ply, tmp_path / "o.ply",
                                                                              "-q"],
            "render": ["render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q"]}[command]
    res = run_cli(*args)
    expect_failure(res, 1, words)
    assert world.unchanged()


def test_a_missing_system_library_is_named(world, run_cli, tmp_path: Path, monkeypatch) -> None:
    import builtins

    real_import = builtins.__import__

    def no_gl(name, *args, **kwargs):
        if name.split(".")[0] in ("pyvista", "vtk", "vtkmodules"):
            raise ImportError("libGL.so.1: cannot open shared object file: No such file or directory")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_gl)
    for mod in [m for m in sys.modules if m.split(".")[0] in ("pyvista", "vtk", "vtkmodules")]:
        monkeypatch.delitem(sys.modules, mod)
    res = run_cli("inspect", world.ply, "--view-png", tmp_path / "s.png", "-q")  # the PyVista view
    expect_failure(res, 1, "libGL.so.1", "apt-get install libgl1")


# ------------------------------------------------------------------------------------------ killed mid-write
FINAL_OUTPUTS = {"convert": ["o.spz"], "prune": ["o.ply"], "render": ["orbit_000.png", "orbit_001.png", "render.json"],
                 "evaluate json": ["s.json"], "select": ["o.ply", "o.png"]}


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
@pytest.mark.parametrize("command", ["convert", "prune", "render", "evaluate json", "select"])
def test_killed_at_the_final_step_completes_it(sig: int, code: int, command: str, world, run_cli, tmp_path: Path,
                                              monkeypatch) -> None:
    """The signal arrives while the first output is being put in place: the final step is never cut in two (the
    signal is held over it), so every output is there, whole, no hidden temporary file is left, and the command
    exits with the signal's code. (A signal before the final step leaves nothing: test_write_window.py.)"""
    real_replace, real_link = os.replace, os.link

    def killed(real):
        def step(src, dst, *a, **k):
            os.kill(os.getpid(), sig)
            time.sleep(0.2)  # a signal that is not held raises at the next bytecode, before the real step
            return real(src, dst, *a, **k)
        return step

    out = tmp_path / "out"
    out.mkdir()
    args = {"convert": ["convert", world.ply, out / "o.spz"], "prune": ["prune", world.ply, out / "o.ply", "-q"],
            "render": ["render", world.ply, out / "r", "--orbit", "2", "--size", "8x8", "-q"],
            "evaluate json": ["evaluate", world.ply, world.gen, "--object", "1", "--json", out / "s.json", "-q"],
            "select": ["select", world.dist, out / "o.ply", "--object", "1", "-q"]}[command]
    # Ctrl-C reaches a process that has Python's SIGINT handler; a suite started as a background job inherits SIGINT
    # ignored (POSIX), so the handler is put in place for this run and the previous one restored after it
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.setattr(os, "replace", killed(real_replace))
    monkeypatch.setattr(os, "link", killed(real_link))
    try:
        res = run_cli(*args)
    finally:
        monkeypatch.setattr(os, "replace", real_replace)
        monkeypatch.setattr(os, "link", real_link)
        signal.signal(signal.SIGINT, previous)
    assert res.exit_code == code, res.stderr
    assert sorted(p.name for p in out.rglob("*") if p.is_file()) == FINAL_OUTPUTS[command]
    assert world.unchanged()


@pytest.fixture(scope="module")
def big_ply(tmp_path_factory) -> Path:
    """A 400k-Gaussian PLY (99 MB), written once for the signals' cases: they only read it."""
    from roodi_toolkit.io.splat import write_cloud
    from tests.conftest import make_cloud

    return write_cloud(make_cloud(400_000, sh_degree=3, seed=1), tmp_path_factory.mktemp("big") / "big.ply")


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)])
def test_a_real_process_killed_while_converting(sig: int, code: int, tmp_path: Path, big_ply: Path) -> None:
    """A separate process, signalled while it works: it exits with the signal's code (or finished first), and leaves
    either the complete output or none, never a hidden partial file."""
    from roodi_toolkit.io.splat import read_cloud

    out = tmp_path / "big.spz"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    proc = subprocess.Popen([sys.executable, "-m", "roodi_toolkit.cli.main", "convert", str(big_ply), str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp_path)
    deadline = time.time() + 60
    while time.time() < deadline and not any(p.name.startswith(".big.spz") for p in tmp_path.iterdir()):
        if proc.poll() is not None:
            break
        time.sleep(0.005)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (0, code), err
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    if proc.returncode == 0 or out.exists():  # finished, or signalled just after the rename: the whole output
        assert len(read_cloud(out)) == 400_000
