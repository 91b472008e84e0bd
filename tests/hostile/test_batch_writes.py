"""What a batch writes: its results file (never an input, a manifest or a stranger's file), its items' outputs (never a
file it did not write, unless --overwrite; its own recorded ones still skipped or replaced), per-item options checked
before any work, and a SIGTERM that stops it at once and keeps the lines of what finished."""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .conftest import expect_failure


@pytest.fixture
def src(world, tmp_path: Path, monkeypatch) -> Path:
    """src/a.ply and src/b.spz; cwd = tmp_path."""
    (tmp_path / "src").mkdir()
    shutil.copyfile(world.ply, tmp_path / "src" / "a.ply")
    shutil.copyfile(world.spz, tmp_path / "src" / "b.spz")
    monkeypatch.chdir(tmp_path)
    return tmp_path / "src"


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _results(path: Path) -> list[dict]:
    return [json.loads(t) for t in path.read_text().splitlines()]


# ------------------------------------------------------------------------------------------ the results file
RESULTS = {
    "an input splat": ("src/b.spz", None),
    "the manifest itself": ("m.csv", None),
    "a stranger's text": ("notes.txt", b"my notes\n"),
    "a stranger's JSON lines": ("log.jsonl", b'{"event": "start"}\n{"event": "stop"}\n'),
    "a binary file": ("blob.bin", bytes(range(256)) * 4),
    "a deeply nested line": ("deep.jsonl", b"[" * 100_000 + b"\n"),
    "an item's output": ("out/a.ply", None),
    "inside the source folder": ("src/r.jsonl", None),
    "a folder": ("rdir", "dir"),
    "a dangling link": ("dangling.jsonl", "link"),
}


@pytest.mark.parametrize("kind", list(RESULTS))
def test_results_that_are_not_a_results_file_are_refused(kind: str, src: Path, run_cli, tmp_path: Path) -> None:
    path, content = RESULTS[kind]
    (tmp_path / "m.csv").write_text("input\nsrc/a.ply\nsrc/b.spz\n")
    if content == "dir":
        (tmp_path / path).mkdir()
    elif content == "link":
        (tmp_path / path).symlink_to(tmp_path / "nowhere" / "r.jsonl")
    elif content is not None:
        (tmp_path / path).write_bytes(content)
    before = _tree(tmp_path)
    source = "m.csv" if kind == "the manifest itself" else "src"
    res = run_cli("batch", "prune", source, "out", "--results", path, "-q")
    expect_failure(res, 1, path)
    assert _tree(tmp_path) == before  # the file untouched, no output written
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.ply"))


def test_results_of_an_earlier_batch_are_appended_to(src: Path, run_cli, tmp_path: Path) -> None:
    assert run_cli("batch", "convert", "src", "out", "--to", ".ply", "--results", "r.jsonl", "-q").exit_code == 0
    with open(tmp_path / "r.jsonl", "a") as f:
        f.write('{"item": "a.ply", "sta')  # the torn last line of a killed run
    res = run_cli("batch", "convert", "src", "out", "--to", ".ply", "--results", "r.jsonl", "-q")
    assert res.exit_code == 0, res.stderr
    assert "2 unchanged and skipped" in res.stdout
    # the torn line was ended, so the lines after it stay whole, and the file is still a results file
    texts = (tmp_path / "r.jsonl").read_text().splitlines()
    assert texts[-3] == '{"item": "a.ply", "sta' and all(json.loads(t)["status"] == "skipped" for t in texts[-2:])
    res = run_cli("batch", "convert", "src", "out", "--to", ".ply", "--results", "r.jsonl", "-q")
    assert res.exit_code == 0 and "2 unchanged and skipped" in res.stdout, res.stderr


# ------------------------------------------------------------------------------------------ items' outputs
TASK_ARGS = {"prune": ["prune"], "convert": ["convert", "--to", ".ply"], "info": ["info"]}
OUT_NAME = {"prune": "a.ply", "convert": "a.ply", "info": "a.json"}


