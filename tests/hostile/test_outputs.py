"""Outputs aimed at inputs: the same file by another spelling, a symbolic or hard link, a path inside an input
folder, two outputs that are one file. Every one is refused (exit 1, one line naming the output), with --overwrite
too, and every input stays byte-identical."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from .conftest import expect_failure


@pytest.fixture
def inputs(world, tmp_path: Path, monkeypatch) -> dict[str, Path]:
    """A private copy of the cloud (so links to it can be made beside it) and the world's folders; cwd = tmp_path."""
    ply = tmp_path / "in.ply"
    shutil.copyfile(world.ply, ply)
    (tmp_path / "link.ply").symlink_to(ply)
    os.link(ply, tmp_path / "hard.ply")
    (tmp_path / "sub").mkdir()
    (tmp_path / "dirlink").symlink_to(tmp_path)
    monkeypatch.chdir(tmp_path)
    return {"ply": ply}


SPELLINGS = ["in.ply", "./in.ply", "sub/../in.ply", "link.ply", "hard.ply", "dirlink/in.ply", "{abs}"]


@pytest.mark.parametrize("spelling", SPELLINGS)
@pytest.mark.parametrize("command", ["convert", "prune", "prune floaters", "prune report", "inspect"])
def test_output_over_the_input_by_any_spelling(command: str, spelling: str, inputs, run_cli) -> None:
    ply = inputs["ply"]
    before = ply.read_bytes()
    out = str(ply) if spelling == "{abs}" else spelling
    args = {"convert": ["convert", "in.ply", out, "--overwrite"],
            "prune": ["prune", "in.ply", out, "--overwrite", "-q"],
            "prune floaters": ["prune", "in.ply", "kept.ply", "--floaters-out", out, "--overwrite", "-q"],
            "prune report": ["prune", "in.ply", "kept.ply", "--report", out, "--overwrite", "-q"],
            "inspect": ["inspect", "in.ply", "--histogram", out, "--overwrite", "-q"]}[command]
    res = run_cli(*args)
    expect_failure(res, 1, str(Path(out)))
    assert ply.read_bytes() == before
    assert not Path("kept.ply").exists()


@pytest.mark.parametrize("pair", [("o.ply", "./o.ply"), ("o.ply", "sub/../o.ply"), ("o.ply", "dirlink/o.ply")])
def test_inspect_outputs_that_are_one_file(pair, inputs, run_cli) -> None:
    a, b = pair
    res = run_cli("inspect", "in.ply", "--histogram", a, "--screenshot", b, "-q")
    expect_failure(res, 1, "same file")
    assert not Path("o.ply").exists()


@pytest.mark.parametrize("pair", [("o.ply", "./o.ply"), ("o.ply", "dirlink/o.ply")])
def test_prune_outputs_that_are_one_file(pair, inputs, run_cli) -> None:
    a, b = pair
    res = run_cli("prune", "in.ply", a, "--floaters-out", b, "--alpha", "0.1", "-q")
    expect_failure(res, 1, b)
    assert not Path("o.ply").exists()


def _inside_cases():
    # (case, args; {data} {model} {dist} {gen} {ply} are the world's inputs), the output path named in the message
    return [
        ("select over the model PLY", "select {dist} {model}/point_cloud/iteration_7/point_cloud.ply --object 1 "
                                      "--overwrite -q", "point_cloud.ply"),
        ("select over the classifier", "select {dist} {dist}/object_classifier.pt --object 1 --overwrite -q",
         "object_classifier.pt"),
        ("select into the distillation", "select {dist} {dist}/new.ply --object 1 -q", "new.ply"),
        ("select into the model folder", "select {dist} {model}/new.ply --object 1 -q", "new.ply"),
        ("select picture into the model", "select {dist} {out}/o.ply --object 1 --picture {model}/p.png -q", "p.png"),
        ("evaluate json over scene.json", "evaluate {ply} {gen} --object 1 --json {gen}/scene.json --overwrite -q",
         "scene.json"),
        ("evaluate json into the scene", "evaluate {ply} {gen} --object 1 --json {gen}/scores.json -q",
         "scores.json"),
        ("evaluate renders into the scene", "evaluate {ply} {gen} --object 1 --renders {gen}/train --overwrite -q",
         "train"),
        ("evaluate json over the object", "evaluate {ply} {gen} --object 1 --json {ply} --overwrite -q", "cloud.ply"),
        ("render into the images", "render {ply} {data}/train --cameras {data}/transforms_train.json --overwrite -q",
         "train"),
        ("render into the dataset", "render {ply} {data}/renders --cameras {data} -q", "renders"),
        ("distill into the model", "distill {model} {data} {model}/d --iterations 1 -q", "d"),
        ("distill into the data", "distill {model} {data} {data}/d --iterations 1 -q", "d"),
        ("distill over the model", "distill {model} {data} {model} --iterations 1 --overwrite -q", ""),
        ("train into the data", "train {data} {data}/t --iterations 1 -q", "t"),
        ("train over the data", "train {data} {data} --iterations 1 --overwrite -q", ""),
        ("extract into the data", "extract {data} {data}/e --object 1 -q", "e"),
    ]


