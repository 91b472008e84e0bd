"""batch: many items on a process pool or Ray; results as JSON lines; failures isolated; resumable."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit import read_ply, write_ply
from roodi_toolkit.batch.items import Item, collect_items
from roodi_toolkit.batch.runner import run_batch
from roodi_toolkit.batch.tasks import settings_for
from roodi_toolkit.errors import InputError
from roodi_toolkit.prune.outliers import PruneConfig
from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud


def _clouds(folder: Path, n: int, size: int = 2000) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        sub = folder / ("a" if i % 2 else "b")
        sub.mkdir(exist_ok=True)
        paths.append(write_ply(planted_floater_cloud(FloaterMix(n_object=size), seed=i).cloud, sub / f"c{i}.ply"))
    return paths


def _lines(path: Path) -> list[dict]:
    """The result lines of a results file (without the ``writing`` lines workers add before an output is placed)."""
    return [line for line in map(json.loads, path.read_text().splitlines()) if line["status"] != "writing"]


def test_batch_prune_matches_single_runs_and_isolates_a_corrupt_file(tmp_path, run_cli):
    paths = _clouds(tmp_path / "in", 3)
    (tmp_path / "in" / "broken.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 5\n")
    r = run_cli("batch", "prune", tmp_path / "in", tmp_path / "out", "--jobs", "2", "-q")
    assert r.exit_code == 1 and "1 of 4 items failed" in r.stderr and "broken.ply" in r.stderr
    lines = {line["item"]: line for line in _lines(tmp_path / "out" / "results.jsonl")}
    assert lines["broken.ply"]["status"] == "failed" and "broken.ply" in lines["broken.ply"]["error"]
    for p in paths:
        rel = p.relative_to(tmp_path / "in").as_posix()
        assert lines[rel]["status"] == "ok" and lines[rel]["seconds"] > 0
        single = tmp_path / f"single_{p.name}"
        assert run_cli("prune", p, single, "-q").exit_code == 0
        assert (tmp_path / "out" / rel).read_bytes() == single.read_bytes()  # identical to a single run
    # a re-run skips what is done and unchanged; the corrupt item is tried again
    r = run_cli("batch", "prune", tmp_path / "in", tmp_path / "out", "--jobs", "2", "-q")
    again = _lines(tmp_path / "out" / "results.jsonl")[4:]
    assert sorted(line["status"] for line in again) == ["failed", "skipped", "skipped", "skipped"]
    # other settings: every item runs again
    r = run_cli("batch", "prune", tmp_path / "in", tmp_path / "out", "--k", "8", "-q")
    third = _lines(tmp_path / "out" / "results.jsonl")[8:]
    assert sorted(line["status"] for line in third) == ["failed", "ok", "ok", "ok"]


def test_manifest_options_per_item_and_changed_inputs(tmp_path):
    paths = _clouds(tmp_path / "in", 2)
    manifest = tmp_path / "m.csv"
    rows = [f"{paths[0]},{tmp_path / 'o' / 'x.ply'},8", f"{paths[1].relative_to(tmp_path).as_posix()},o/y.ply,"]
    manifest.write_text("\n".join(["input,output,k", *rows]) + "\n")
    items = collect_items(str(manifest), str(tmp_path / "o"), suffix=".ply")
    assert [i.options for i in items] == [{"k": 8}, {}] and items[1].output == str(tmp_path / "o" / "y.ply")
    results = tmp_path / "r.jsonl"
    settings = settings_for("prune", prune_config=PruneConfig())
    summary = run_batch("prune", items, results, settings=settings)
    assert summary.ok == 2 and summary.lines[0]["kept"] < summary.lines[0]["input_count"]
    # an input that changes is run again; the other is skipped
    time.sleep(0.01)
    write_ply(read_ply(paths[1]).select(np.arange(1500)), paths[1])
    summary = run_batch("prune", items, results, settings=settings)
    assert [line["status"] for line in summary.lines] == ["skipped", "ok"]
    assert summary.lines[1]["input_count"] == 1500
    bad = [Item("x", str(paths[0]), str(tmp_path / "z.ply"), {"kk": 3})]
    line = run_batch("prune", bad, results, settings=settings).lines[0]
    assert line["status"] == "failed" and "unknown prune option(s) kk" in line["error"]


def test_sources_and_their_errors(tmp_path):
    _clouds(tmp_path / "in", 2)
    assert len(collect_items(str(tmp_path / "in"), "out", suffix=".spz")) == 2
    items = collect_items(str(tmp_path / "in" / "**" / "*.ply"), "out", suffix=".spz")
    assert sorted(i.output for i in items) == [str(Path("out") / "a" / "c1.spz"), str(Path("out") / "b" / "c0.spz")]
    with pytest.raises(InputError, match="no such"):
        collect_items(str(tmp_path / "nope"), "out", suffix=".ply")
    (tmp_path / "m.jsonl").write_text('{"input": 3}\n')
    with pytest.raises(InputError, match="m.jsonl:1"):
        collect_items(str(tmp_path / "m.jsonl"), "out", suffix=".ply")


def test_info_and_fsspec_output(tmp_path):
    paths = _clouds(tmp_path / "in", 2)
    items = collect_items(str(tmp_path / "in"), f"file://{tmp_path / 'remote'}", suffix=".json")
    summary = run_batch("info", items, tmp_path / "r.jsonl")
    assert summary.ok == 2
    described = json.loads((tmp_path / "remote" / "a" / "c1.json").read_text())
    assert described["count"] == len(read_ply(paths[1]))


def test_killed_batch_resumes_with_only_the_missing_items(tmp_path):
    _clouds(tmp_path / "in", 8, size=20_000)
    results = tmp_path / "out" / "results.jsonl"
    cmd = [sys.executable, "-m", "roodi_toolkit.cli.main", "batch", "prune", str(tmp_path / "in"),
           str(tmp_path / "out"), "-q"]
    proc = subprocess.Popen(cmd, start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline and (not results.is_file() or results.read_text().count('"status": "ok"') < 2):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the batch and its workers, mid-item
    proc.wait()
    done = {line["item"] for line in _lines(results) if line["status"] == "ok"}
    assert 2 <= len(done) < 8
    # nothing half written under a final name: every output present is a whole PLY
    for ply in (tmp_path / "out").rglob("*.ply"):
        if not ply.name.startswith("."):  # a killed worker's hidden temporary file is no output
            read_ply(ply)
    assert subprocess.run(cmd).returncode == 0
    rerun = _lines(results)[len(done):]
    assert {line["item"] for line in rerun if line["status"] == "skipped"} == done
    assert len([line for line in rerun if line["status"] == "ok"]) == 8 - len(done)


def test_ray_local_gives_the_same_outputs(tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'roodi-toolkit[ray]')")
    del ray
    _clouds(tmp_path / "in", 3)
    items = collect_items(str(tmp_path / "in"), str(tmp_path / "pool"), suffix=".ply")
    settings = settings_for("prune", prune_config=PruneConfig())
    assert run_batch("prune", items, tmp_path / "p.jsonl", settings=settings, jobs=2).ok == 3
    ray_items = collect_items(str(tmp_path / "in"), str(tmp_path / "ray"), suffix=".ply")
    summary = run_batch("prune", ray_items, tmp_path / "r.jsonl", settings=settings, jobs=2, ray="local")
    assert summary.ok == 3
    for a, b in zip(items, ray_items):
        assert Path(a.output).read_bytes() == Path(b.output).read_bytes()


def test_batch_extract_every_object_shares_the_scene(tiny_kitchen, tmp_path, run_cli):
    args = ["--iterations", "30", "--init", "depth", "--distill-iterations", "20", "--no-inpaint"]
    r = run_cli("batch", "extract", tiny_kitchen, tmp_path / "o", "--object", "all", "--jobs", "2", "-q", *args)
    lines = _lines(tmp_path / "o" / "results.jsonl")
    classes = len(json.loads((tmp_path / "o" / "distill" / "distill.json").read_text())["labels"])
    assert sorted(line["item"] for line in lines) == sorted(f"object_{i}" for i in range(1, classes))
    failed = [line for line in lines if line["status"] == "failed"]
    # so short a training leaves a small object without Gaussians: its line says so, the others complete
    assert r.exit_code == (1 if failed else 0) and all("no Gaussian has a probability" in f["error"] for f in failed)
    lines = [line for line in lines if line["status"] == "ok"]
    assert len(lines) >= 3
    assert len({line["pid"] for line in lines}) <= 2  # two workers, each loading the scene once
    for line in lines:
        assert len(read_ply(line["object_ply"])) == line["gaussians"]
    # the same objects through extract in one process: the same PLYs
    one = lines[0]["item"].split("_")[1]
    r = run_cli("extract", tiny_kitchen, tmp_path / "single", "--object", one, "-q", *args)
    assert r.exit_code == 0, r.stderr
    single = tmp_path / "single" / f"object_{one}" / "object.ply"
    assert single.read_bytes() == Path(lines[0]["object_ply"]).read_bytes()
    r = run_cli("batch", "extract", tiny_kitchen, tmp_path / "o", "--object", "all", "-q", *args)
    assert f"0 done, {len(lines)} unchanged and skipped" in r.stdout


def test_batch_convert_matches_the_convert_command(tmp_path, run_cli):
    paths = _clouds(tmp_path / "in", 2)
    r = run_cli("batch", "convert", tmp_path / "in", tmp_path / "out", "--to", ".spz", "-q")
    assert r.exit_code == 0, r.stderr
    for p in paths:
        rel = p.relative_to(tmp_path / "in").with_suffix(".spz")
        single = tmp_path / f"single_{p.stem}.spz"
        assert run_cli("convert", p, single).exit_code == 0
        assert (tmp_path / "out" / rel).read_bytes() == single.read_bytes()


def test_manifest_options_are_read_as_the_prune_settings_declare_them():
    """A manifest's columns are PruneConfig's settings, read from their declarations: a fixed tuple as the command
    line writes it, a repeatable one as ';'-separated entries or a JSON list, numbers from text."""
    from roodi_toolkit.batch.tasks import prune_config
    from roodi_toolkit.errors import ConfigError

    config = prune_config({}, {"k": "12", "box": "-1,-1,-1,1,1,1", "value_ranges": "scale,0,0.5;z,-1,10"})
    assert config.k == 12 and config.box == (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0)
    assert config.value_ranges == (("scale", 0.0, 0.5), ("z", -1.0, 10.0))
    json_form = prune_config({}, {"box": [-1, -1, -1, 1, 1, 1], "value_ranges": [["scale", 0, 0.5], "z,-1,10"]})
    assert json_form.box == config.box and json_form.value_ranges == config.value_ranges
    for bad in ({"box": "1,2"}, {"value_ranges": 3}, {"value_ranges": "size,0,1"}, {"sphere": [0, 0, "x", 1]}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            prune_config({}, bad)