@pytest.mark.parametrize("what", ["a file", "a dangling link"])
@pytest.mark.parametrize("task", list(TASK_ARGS))
def test_a_users_file_at_an_output_is_refused_then_replaced_with_overwrite(task: str, what: str, src: Path, run_cli,
                                                                          tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    mine = out / OUT_NAME[task]
    if what == "a file":
        mine.write_bytes(b"my own file\n")
    else:
        mine.symlink_to(tmp_path / "nowhere")
    res = run_cli("batch", *TASK_ARGS[task][:1], "src", "out", *TASK_ARGS[task][1:], "-q")
    expect_failure(res, 1, str(Path("out") / OUT_NAME[task]), "--overwrite")
    assert os.path.lexists(mine) and (mine.is_symlink() or mine.read_bytes() == b"my own file\n")
    assert sorted(p.name for p in out.iterdir()) == [OUT_NAME[task]]  # refused before any work
    res = run_cli("batch", *TASK_ARGS[task][:1], "src", "out", *TASK_ARGS[task][1:], "--overwrite", "-q")
    assert res.exit_code == 0, res.stderr
    assert not mine.is_symlink() and mine.read_bytes() != b"my own file\n"


def test_resume_skips_and_replaces_only_what_the_batch_wrote(src: Path, run_cli, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert run_cli("batch", "prune", "src", "out", "-q").exit_code == 0
    res = run_cli("batch", "prune", "src", "out", "-q")  # unchanged: skipped
    assert res.exit_code == 0 and "2 unchanged and skipped" in res.stdout
    res = run_cli("batch", "prune", "src", "out", "--k", "8", "-q")  # other settings: its own outputs replaced
    assert res.exit_code == 0 and "2 done" in res.stdout, res.stderr
    # the user puts a file of their own where an output was: a change of settings no longer replaces it
    (out / "a.ply").unlink()
    (out / "a.ply").write_bytes(b"mine now\n")
    res = run_cli("batch", "prune", "src", "out", "--k", "4", "-q")
    expect_failure(res, 1, str(Path("out") / "a.ply"), "no earlier run")
    assert (out / "a.ply").read_bytes() == b"mine now\n"


@pytest.mark.parametrize("kept", ["writing lines", "no lines"])
def test_an_output_written_just_before_a_kill_is_known_as_the_batchs(kept: str, src: Path, run_cli,
                                                                     tmp_path: Path) -> None:
    """A batch killed after an output was put in place but before its result line: the worker's ``writing`` line,
    added just before, is enough for a re-run to know the output as its own; without it the output is a stranger's."""
    assert run_cli("batch", "prune", "src", "out", "-q").exit_code == 0
    results = tmp_path / "out" / "results.jsonl"
    lines = _results(results)
    assert sorted(line["item"] for line in lines if line["status"] == "writing") == ["a.ply", "b.spz"]
    keep = [line for line in lines if line["status"] == "writing"] if kept == "writing lines" else []
    results.write_text("".join(json.dumps(line) + "\n" for line in keep))
    res = run_cli("batch", "prune", "src", "out", "--k", "8", "-q")
    if kept == "writing lines":
        assert res.exit_code == 0 and "2 done" in res.stdout, res.stderr
    else:
        expect_failure(res, 1, "already exists", "--overwrite")


ANOTHER_PROGRAM = """
import sys
from pathlib import Path
from roodi_toolkit.batch import tasks
from roodi_toolkit.cli.main import main

real_read = tasks._read


def read_while_another_program_writes(path):
    if path.endswith("a.ply"):
        Path("out").mkdir(exist_ok=True)
        Path("out", "a.ply").write_bytes(b"another program's file\\n")
    return real_read(path)


tasks._read = read_while_another_program_writes
sys.exit(main(["batch", "prune", "src", "out", "-q"]))
"""


@pytest.mark.skipif(multiprocessing.get_start_method() != "fork",
                    reason="the workers must inherit the stand-in for another program (fork start method)")
def test_a_file_appearing_at_an_output_while_the_batch_runs_is_left_alone(src: Path, tmp_path: Path) -> None:
    # a fresh process: this one may have started the kernels' OpenMP threads, and its batches then start their
    # workers from a server process (forkserver), which would not inherit the stand-in
    res = subprocess.run([sys.executable, "-c", ANOTHER_PROGRAM], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 1, res.stderr
    assert (tmp_path / "out" / "a.ply").read_bytes() == b"another program's file\n"
    failed = [line for line in _results(tmp_path / "out" / "results.jsonl") if line["status"] == "failed"]
    assert [line["item"] for line in failed] == ["a.ply"] and "appeared while" in failed[0]["error"]
    assert (tmp_path / "out" / "b.ply").is_file()
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]


def test_a_batch_run_after_a_render_in_the_same_process_renders_in_its_workers() -> None:
    """A process forked after the kernels' OpenMP threads started is stopped by numba when it runs a kernel: the
    batch's pool then starts its workers otherwise, and they render."""
    from roodi_toolkit.batch.runner import _pool

    assert _render_sum() > 0  # the kernels' threads start here
    with _pool(1) as pool:
        assert pool.submit(_render_sum).result(timeout=300) == _render_sum()


def _render_sum() -> float:
    import torch

    from roodi_toolkit.render.fast import rasterize_fast
    from tests.render.test_rasterizer import call, random_scene

    return float(call(rasterize_fast, random_scene(n=50, dtype=torch.float32)).rgb.sum())


def test_an_output_folder_that_is_a_file_is_refused(src: Path, run_cli, tmp_path: Path) -> None:
    (tmp_path / "out").write_bytes(b"a file\n")
    res = run_cli("batch", "convert", "src", "out", "--to", ".ply", "-q")
    expect_failure(res, 1, "out", "not a folder")
    assert (tmp_path / "out").read_bytes() == b"a file\n"


# ------------------------------------------------------------------------------------------ per-item options
MANIFESTS = {
    "k=abc": ("m.csv", "input,k\nsrc/a.ply,abc\n", "k"),
    "k=1.5": ("m.csv", "input,k\nsrc/a.ply,1.5\n", "k"),
    "k=-3": ("m.csv", "input,k\nsrc/a.ply,-3\n", "k"),
    "rule=bogus": ("m.csv", "input,rule\nsrc/a.ply,bogus\n", "rule"),
    "filter_nan=maybe": ("m.csv", "input,filter_nan\nsrc/a.ply,maybe\n", "filter_nan"),
    "box=1,2": ("m.csv", 'input,box\nsrc/a.ply,"1,2"\n', "box"),
    "alpha=nan": ("m.csv", "input,alpha\nsrc/a.ply,nan\n", "alpha"),
    "unknown option": ("m.csv", "input,kk\nsrc/a.ply,3\n", "kk"),
    "JSON k=[1]": ("m.jsonl", '{"input": "src/a.ply", "options": {"k": [1]}}\n', "k"),
    "JSON k=null": ("m.jsonl", '{"input": "src/a.ply", "options": {"k": null}}\n', "k"),
    "JSON alpha=1e400": ("m.jsonl", '{"input": "src/a.ply", "options": {"alpha": 1e400}}\n', "alpha"),
    "JSON value_ranges=3": ("m.jsonl", '{"input": "src/a.ply", "options": {"value_ranges": 3}}\n', "value_ranges"),
    "JSON output=3": ("m.jsonl", '{"input": "src/a.ply", "output": 3}\n', "output"),
    "JSON nested deeply": ("m.jsonl", '{"input": "src/a.ply", "options": ' + "[" * 100_000 + "\n", "nested"),
    "JSON empty input": ("m.jsonl", '{"input": ""}\n', "input"),
    "a NUL byte": ("m.csv", "input\nsrc/a.ply\0\n", "NUL"),
    "a 200 KB cell": ("m.csv", "input,k\nsrc/a.ply," + "9" * 200_000 + "\n", "m.csv:2"),
    "input named twice": ("m.csv", "input,input\nsrc/a.ply,src/b.spz\n", "'input'"),
    "more cells than columns": ("m.csv", "input,k\nsrc/a.ply,8,9\n", "m.csv:2"),
    "an empty input cell": ("m.csv", 'input,k\n"",8\n', "empty"),
}


@pytest.mark.parametrize("case", list(MANIFESTS))
def test_bad_item_options_are_refused_before_any_work(case: str, src: Path, run_cli, tmp_path: Path) -> None:
    name, text, needle = MANIFESTS[case]
    (tmp_path / name).write_text(text)
    res = run_cli("batch", "prune", name, "out", "-q")
    expect_failure(res, 1, name, needle)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.ply"))


def test_a_manifest_with_a_byte_order_mark_is_read(src: Path, run_cli, tmp_path: Path) -> None:
    """Spreadsheets write CSV with a byte-order mark before the header: it is no part of 'input'."""
    (tmp_path / "m.csv").write_bytes(b"\xef\xbb\xbfinput,k\nsrc/a.ply,8\n")
    res = run_cli("batch", "prune", "m.csv", "out", "-q")
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "out" / "src" / "a.ply").is_file()


def test_convert_items_take_no_options(src: Path, run_cli, tmp_path: Path) -> None:
    (tmp_path / "m.csv").write_text("input,k\nsrc/a.ply,8\n")
    res = run_cli("batch", "convert", "m.csv", "out", "--to", ".spz", "-q")
    expect_failure(res, 1, "m.csv", "no per-item options", "k")


# ------------------------------------------------------------------------------------------ stopped by a signal
@pytest.mark.parametrize("how", ["SIGTERM to the batch",
                                 pytest.param("Ctrl-C to its process group", marks=pytest.mark.slow)])
def test_a_signal_stops_a_batch_at_once_and_keeps_what_finished(how: str, tmp_path: Path) -> None:
    """SIGTERM to the batch (not its workers), or Ctrl-C to all of them: the signal's exit code in seconds, not
    after the queue; every output present has its line (a re-run skips exactly those), no hidden temporary file, no
    traceback, and the re-run does the rest."""
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    (tmp_path / "in").mkdir()
    for i in range(8):
        write_ply(planted_floater_cloud(FloaterMix(n_object=20_000), seed=i).cloud, tmp_path / "in" / f"c{i}.ply")
    results = tmp_path / "out" / "results.jsonl"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    cmd = [sys.executable, "-m", "roodi_toolkit.cli.main", "batch", "prune", str(tmp_path / "in"),
           str(tmp_path / "out"), "--jobs", "2", "-q"]
    # Ctrl-C as a terminal sends it: a test run in the background (`cmd &` in a script) has SIGINT ignored, which the
    # batch would inherit
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while time.time() < deadline and (not results.is_file() or '"status": "ok"' not in results.read_text()):
        time.sleep(0.02)
    t0 = time.time()
    if how.startswith("SIGTERM"):
        proc.send_signal(signal.SIGTERM)
    else:
        os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    stopped = time.time() - t0
    assert proc.returncode == (143 if how.startswith("SIGTERM") else 130), err
    assert "Traceback" not in err.decode() and "Error" not in err.decode(), err
    assert stopped < 10, f"took {stopped:.1f} s to stop"
    done = {line["item"] for line in _results(results) if line["status"] == "ok"}
    written = {p.name for p in (tmp_path / "out").glob("*.ply")}
    assert written == done and 1 <= len(done) < 8
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert f"{8 - len(done)} done, {len(done)} unchanged and skipped" in res.stdout
