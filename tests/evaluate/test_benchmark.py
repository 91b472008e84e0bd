"""Baselines and the benchmark command on a tiny generated scene."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from roodi_toolkit.evaluate.baselines import click_in_mask, gaussian_grouping
from roodi_toolkit.pipeline.distill import DistillConfig, ObjectClassifier, with_features
from roodi_toolkit.errors import ConfigError, RoodiError
from roodi_toolkit.pipeline.extract import ExtractConfig
from roodi_toolkit.pipeline.finetune import FinetuneConfig
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.pipeline.occlusion import OcclusionConfig
from roodi_toolkit.pipeline.strategy import MCMCStrategy
from roodi_toolkit.pipeline.train import TrainConfig

from ..conftest import make_cloud


def test_gaussian_grouping_takes_the_argmax_class():
    cloud = make_cloud(6)
    feats = torch.eye(3)[[0, 1, 2, 1, 1, 0]].float()
    classifier = ObjectClassifier(torch.eye(3) * 5, torch.zeros(3))
    sel = gaussian_grouping(with_features(cloud, feats), classifier, 1)
    assert sel.keep.tolist() == [False, True, False, True, True, False] and len(sel.cloud) == 3
    assert not any(k.startswith("object_feature_") for k in sel.cloud.extras)
    assert gaussian_grouping(with_features(cloud, feats), classifier, 2, rule="threshold", threshold=0.9).keep.sum() == 1
    with pytest.raises(ConfigError):
        gaussian_grouping(with_features(cloud, feats), classifier, 7)
    with pytest.raises(ConfigError, match="threshold_hull"):
        gaussian_grouping(with_features(cloud, feats), classifier, 1, rule="magic")
    with pytest.raises(RoodiError, match="selected no Gaussian"):
        gaussian_grouping(with_features(cloud, torch.zeros(6, 3)), ObjectClassifier(torch.eye(3), torch.tensor([1., 0, 0])), 2)


def test_gaussian_grouping_code_rule_adds_the_convex_hull():
    # class 1 on the corners of a unit cube and one far stray; class 0 at the centre and outside the cube
    corners = [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    means = np.array(corners + [[9.0, 9.0, 9.0], [0.5, 0.5, 0.5], [3.0, 0.5, 0.5]])
    cloud = GaussianCloud.from_activated(means, scales=np.full((11, 3), 0.01), opacities=np.full(11, 0.9),
                                         rgb=np.full((11, 3), 0.5))
    feats = torch.eye(2)[[1] * 9 + [0, 0]].float()
    classifier = ObjectClassifier(torch.eye(2) * 5, torch.zeros(2))
    sel = gaussian_grouping(with_features(cloud, feats), classifier, 1, rule="threshold_hull")
    # the stray is outside 1x the interquartile range: it stays selected but does not stretch the hull
    assert sel.keep.tolist() == [True] * 9 + [True, False]
    assert sel.details["selected"] == 9 and sel.details["added_by_hull"] == 1 and sel.details["threshold"] == 0.3
    assert gaussian_grouping(with_features(cloud, feats), classifier, 1, rule="threshold").keep.sum() == 9


def test_click_lands_deepest_inside_the_mask():
    mask = np.zeros((20, 30), bool)
    mask[2:18, 3:13] = True  # a 10-wide bar: its middle column is deepest
    mask[8:12, 13:29] = True  # a thin arm
    x, y = click_in_mask(mask)
    assert mask[y, x] and 6 <= x <= 9 and 8 <= y <= 11
    with pytest.raises(ConfigError):
        click_in_mask(np.zeros((4, 4), bool))


TINY = ExtractConfig(
    train=TrainConfig(iterations=40, init="depth", init_num_points=800, eval_every=0,
                      strategy=MCMCStrategy(cap_max=1000, refine_start_iter=10, refine_every=10)),
    distill=DistillConfig(iterations=40), occlusion=OcclusionConfig(size=32, opening_reference=0, opening_size=5),
    finetune=FinetuneConfig(iterations=2))


def test_benchmark_runs_every_method_and_writes_the_tables(tiny_kitchen, tmp_path):
    from roodi_toolkit.evaluate.benchmark import ABLATIONS, MACHINE_SIZE, METHODS
    from roodi_toolkit.run.benchmark import run_benchmark

    root = tmp_path / "scenes"
    root.mkdir()
    (root / "kitchen").symlink_to(tiny_kitchen)  # reused as it is
    results = run_benchmark(root, tmp_path / "bench", presets=["kitchen"], size=MACHINE_SIZE, config=TINY)
    assert list(results["mean"]) == list(METHODS)
    targets = json.loads((tiny_kitchen / "scene.json").read_text())["targets"]
    for m in METHODS:
        rows = results["scenes"]["kitchen"][m]["objects"]
        assert len(rows) == len(targets)
        assert all(0 <= r["iou"] <= 1 for r in rows)
    saved = json.loads((tmp_path / "bench" / "results.json").read_text())
    assert {c["check"] for c in saved["checks"]} >= {"full - Gaussian Grouping IoU >= 0.3"}
    assert len([c for c in saved["checks"] if c["met"] is not None]) == 2 + len(ABLATIONS)
    # Gaussian Grouping as its authors run it selects from the jointly trained model; the shared variant from ours
    kitchen = tmp_path / "bench" / "kitchen"
    first = f"object_{targets[0]['id']}"
    joint = json.loads((kitchen / "gaussian_grouping" / first / "selection.json").read_text())
    argmax = json.loads((kitchen / "gaussian_grouping_argmax" / first / "selection.json").read_text())
    shared = json.loads((kitchen / "gaussian_grouping_shared" / first / "selection.json").read_text())
    assert Path(joint["model"]) == Path(argmax["model"]) == kitchen / "no_two_stage" / "scene"
    assert Path(shared["model"]) == kitchen / "full" / "scene"
    assert (joint["rule"], argmax["rule"], shared["rule"]) == ("threshold_hull", "argmax", "argmax")
    md = (tmp_path / "bench" / "results.md").read_text()
    assert "Table 1" in md and "Table 2" in md and "36.12" in md and "w/o two-stage" in md
    assert (tmp_path / "bench" / "kitchen.png").stat().st_size > 5000
    sim = json.loads((tmp_path / "bench" / "kitchen" / "feature_similarity" / f"object_{targets[0]['id']}"
                      / "selection.json").read_text())
    assert 0.5 <= sim["threshold"] <= 0.99 and sim["train_mask_iou"] is not None
    # scores are kept per scene (presets can run side by side); a re-run reuses everything: same scores
    assert set(json.loads((kitchen / "scores.json").read_text())) == {
        f"kitchen/{m}/{t['id']}" for m in METHODS for t in targets}
    assert not (tmp_path / "bench" / "scores.json").exists()
    again = run_benchmark(root, tmp_path / "bench", presets=["kitchen"], size=MACHINE_SIZE, config=TINY)
    assert again["mean"] == results["mean"]
    # a baseline extracted with another selection rule (an older version) is made again, and scored again
    record = kitchen / "gaussian_grouping" / first / "selection.json"
    record.write_text(json.dumps({**joint, "rule": "argmax"}))
    (kitchen / "gaussian_grouping" / first / "object.ply").write_bytes(
        (kitchen / "gaussian_grouping_argmax" / first / "object.ply").read_bytes())
    scores = json.loads((kitchen / "scores.json").read_text())
    key = f"kitchen/gaussian_grouping/{targets[0]['id']}"
    scores[key]["psnr"] = -1.0  # the stale extraction's score, which must not survive
    (kitchen / "scores.json").write_text(json.dumps(scores))
    third = run_benchmark(root, tmp_path / "bench", presets=["kitchen"], size=MACHINE_SIZE, config=TINY)
    assert json.loads(record.read_text())["rule"] == "threshold_hull"
    assert json.loads((kitchen / "scores.json").read_text())[key]["psnr"] != -1.0
    assert third["mean"] == results["mean"]
    assert not again["recomputed"]
    # an object that changed since it was scored (an extraction redone with other settings) is scored again, and said
    full_ply = kitchen / "full" / first / "object.ply"
    full_ply.write_bytes((kitchen / "gaussian_grouping_argmax" / first / "object.ply").read_bytes())
    fourth = run_benchmark(root, tmp_path / "bench", presets=["kitchen"], size=MACHINE_SIZE, config=TINY,
                           methods=["full"])
    assert f"kitchen/full/{targets[0]['id']}" in fourth["recomputed"]


def test_benchmark_command_errors(tmp_path, run_cli):
    res = run_cli("benchmark", tmp_path / "r", tmp_path / "o", "--preset", "attic", "-q")
    assert res.exit_code == 1 and "unknown preset" in res.stderr
    res = run_cli("benchmark", tmp_path / "r", tmp_path / "o2", "--method", "magic", "-q")
    assert res.exit_code == 1 and "unknown method" in res.stderr


@pytest.mark.parametrize("kwargs,message", [
    ({"size": 8}, "size must be a whole number in [16, 2048], got 8"),
    ({"iterations": 0}, "iterations must be a whole number >= 1"),
    ({"train_views": 0}, "train_views must be a whole number >= 1"),
    ({"supersample": 5}, "supersample must be a whole number in [1, 4]"),
    ({"cap_max": 1.5}, "cap_max must be a whole number >= 1"),
])
def test_benchmark_sizes_outside_their_declared_range_are_refused_by_name(kwargs, message):
    from roodi_toolkit.evaluate.benchmark import BenchmarkSize, SIZES

    with pytest.raises(ConfigError) as err:
        BenchmarkSize(**kwargs)
    assert str(err.value).startswith(message), str(err.value)
    assert all(isinstance(size, BenchmarkSize) for size in SIZES.values())  # the presets are inside


def test_benchmark_never_writes_over_a_foreign_folder(tmp_path, run_cli):
    (tmp_path / "r" / "picnic").mkdir(parents=True)
    (tmp_path / "r" / "picnic" / "notes.txt").write_text("mine")
    res = run_cli("benchmark", tmp_path / "r", tmp_path / "o", "--preset", "picnic", "-q")
    assert res.exit_code == 1 and "no scene.json" in res.stderr
    assert (tmp_path / "r" / "picnic" / "notes.txt").read_text() == "mine"


def test_a_missing_scene_is_made_by_the_make_scene_passed_in_and_refused_without_one(tiny_kitchen, tmp_path,
                                                                                     monkeypatch):
    """The benchmark reuses the scenes in ROOT; one missing is generated by the caller's make_scene (the generator is
    on the floor above the benchmark's), and without one it is refused by name before anything is written."""
    from roodi_toolkit.run import benchmark

    def fail(method, data, out, object_id, *args):  # no extraction: this test is about the scene
        raise ConfigError("not extracted")

    calls = []

    def make(folder, preset, seed, size, occluded, progress):
        calls.append((folder, preset, seed, size, occluded))
        folder.symlink_to(tiny_kitchen)

    monkeypatch.setattr(benchmark, "_extract_one", fail)
    root, out = tmp_path / "scenes", tmp_path / "bench"
    with pytest.raises(ConfigError, match=r"kitchen: no scene\.json"):
        benchmark.run_benchmark(root, out, presets=["kitchen"], methods=["full"], config=TINY)
    assert not root.exists() and not out.exists()
    results = benchmark.run_benchmark(root, out, presets=["kitchen"], seed=3, methods=["full"], config=TINY,
                                      make_scene=make)
    assert calls == [(root / "kitchen", "kitchen", 3, benchmark.MACHINE_SIZE, False)]
    assert [r["failed"] for r in results["scenes"]["kitchen"]["full"]["objects"]] == ["not extracted"] * 3
    benchmark.run_benchmark(root, out, presets=["kitchen"], seed=3, methods=["full"], config=TINY, make_scene=make)
    assert len(calls) == 1  # made once, then reused


def test_a_failed_extraction_scores_as_an_empty_one_with_its_message(tiny_kitchen, tmp_path, monkeypatch):
    """An extraction that fails (a RoodiError) costs the method that object's score, not the run: the row holds the
    scores of an empty extraction (a white render, nothing covered) and the message."""
    from roodi_toolkit.run import benchmark

    def fail(method, data, out, object_id, *args):
        raise ConfigError(f"object {object_id}: nothing selected")

    monkeypatch.setattr(benchmark, "_extract_one", fail)
    root = tmp_path / "scenes"
    root.mkdir()
    (root / "kitchen").symlink_to(tiny_kitchen)
    results = benchmark.run_benchmark(root, tmp_path / "bench", presets=["kitchen"], methods=["full"], config=TINY)
    targets = json.loads((tiny_kitchen / "scene.json").read_text())["targets"]
    rows = results["scenes"]["kitchen"]["full"]["objects"]
    assert [r["failed"] for r in rows] == [f"object {t['id']}: nothing selected" for t in targets]
    assert all(r["iou"] == 0.0 and r["gaussians"] == 0 for r in rows)
    assert results["mean"]["full"]["iou"] == 0.0
