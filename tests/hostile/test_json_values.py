"""JSON in and out: every JSON a command reads, nested a hundred thousand deep (Python's parser gives up with a
RecursionError) or valid but of the wrong shape, is refused in one line naming it; every JSON a command writes is
strict JSON (no bare NaN or Infinity); and a cloud of NaN is not scored as if it were an object."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from .conftest import expect_failure

DEEP = "[" * 100_000
SHALLOW_WRONG = "[" * 500 + "]" * 500  # parses; a list where an object belongs


def _strict(text: str):
    """Parse ``text`` as strict JSON: NaN, Infinity and -Infinity are errors, as in JavaScript's JSON.parse."""
    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


# reader -> (the JSON file to spoil, relative to the copied folder; how to run the command that reads it)
READERS = {
    "transforms (render --cameras)": ("data", "transforms_train.json",
                                      "render {ply} {tmp}/r --cameras {copy}/transforms_train.json -q"),
    "transforms (train)": ("data", "transforms_train.json", "train {copy} {tmp}/t --iterations 1 -q"),
    "cfg.json (prune --photos)": ("model", "cfg.json", "prune {ply} {tmp}/o.ply --photos {copy} -q"),
    "cfg.json (distill)": ("model", "cfg.json", "distill {copy} {data} {tmp}/d --iterations 1 -q"),
    "scene.json (evaluate)": ("gen", "scene.json", "evaluate {ply} {copy} --object 1 -q"),
    "distill.json (select)": ("dist", "distill.json", "select {copy} {tmp}/o.ply --object 1 -q"),
}


@pytest.mark.parametrize("text", [DEEP, SHALLOW_WRONG], ids=["100000 deep", "500 deep, wrong shape"])
@pytest.mark.parametrize("reader", list(READERS))
def test_json_readers_refuse_deep_or_misshapen_json(reader: str, text: str, world, run_cli, tmp_path: Path) -> None:
    folder, name, args = READERS[reader]
    copy = _copy(getattr(world, folder), tmp_path / "copy")
    (copy / name).write_text(text)
    res = run_cli(*args.format(ply=world.ply, data=world.data, copy=copy, tmp=tmp_path).split())
    expect_failure(res, 1, name)
    assert world.unchanged()


def test_render_up_auto_with_a_deep_cfg_json(world, run_cli, tmp_path: Path) -> None:
    """render reads a model's cfg.json for its cameras' up; one it cannot read means no cameras (no RecursionError):
    --up auto then falls back to what the cloud says (render/upright.py), and the view is written."""
    copy = _copy(world.model, tmp_path / "copy")
    (copy / "cfg.json").write_text(DEEP)
    res = run_cli("render", copy / "point_cloud" / "iteration_7" / "point_cloud.ply", tmp_path / "r", "--orbit", "1",
                  "--size", "8x8", "--up", "auto", "-q")
    assert res.exit_code == 0, (res.exit_code, res.stderr)
    assert "Recursion" not in res.stderr and "unexpected" not in res.stderr
    assert any((tmp_path / "r").iterdir())


@pytest.mark.parametrize("text", [DEEP, '{"version": 2, "count": ' + "[" * 600 + "]" * 600 + "}"],
                         ids=["100000 deep", "count a nested list"])
def test_sog_meta_json_deep_or_misshapen(text: str, run_cli, tmp_path: Path) -> None:
    import zipfile

    f = tmp_path / "deep.sog"
    with zipfile.ZipFile(f, "w") as z:
        z.writestr("meta.json", text)
    expect_failure(run_cli("info", f), 1, "deep.sog", "meta.json")


# ------------------------------------------------------------------------------------------ JSON written
@pytest.fixture
def nan_cloud(tmp_path: Path) -> Path:
    """Every opacity NaN (info's opacity statistics are NaN), some centres infinite."""
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    c = make_cloud(40, seed=2)
    c.opacity_logits[:] = np.nan
    c.means[3] = np.inf
    c.means[4] = -np.inf
    return write_ply(c, tmp_path / "bad.ply")


def test_info_json_is_strict_json(nan_cloud: Path, run_cli) -> None:
    res = run_cli("info", nan_cloud, "--json")
    assert res.exit_code == 0
    doc = _strict(res.stdout)
    assert doc["nonfinite_rows"] == 40 and doc["opacity"]["median"] is None


def test_prune_report_is_strict_json(run_cli, tmp_path: Path) -> None:
    """Log scales of 80 overflow the statistical rule's W2 distances: its statistics are NaN."""
    from roodi_toolkit.io.ply import write_ply
    from tests.conftest import make_cloud

    c = make_cloud(60, seed=2)
    c.log_scales[:] = 80.0
    f = write_ply(c, tmp_path / "wide.ply")
    res = run_cli("prune", f, tmp_path / "o.ply", "--mode", "statistical", "--report", tmp_path / "r.json", "-q")
    assert res.exit_code == 0, res.stderr
    report = _strict((tmp_path / "r.json").read_text())
    assert report["statistics"]["mean"] is None


def test_batch_info_outputs_and_lines_are_strict_json(nan_cloud: Path, run_cli, tmp_path: Path) -> None:
    res = run_cli("batch", "info", nan_cloud, tmp_path / "out", "-q")
    assert res.exit_code == 0, res.stderr
    assert _strict((tmp_path / "out" / "bad.json").read_text())["opacity"]["median"] is None
    for line in (tmp_path / "out" / "results.jsonl").read_text().splitlines():
        _strict(line)


def test_evaluate_refuses_a_cloud_of_nan(world, run_cli, tmp_path: Path) -> None:
    from roodi_toolkit.io.ply import read_ply, write_ply

    cloud = read_ply(world.ply)
    cloud.means[:] = np.nan
    f = write_ply(cloud, tmp_path / "nan.ply")
    res = run_cli("evaluate", f, world.gen, "--object", "1", "--json", tmp_path / "s.json", "-q")
    expect_failure(res, 1, "nan.ply", "--filter-nan")
    assert not (tmp_path / "s.json").exists()
