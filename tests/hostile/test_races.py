"""Two writers, one output: a file that appears at an output while a command runs (another program, a second run of
the same command) is left alone and the command refuses in one line, none of its outputs written; symbolic links at
an output count as files (a dangling one too); output names up to the 255 bytes file systems allow work (the hidden
temporary name is cut to fit), longer ones are refused in one line."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from .conftest import expect_failure

# command -> (arguments; {ply} {dist} {gen} {out} filled in), the outputs it writes (relative to {out})
COMMANDS = {
    "convert": ("convert {ply} {out}/o.spz", ["o.spz"]),
    "prune": ("prune {ply} {out}/o.ply -q", ["o.ply"]),
    "prune, three outputs": ("prune {ply} {out}/o.ply --floaters-out {out}/f.ply --report {out}/r.json --alpha 0.1 "
                             "--mode statistical -q", ["f.ply", "o.ply", "r.json"]),
    "render": ("render {ply} {out}/r --orbit 2 --size 8x8 -q", ["r/orbit_000.png", "r/orbit_001.png", "r/render.json"]),
    "select": ("select {dist} {out}/o.ply --object 1 -q", ["o.ply", "o.png"]),
    "evaluate": ("evaluate {ply} {gen} --object 1 --json {out}/s.json -q", ["s.json"]),
    "inspect": ("inspect {ply} --histogram {out}/h.png -q", ["h.png"]),
}


def _args(command: str, world, out: Path) -> list[str]:
    return COMMANDS[command][0].format(ply=world.ply, dist=world.dist, gen=world.gen, out=out).split()


def _files(out: Path) -> list[str]:
    return sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file() or p.is_symlink())


def _appear_at(target: Path, monkeypatch) -> None:
    """Make ``target`` appear (another program's file) just as the command starts writing its first output."""
    real = tempfile.mkstemp
    done = []

    def mkstemp(*args, **kwargs):
        if not done:
            done.append(True)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(b"another program's file\n")
        return real(*args, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_file_appearing_at_an_output_is_left_alone(command: str, world, run_cli, tmp_path: Path,
                                                     monkeypatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    outputs = COMMANDS[command][1]
    stranger = out / outputs[-1]
    _appear_at(stranger, monkeypatch)
    res = run_cli(*_args(command, world, out))
    expect_failure(res, 1, stranger.name, "appeared while this command ran")
    assert stranger.read_bytes() == b"another program's file\n"
    assert _files(out) == [stranger.relative_to(out).as_posix()]  # none of the command's own outputs appeared
    assert res.stdout == ""  # no "wrote ..." for what was not written
    assert world.unchanged()


def test_a_file_appearing_while_prune_computes_is_left_alone(world, run_cli, tmp_path: Path, monkeypatch) -> None:
    """The issue's case: the output is free when prune checks it, taken while it computes."""
    from roodi_toolkit.cli import prune_options

    real = prune_options.prune_with_photos

    def slow_prune(*args, **kwargs):
        (tmp_path / "o.ply").write_bytes(b"written by a second prune\n")
        return real(*args, **kwargs)

    monkeypatch.setattr(prune_options, "prune_with_photos", slow_prune)
    monkeypatch.setattr("roodi_toolkit.cli.cmd_prune.prune_with_photos", slow_prune)
    res = run_cli("prune", world.ply, tmp_path / "o.ply", "-q")
    expect_failure(res, 1, "o.ply", "appeared", "--overwrite")
    assert (tmp_path / "o.ply").read_bytes() == b"written by a second prune\n"
    res = run_cli("prune", world.ply, tmp_path / "p.ply", "--overwrite", "-q")  # --overwrite: replaced
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "p.ply").read_bytes() != b"written by a second prune\n"


def test_two_prunes_to_one_output_one_wins_whole(world, tmp_path: Path) -> None:
    """Two real processes, the second started 0.2 s after the first: one writes the output, the other refuses;
    the output is exactly the winner's."""
    from roodi_toolkit.io.splat import write_cloud
    from tests.conftest import make_cloud

    inputs = [write_cloud(make_cloud(60_000, sh_degree=1, seed=s), tmp_path / f"in{s}.ply") for s in (1, 2)]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    run = [sys.executable, "-m", "roodi_toolkit.cli.main", "prune"]
    procs = []
    for src in inputs:
        procs.append(subprocess.Popen([*run, str(src), str(tmp_path / "o.ply"), "-q"], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        time.sleep(0.2)
    results = [p.communicate(timeout=300) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(codes) == [0, 1], results
    loser = results[codes.index(1)][1]
    assert len(loser.strip().splitlines()) == 1 and ("appeared" in loser or "already exists" in loser), loser
    winner = inputs[codes.index(0)]
    ref = subprocess.run([*run, str(winner), str(tmp_path / "ref.ply"), "-q"], env=env, capture_output=True)
    assert ref.returncode == 0
    assert (tmp_path / "o.ply").read_bytes() == (tmp_path / "ref.ply").read_bytes()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ------------------------------------------------------------------------------------------ links at an output
LINKED = {
    "convert": "convert {ply} {link}",
    "prune": "prune {ply} {link} -q",
    "prune --floaters-out": "prune {ply} {out}/kept.ply --floaters-out {link} --alpha 0.1 --mode statistical -q",
    "prune --report": "prune {ply} {out}/kept.ply --report {link} -q",
    "select": "select {dist} {out}/o.ply --object 1 --picture {link} -q",
    "evaluate --json": "evaluate {ply} {gen} --object 1 --json {link} -q",
    "inspect --histogram": "inspect {ply} --histogram {link} -q",
}
SUFFIX = {"convert": ".spz", "prune --report": ".json", "evaluate --json": ".json", "select": ".png",
          "inspect --histogram": ".png"}


@pytest.mark.parametrize("target", ["nothing", "a stranger's file"])
@pytest.mark.parametrize("command", list(LINKED))
def test_a_symbolic_link_at_an_output_is_a_file_there(command: str, target: str, world, run_cli,
                                                      tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    aim = tmp_path / "elsewhere" / "file"
    if target != "nothing":
        aim.parent.mkdir()
        aim.write_bytes(b"a stranger's file\n")
    link = out / f"link{SUFFIX.get(command, '.ply')}"
    link.symlink_to(aim)
    args = LINKED[command].format(ply=world.ply, dist=world.dist, gen=world.gen, out=out, link=link).split()
    res = run_cli(*args)
    expect_failure(res, 1, link.name, "already exists", "symbolic link", "--overwrite")
    assert link.is_symlink() and os.readlink(link) == str(aim)
    assert _files(out) == [link.name]
    res = run_cli(*args, "--overwrite")
    assert res.exit_code == 0, res.stderr
    assert not link.is_symlink() and link.is_file()  # the link itself replaced by the output
    assert (aim.read_bytes() == b"a stranger's file\n") if target != "nothing" else not aim.exists()
    assert world.unchanged()


# ------------------------------------------------------------------------------------------ long names
NAMES = {"250 ASCII bytes": "a" * 246 + ".ply", "255 ASCII bytes": "b" * 251 + ".ply",
         "255 UTF-8 bytes": "é" * 125 + "c.ply", "254 bytes, a 2-part suffix": "d" * 239 + ".compressed.ply"}


@pytest.mark.parametrize("name", list(NAMES))
@pytest.mark.parametrize("command", ["convert", "prune", "render"])
def test_outputs_with_names_up_to_255_bytes(command: str, name: str, world, run_cli, tmp_path: Path) -> None:
    file = NAMES[name]
    out = tmp_path / "out"
    out.mkdir()
    args = {"convert": ["convert", world.ply, out / file],
            "prune": ["prune", world.ply, out / file, "--report", out / (file[:-5] + ".json"), "-q"],
            "render": ["render", world.ply, out / file[:-4], "--orbit", "1", "--size", "8x8", "-q"]}[command]
    res = run_cli(*args)
    assert res.exit_code == 0, res.stderr
    assert (out / file).exists() or (out / file[:-4]).is_dir()
    assert not [p for p in out.rglob(".*")]


@pytest.mark.parametrize("command", ["convert", "prune", "render", "batch"])
def test_output_names_over_255_bytes_are_refused(command: str, world, run_cli, tmp_path: Path) -> None:
    file = "e" * 252 + ".ply"
    args = {"convert": ["convert", world.ply, tmp_path / file],
            "prune": ["prune", world.ply, tmp_path / "o.ply", "--floaters-out", tmp_path / file, "-q"],
            "render": ["render", world.ply, tmp_path / file, "--orbit", "1", "--size", "8x8", "-q"],
            "batch": ["batch", "convert", world.ply, tmp_path / "b", "--to", ".ply", "--results", tmp_path / file,
                      "-q"]}[command]
    res = run_cli(*args)
    expect_failure(res, 1, "256 bytes long")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