@pytest.mark.parametrize("name,args,needle", _inside_cases(), ids=[c[0] for c in _inside_cases()])
def test_output_inside_an_input_folder(name: str, args: str, needle: str, world, run_cli, tmp_path: Path) -> None:
    values = {"data": world.data, "model": world.model, "dist": world.dist, "gen": world.gen, "ply": world.ply,
              "root": world.ply.parent, "out": tmp_path}
    res = run_cli(*[a.format(**values) for a in args.split()])
    line = expect_failure(res, 1, needle)
    assert "input" in line
    assert world.unchanged()


BATCH_MANIFESTS = {
    "own input": ("src/a.ply,src/a.ply\n", "src/a.ply"),
    "own input by another spelling": ("src/a.ply,./src/../src/a.ply\n", "a.ply"),
    "own input through a link": ("src/a.ply,alink.ply\n", "alink.ply"),
    "another item's input": ("src/a.ply,src/b.ply\nsrc/b.ply,o.ply\n", "src/b.ply"),
    "two items, one file": ("src/a.ply,o.ply\nsrc/b.ply,./o.ply\n", "o.ply"),
}


@pytest.mark.parametrize("kind", list(BATCH_MANIFESTS))
def test_batch_manifest_outputs_over_inputs(kind: str, world, run_cli, tmp_path: Path, monkeypatch) -> None:
    rows, needle = BATCH_MANIFESTS[kind]
    (tmp_path / "src").mkdir()
    shutil.copyfile(world.ply, tmp_path / "src" / "a.ply")
    shutil.copyfile(world.spz, tmp_path / "src" / "b.ply")
    (tmp_path / "alink.ply").symlink_to(tmp_path / "src" / "a.ply")
    (tmp_path / "m.csv").write_text("input,output\n" + rows)
    monkeypatch.chdir(tmp_path)
    before = {p.name: p.read_bytes() for p in (tmp_path / "src").iterdir()}
    res = run_cli("batch", "prune", "m.csv", "out", "--alpha", "0.1", "-q")
    expect_failure(res, 1, needle)
    assert {p.name: p.read_bytes() for p in (tmp_path / "src").iterdir()} == before
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize("out", ["src", "src/out", "./src/../src/x"])
def test_batch_output_folder_inside_the_source(out: str, world, run_cli, tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "src").mkdir()
    shutil.copyfile(world.ply, tmp_path / "src" / "a.ply")
    monkeypatch.chdir(tmp_path)
    res = run_cli("batch", "prune", "src", out, "-q")
    expect_failure(res, 1, "inside the input folder")
    assert sorted(p.name for p in (tmp_path / "src").iterdir()) == ["a.ply"]


@pytest.mark.parametrize("args,needle", [(["prune", "--alpha", "nan"], "--alpha"), (["prune", "--k", "0"], "--k"),
                                         (["prune", "--jobs", "100000"], "--jobs"),
                                         (["convert", "--to", ".xyz"], "--to")])
def test_batch_bad_options(args, needle: str, world, run_cli, tmp_path: Path) -> None:
    res = run_cli("batch", args[0], world.ply.parent, tmp_path / "o", *args[1:])
    expect_failure(res, 2, needle)
    assert not (tmp_path / "o").exists()


@pytest.fixture
def sog_folder(tmp_path: Path) -> Path:
    """A SOG meta.json with its textures, as PlayCanvas and splat-transform write it."""
    from ..io.test_formats import encode_sog, make_cloud

    folder = tmp_path / "scene_sog"
    folder.mkdir()
    for name, data in encode_sog(make_cloud(300)).items():
        (folder / name).write_bytes(data)
    return folder


SOG_OUTPUTS = {"prune": "prune {meta} {sog}/clean.ply -q", "convert": "convert {meta} {sog}/sub/clean.spz",
               "inspect": "inspect {meta} --histogram {sog}/h.png -q",
               "render": "render {meta} {sog} --orbit 1 --size 16x16 --overwrite -q",
               "render frame-like": "render {tmp}/c.ply {sog}/v --frame-like {meta} --orbit 1 --size 16x16 -q"}


@pytest.mark.parametrize("command", list(SOG_OUTPUTS))
def test_a_sog_meta_json_guards_its_folder(command: str, sog_folder: Path, run_cli, tmp_path: Path) -> None:
    # meta.json names the textures beside it: its folder is the input, so nothing is written into it
    from roodi_toolkit import read_cloud, write_cloud

    write_cloud(read_cloud(sog_folder), tmp_path / "c.ply")
    before = {p.name: p.read_bytes() for p in sog_folder.iterdir()}
    res = run_cli(*SOG_OUTPUTS[command].format(meta=sog_folder / "meta.json", sog=sog_folder, tmp=tmp_path).split())
    expect_failure(res, 1, "inside the input folder", str(sog_folder))
    assert {p.name: p.read_bytes() for p in sog_folder.iterdir()} == before


def test_render_reads_a_sog_folder_and_frames_on_one(sog_folder: Path, run_cli, tmp_path: Path) -> None:
    res = run_cli("render", sog_folder, tmp_path / "v", "--orbit", "1", "--size", "16x16", "-q")
    assert res.exit_code == 0, res.stderr
    res = run_cli("render", sog_folder / "meta.json", tmp_path / "w", "--frame-like", sog_folder, "--orbit", "1",
                  "--size", "16x16", "-q")
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "v" / "orbit_000.png").read_bytes() == (tmp_path / "w" / "orbit_000.png").read_bytes()
