"""``roodi-toolkit prune``: outputs, columns and order, floaters, report, NaN rows, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from roodi_toolkit.io.ply import read_ply, write_ply
from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud


@pytest.fixture
def scene(tmp_path):
    planted = planted_floater_cloud(FloaterMix("sphere", n_object=3000, far_fraction=0.01, near_fraction=0.01), 0)
    cloud = planted.cloud
    cloud.extras["label"] = planted.labels.astype(np.int32)
    cloud.extras["weight"] = np.linspace(0, 1, len(cloud))
    path = tmp_path / "in.ply"
    write_ply(cloud, path)
    return path, cloud


def test_prune_writes_kept_floaters_and_report(run_cli, scene, tmp_path):
    path, cloud = scene
    before = path.read_bytes()
    out, fl, rep = tmp_path / "out.ply", tmp_path / "fl.ply", tmp_path / "r.json"
    res = run_cli("prune", path, out, "--floaters-out", fl, "--report", rep, "--mode", "statistical")
    assert res.exit_code == 0, res.stderr
    assert "kept" in res.stdout
    kept, floaters = read_ply(out), read_ply(fl)
    assert len(kept) + len(floaters) == len(cloud)
    assert list(kept.extras) == ["label", "weight"]
    assert np.all(np.diff(kept.extras["weight"]) > 0)  # input order
    assert (kept.extras["label"] == 0).mean() > 0.999 and (floaters.extras["label"] != 0).mean() > 0.95
    summary = json.loads(rep.read_text())
    assert summary["kept_count"] == len(kept) and summary["input_count"] == len(cloud)
    assert summary["config"]["rule"] == "robust" and summary["threshold"] > 0
    assert {"read", "write", "neighbours_and_distances", "rule"} <= set(summary["timings_s"])
    assert path.read_bytes() == before
    # the same keep mask through the library
    from roodi_toolkit.prune.outliers import remove_statistical_outliers

    _, keep, _ = remove_statistical_outliers(read_ply(path))
    np.testing.assert_array_equal(kept.means, cloud.means[keep])


def test_prune_options_and_overwrite(run_cli, scene, tmp_path):
    path, cloud = scene
    out = tmp_path / "out.ply"
    res = run_cli("prune", path, out, "--rule", "paper", "--alpha", "2", "--k", "8", "--distance", "euclidean",
                  "--min-opacity", "0.05", "--filter-box", "-3,-3,-3,3,3,3", "--filter-sphere", "0,0,0,2.5")
    assert res.exit_code == 0, res.stderr
    res = run_cli("prune", path, out)
    assert res.exit_code == 1 and "--overwrite" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert run_cli("prune", path, out, "--overwrite", "--neighbors", "w2").exit_code == 0
    res = run_cli("prune", path, out, "--overwrite", "--neighbors", "w2", "--distance", "euclidean")
    assert res.exit_code == 1 and "needs distance 'w2'" in res.stderr
    res = run_cli("prune", path, out, "--overwrite", "--filter-box", "1,2,3")
    assert res.exit_code == 2 and "--filter-box" in res.stderr
    res = run_cli("prune", path, path, "--overwrite")
    assert res.exit_code == 1 and "same file" in res.stderr
    res = run_cli("prune", path, out, "--overwrite", "--foreign-size", "0.5")
    assert res.exit_code == 1 and "foreign_size" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = run_cli("prune", path, out, "--overwrite", "--foreign-size", "0", "--report", tmp_path / "r.json")
    assert res.exit_code == 0 and json.loads((tmp_path / "r.json").read_text())["statistics"]["oversized_foreign"] == 0


def test_nan_rows_error_without_filter_and_dropped_with_it(run_cli, scene, tmp_path):
    path, cloud = scene
    means = cloud.means.copy()
    means[[3, 10]] = np.nan
    bad = tmp_path / "nan.ply"
    write_ply(cloud.with_fields(means=means), bad)
    out = tmp_path / "out.ply"
    res = run_cli("prune", bad, out)
    assert res.exit_code == 1 and "--filter-nan" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not out.exists()
    res = run_cli("prune", bad, out, "--filter-nan", "--report", tmp_path / "r.json")
    assert res.exit_code == 0, res.stderr
    assert np.isfinite(read_ply(out).means).all()
    stages = {s["stage"]: s["removed"] for s in json.loads((tmp_path / "r.json").read_text())["stages"]}
    assert stages["nonfinite"] == 2


@pytest.mark.parametrize("kind", ["missing", "folder", "not_ply", "truncated", "empty"])
def test_bad_input_is_one_line_and_exit_1(run_cli, scene, tmp_path, kind):
    path, _ = scene
    target = tmp_path / f"{kind}.ply"
    if kind == "folder":
        target.mkdir()
    elif kind == "not_ply":
        target.write_text("hello, I am not a PLY\n")
    elif kind == "truncated":
        target.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif kind == "empty":
        target.write_bytes(b"")
    before = target.read_bytes() if target.is_file() else None
    out = tmp_path / "out.ply"
    res = run_cli("prune", target, out)
    assert res.exit_code == 1
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not out.exists()
    if before is not None:
        assert target.read_bytes() == before


def test_help_lists_prune(run_cli):
    res = run_cli("--help")
    assert "prune" in res.stdout
    res = run_cli("prune", "--help")
    assert res.exit_code == 0 and "--floaters-out" in res.stdout


def test_nothing_removed_writes_no_floater_file(run_cli, tmp_path):
    import numpy as np

    from roodi_toolkit import GaussianCloud, write_ply

    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)  # a ring: every Gaussian has the same neighbourhood
    ring = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], 1) * 10
    cloud = GaussianCloud.from_activated(ring, scales=np.full((200, 3), 0.2), opacities=np.full(200, 0.9),
                                         rgb=np.full((200, 3), 0.5))
    src = tmp_path / "ring.ply"
    write_ply(cloud, src)
    res = run_cli("prune", src, tmp_path / "o.ply", "--floaters-out", tmp_path / "f.ply", "-q")
    assert res.exit_code == 0, res.stderr
    assert "nothing was removed" in res.stdout
    assert (tmp_path / "o.ply").exists() and not (tmp_path / "f.ply").exists()
