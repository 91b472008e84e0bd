"""The benchmark's evaluation in memory (evaluate/benchmark.py) and its truth read once per scene (run/benchmark.py)."""

from __future__ import annotations

import json

import numpy as np

from roodi_toolkit.evaluate.benchmark import empty_scores, score_object
from roodi_toolkit.run.evaluate import evaluate_object
from roodi_toolkit.run import benchmark as run_benchmark_module
from roodi_toolkit.run.benchmark import _LPIPS, _Truths, load_truth

from ..conftest import make_cloud


def _target(scene) -> int:
    return json.loads((scene / "scene.json").read_text())["targets"][0]["id"]


def test_scoring_in_memory_gives_what_scoring_the_folder_gives(tiny_kitchen):
    target = _target(tiny_kitchen)
    cloud = make_cloud(200, seed=4)
    cloud.means *= 0.3  # near the scene's middle, so that the views see some of it
    folder, renders = evaluate_object(cloud, tiny_kitchen, target)
    model, status = _LPIPS().get()
    memory, renders_now = score_object(cloud, load_truth(tiny_kitchen, target), lpips_model=model, lpips_status=status)
    assert memory.to_dict() == folder.to_dict()
    np.testing.assert_array_equal(renders_now, renders)
    empty = empty_scores(load_truth(tiny_kitchen, target))
    assert empty["iou"] == 0.0 and empty["lpips_status"] == "not computed: empty extraction"


def test_a_scenes_truth_is_read_once_for_every_method(tiny_kitchen, monkeypatch):
    calls = []
    read = run_benchmark_module.load_truth

    def counted(data, object_id):
        calls.append(object_id)
        return read(data, object_id)

    monkeypatch.setattr(run_benchmark_module, "load_truth", counted)
    truths = _Truths(tiny_kitchen)
    ids = [t["id"] for t in truths.targets]
    for _ in range(3):  # three methods score every target
        views = [truths[i] for i in ids]
    assert calls == ids and all(truths[i] is v for i, v in zip(ids, views))
