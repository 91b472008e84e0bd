"""Tests of the never-seen region metrics (issue 22): the definitions on hand-made arrays, evaluate on an occluded
scene, and the benchmark's averages, checks and tables."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit.evaluate.benchmark import _average, checks, results_markdown
from roodi_toolkit.evaluate.metrics import Evaluation, region_scores, score_views
from roodi_toolkit.io.files import read_json
from roodi_toolkit.run.evaluate import evaluate_object, load_never_seen
from roodi_toolkit.synth.scene import SceneSettings, make_scene, scene_from_record
from tests.mesh_gaussians import mesh_cloud


def _region(h: int = 32, w: int = 32) -> np.ndarray:
    m = np.zeros((h, w), bool)
    m[8:16, 10:20] = True  # 80 pixels
    return m


def test_identical_views_score_perfectly() -> None:
    rng = np.random.default_rng(0)
    truth = rng.uniform(size=(32, 32, 3)).astype(np.float32)
    alpha = np.ones((32, 32), np.float32)
    s = region_scores(truth, alpha, truth, alpha, _region())
    assert s["ns_psnr"] == math.inf and s["ns_ssim"] == pytest.approx(1.0, abs=1e-6) and s["ns_iou"] == 1.0
    assert s["ns_pixels"] == 80 and s["ns_lpips"] is None


def test_known_differences() -> None:
    truth = np.full((32, 32, 3), 0.5, np.float32)
    render = truth.copy()
    region = _region()
    render[region] = 0.6  # 0.1 off in every channel of the region: MSE 0.01 -> 20 dB
    render[0:4, 0:4] = 0.0  # far outside the region: must not count
    alpha = np.ones((32, 32), np.float32)
    s = region_scores(render, alpha, truth, alpha, region)
    assert s["ns_psnr"] == pytest.approx(20.0, abs=1e-4)
    # half the region's error: MSE 0.005 -> 23.01 dB
    render2 = truth.copy()
    rows = np.nonzero(region.any(axis=1))[0]
    render2[rows[:4], 10:20] = 0.6
    assert region_scores(render2, alpha, truth, alpha, region)["ns_psnr"] == pytest.approx(
        10 * math.log10(1 / 0.005), abs=1e-4)
    # IoU inside the region: the render covers the left half of it, the truth all of it
    half = np.zeros((32, 32), np.float32)
    half[:, :15] = 1.0
    assert region_scores(truth, half, truth, alpha, region)["ns_iou"] == pytest.approx(0.5)
    # and coverage outside the region does not matter
    assert region_scores(truth, np.ones((32, 32)), truth, region.astype(np.float32), region)["ns_iou"] == 1.0
    # SSIM inside the region falls where the structure differs there, not where it differs elsewhere
    rng = np.random.default_rng(1)
    tex = rng.uniform(size=(32, 32, 3)).astype(np.float32)
    noisy = tex.copy()
    noisy[region] = rng.uniform(size=(int(region.sum()), 3))
    assert region_scores(noisy, alpha, tex, alpha, region)["ns_ssim"] < 0.5
    far = np.zeros((32, 32), bool)
    far[26:31, 26:31] = True
    assert region_scores(noisy, alpha, tex, alpha, far)["ns_ssim"] == pytest.approx(1.0, abs=1e-6)


def test_empty_region_and_evaluation_records() -> None:
    truth = np.ones((2, 16, 16, 3), np.float32)
    alpha = np.zeros((2, 16, 16), np.float32)
    alpha[:, 4:12, 4:12] = 1
    s = region_scores(truth[0], alpha[0], truth[0], alpha[0], np.zeros((16, 16), bool))
    assert s == {"ns_psnr": None, "ns_ssim": None, "ns_lpips": None, "ns_iou": None, "ns_pixels": 0}
    ns = np.zeros((2, 16, 16), bool)
    ns[1, 5:7, 5:7] = True
    render = truth.copy()
    render[1, 5:7, 5:7] = 0.0  # off by 1 in the region: 0 dB
    views = score_views(render, alpha, truth, alpha, ["a", "b"], never_seen=ns)
    assert views[0].ns_psnr is None and views[1].ns_psnr == pytest.approx(0.0)
    ev = Evaluation.from_views(1, "x", views, never_seen=True)
    assert ev.ns_psnr == pytest.approx(0.0) and ev.ns_iou == 1.0  # the mean over the views with a region
    d = ev.to_dict()
    assert d["ns_pixels"] == 4 and d["ns_views"] == 1 and "ns_psnr" in d["per_view"][1]
    plain = Evaluation.from_views(1, "x", score_views(render, alpha, truth, alpha, ["a", "b"])).to_dict()
    assert not any(k.startswith("ns_") for k in plain) and not any(k.startswith("ns_") for k in plain["per_view"][0])


@pytest.fixture(scope="module")
def occ_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("occm") / "picnic"
    make_scene(out, "picnic", 0, settings=SceneSettings(width=64, height=64, train_views=12, test_views=2,
                                                        supersample=1, occluded=True))
    return out


def test_evaluate_scores_the_never_seen_region(occ_scene: Path) -> None:
    rec = read_json(occ_scene / "scene.json")
    scene = scene_from_record(rec)
    t = max(scene.targets, key=lambda o: next(r["never_seen_share"] for r in rec["targets"] if r["id"] == o.id))
    whole = mesh_cloud([t], per_area=40000.0)
    wrap_top = scene.object(t.id + len(scene.targets)).bounds[1, 2]
    keep = whole.means[:, 2] > wrap_top  # what a method that only keeps what it saw would have: the part above
    cut = whole.select(keep)
    ev_whole, _ = evaluate_object(whole, occ_scene, t.id)
    ev_cut, _ = evaluate_object(cut, occ_scene, t.id)
    assert ev_whole.never_seen and ev_whole.ns_iou is not None
    assert ev_whole.ns_iou > 0.7 and ev_cut.ns_iou < 0.3, (ev_whole.ns_iou, ev_cut.ns_iou)
    assert ev_whole.ns_psnr > ev_cut.ns_psnr + 3
    assert "ns_iou" in ev_whole.to_dict(per_view=False)
    masks = load_never_seen(occ_scene, t.id, ["r_000", "r_001"])
    assert masks.shape == (2, 64, 64) and masks.any()


def test_benchmark_averages_checks_and_tables() -> None:
    rows = [{"psnr": 20.0, "ssim": 0.9, "lpips": None, "iou": 0.8, "ns_psnr": 10.0, "ns_ssim": 0.5, "ns_lpips": None,
             "ns_iou": 0.4},
            {"psnr": 22.0, "ssim": 0.8, "lpips": None, "iou": 0.9, "ns_psnr": None, "ns_ssim": None,
             "ns_lpips": None, "ns_iou": None}]
    avg = _average(rows)
    assert avg["psnr"] == 21.0 and avg["ns_psnr"] == 10.0 and avg["ns_iou"] == 0.4 and avg["ns_lpips"] is None
    assert "ns_psnr" not in _average([{"psnr": 1.0, "ssim": 1.0, "lpips": None, "iou": 1.0}])
    mean = {"full": {"psnr": 22.0, "ssim": 0.9, "lpips": None, "iou": 0.9, "ns_psnr": 15.0, "ns_ssim": 0.6,
                     "ns_lpips": None, "ns_iou": 0.6},
            "no_inpaint": {"psnr": 21.0, "ssim": 0.9, "lpips": None, "iou": 0.88, "ns_psnr": 12.0, "ns_ssim": 0.5,
                           "ns_lpips": None, "ns_iou": 0.58},
            "feature_similarity": {"psnr": 20.5, "ssim": 0.8, "lpips": None, "iou": 0.8, "ns_psnr": 11.0,
                                   "ns_ssim": 0.4, "ns_lpips": None, "ns_iou": 0.3}}
    by_name = {c["check"]: c for c in checks(mean)}
    assert by_name["never-seen region: full - w/o inpainting PSNR >= 2 dB"]["met"] is True
    assert by_name["never-seen region: full - w/o inpainting PSNR >= 2 dB"]["value"] == pytest.approx(3.0)
    assert by_name["never-seen region: full - w/o inpainting IoU >= 0.05"]["met"] is False
    assert by_name["occluded scenes: full - SAGA-style PSNR >= 1 dB"]["met"] is True
    assert by_name["occluded scenes: full - SAGA-style IoU >= 0.05"]["value"] == pytest.approx(0.1)
    results = {"scenes": {"kitchen_occluded": {m: {"mean": v, "seconds": 60.0,
                                                   "objects": [{"object_name": "mug_1", "iou": v["iou"],
                                                                "ns_iou": v["ns_iou"], "never_seen_share": 0.25}]}
                                               for m, v in mean.items()} | {"_picture": "p.png"}},
               "seed": 0, "iterations": 10, "methods": list(mean), "mean": mean, "checks": checks(mean),
               "scene_settings": {"kitchen_occluded": {"width": 64, "height": 64, "train_views": 32,
                                                       "test_views": 8}}}
    md = results_markdown(results)
    assert "## Inside the never-seen region" in md and "| w/o inpainting | 12.00 |" in md
    assert "mug_1 25.0%" in md
    plain_mean = {m: {k: v[k] for k in ("psnr", "ssim", "lpips", "iou")} for m, v in mean.items()}
    plain = {**results, "mean": plain_mean, "checks": checks(plain_mean)}
    assert not any("never-seen" in c["check"] or "occluded" in c["check"] for c in plain["checks"])
    assert "never-seen region" not in results_markdown(plain).split("## Per scene")[0]


@pytest.mark.slow  # about a minute: trains a scene and extracts four objects
def test_benchmark_on_an_occluded_scene(tmp_path: Path) -> None:
    from roodi_toolkit.evaluate.benchmark import BenchmarkSize
    from roodi_toolkit.run.benchmark import run_benchmark
    from roodi_toolkit.synth.scene import make_benchmark_scene
    from tests.evaluate.test_benchmark import TINY

    size = BenchmarkSize(size=32, train_views=10, test_views=2, iterations=40, init_points=800, cap_max=1000,
                         supersample=1)
    results = run_benchmark(tmp_path / "scenes", tmp_path / "bench", presets=["picnic"], size=size, config=TINY,
                            methods=["full", "no_inpaint", "feature_similarity"], occluded=True,
                            make_scene=make_benchmark_scene)
    assert (tmp_path / "scenes" / "picnic_occluded" / "scene.json").is_file()
    per = results["scenes"]["picnic_occluded"]
    for m in ("full", "no_inpaint", "feature_similarity"):
        assert all("ns_iou" in o and "never_seen_share" in o for o in per[m]["objects"])
        assert "ns_iou" in per[m]["mean"] and "ns_iou" in results["mean"][m]
    assert any(c["check"].startswith("never-seen region") for c in results["checks"])
    md = (tmp_path / "bench" / "results.md").read_text()
    assert "Inside the never-seen region" in md and "Never seen in training" in md
    assert results["occluded"] is True and results["inpainter"] == "opencv"


def test_benchmark_command_refuses_an_unknown_inpainter(tmp_path: Path, run_cli) -> None:
    res = run_cli("benchmark", tmp_path / "r", tmp_path / "o", "--occluded", "--inpainter", "no_such_fill", "-q")
    assert res.exit_code == 1 and "no_such_fill" in res.stderr
    assert not (tmp_path / "r").exists()


def test_region_lpips_sees_only_the_region() -> None:
    import torch

    def l1(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:  # stands in for LPIPS: [1] mean absolute difference
        return (x - y).abs().mean(dim=(1, 2, 3))

    rng = np.random.default_rng(2)
    truth = rng.uniform(size=(32, 32, 3)).astype(np.float32)
    alpha = np.ones((32, 32), np.float32)
    region = _region()
    outside = truth.copy()
    outside[~region] = 0.0  # wrong everywhere but in the region
    assert region_scores(outside, alpha, truth, alpha, region, l1)["ns_lpips"] == 0.0
    inside = truth.copy()
    inside[region] = np.clip(truth[region] + 0.5, 0, 1)
    assert region_scores(inside, alpha, truth, alpha, region, l1)["ns_lpips"] > 0.05
