"""Signals and a full disk in the write window: while a command writes its outputs, SIGTERM, Ctrl-C or a disk that
fills up leaves none of them (not half of them, not a hidden temporary file, not the folder it made for them), in
one line; train's model folder is either absent or a state --resume continues, never half made."""

from __future__ import annotations

import os
import signal
import tempfile
from pathlib import Path

import pytest

from .conftest import expect_failure

# command -> (arguments; {ply} {dist} {data} {model} {gen} {out} filled in), which temporary file (1-based) the
# trouble hits: a later one, so that earlier outputs of the command are finished and waiting
COMMANDS = {
    "convert": ("convert {ply} {out}/o.spz", 1),
    "prune, three outputs": ("prune {ply} {out}/o.ply --floaters-out {out}/f.ply --report {out}/r.json --alpha 0.1 "
                             "--mode statistical -q", 3),
    "render": ("render {ply} {out}/r --orbit 3 --size 8x8 -q", 2),
    "select": ("select {dist} {out}/o.ply --object 1 -q", 2),
    "evaluate": ("evaluate {ply} {gen} --object 1 --json {out}/s.json --renders {out}/v -q", 2),
    "make-scene": ("make-scene {out}/scene --preset kitchen --size 12x12 --train-views 2 --test-views 1 "
                   "--supersample 1 --objects 5 --targets 1 -q", 6),
    "distill": ("distill {model} {data} {out}/d --iterations 1 -q", 3),
    "train": ("train {data} {out}/t --iterations 2 --checkpoint-every 1 --eval-every 0 -q", 1),
}


def _args(command: str, world, out: Path) -> list[str]:
    return COMMANDS[command][0].format(ply=world.ply, dist=world.dist, data=world.data, model=world.model,
                                       gen=world.gen, out=out).split()


def _on_temp_file(number: int, act, monkeypatch) -> None:
    """Call ``act(path)`` when the command creates its ``number``-th temporary output file."""
    real = tempfile.mkstemp
    made = []

    def mkstemp(*args, **kwargs):
        fd, path = real(*args, **kwargs)
        made.append(path)
        if len(made) == number:
            act(path)
        return fd, path

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


def _left(out: Path) -> list[str]:
    return sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)], ids=["SIGTERM", "SIGINT"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_signal_while_writing_leaves_no_output(command: str, sig: int, code: int, world, run_cli, tmp_path: Path,
                                                 monkeypatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    _on_temp_file(COMMANDS[command][1], lambda path: os.kill(os.getpid(), sig), monkeypatch)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # a background job ignores SIGINT
    try:
        res = run_cli(*_args(command, world, out))
    finally:
        signal.signal(signal.SIGINT, previous)
    assert res.exit_code == code, res.stderr
    assert _left(out) == []  # no output, no temporary file, no folder made for them
    assert world.unchanged()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full to fill a disk")
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_full_disk_while_writing_leaves_no_output(command: str, world, run_cli, tmp_path: Path,
                                                    monkeypatch) -> None:
    def full(path: str) -> None:  # the temporary file becomes a window onto a full disk: writes fail with ENOSPC
        os.unlink(path)
        os.symlink("/dev/full", path)

    out = tmp_path / "out"
    out.mkdir()
    _on_temp_file(COMMANDS[command][1], full, monkeypatch)
    res = run_cli(*_args(command, world, out))
    expect_failure(res, 1, "disk is full", "free some space")
    assert _left(out) == []
    assert world.unchanged()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full to fill a disk")
def test_a_full_disk_at_a_later_checkpoint_keeps_the_resumable_state(world, run_cli, tmp_path: Path,
                                                                      monkeypatch) -> None:
    """The first checkpoint lands with cfg.json; the disk fills at the second: one line, and the folder holds the
    first state, which --resume continues."""
    def full(path: str) -> None:
        os.unlink(path)
        os.symlink("/dev/full", path)

    out = tmp_path / "t"
    _on_temp_file(3, full, monkeypatch)  # cfg.json, checkpoint 1, then checkpoint 2
    res = run_cli("train", world.data, out, "--iterations", "3", "--checkpoint-every", "1", "--eval-every", "0", "-q")
    expect_failure(res, 1, "latest.pt", "disk is full")
    assert _left(out) == ["cfg.json", "checkpoints", "checkpoints/latest.pt"]
    monkeypatch.undo()
    res = run_cli("train", world.data, out, "--resume", "-q")
    assert res.exit_code == 0, res.stderr
    assert (out / "point_cloud" / "iteration_3" / "point_cloud.ply").is_file()
