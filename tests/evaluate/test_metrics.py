"""The paper's extraction metrics: crop box, PSNR/SSIM/IoU, LPIPS unavailable or loaded, evaluate command."""

import json

import numpy as np
import pytest

from roodi_toolkit import write_ply
from roodi_toolkit.errors import DatasetError
from roodi_toolkit.evaluate.metrics import box_around, iou, psnr, score_views
from roodi_toolkit.run.evaluate import evaluate_object

from ..mesh_gaussians import mesh_cloud


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from roodi_toolkit.synth.scene import SceneSettings, make_scene

    root = tmp_path_factory.mktemp("m") / "picnic"
    make_scene(root, "picnic", seed=1, settings=SceneSettings(width=64, height=64, train_views=4, test_views=6,
                                                             supersample=1, n_objects=5, n_targets=2,
                                                             test_framing="object"))  # large enough at 64 px
    return root


def test_box_is_1_2x_the_tight_box_and_clipped():
    a = np.zeros((50, 50))
    a[0:10, 45:50] = 1
    assert box_around(a) == (0, 11, 44, 50)
    assert box_around(np.zeros((5, 5))) is None


def test_scores_of_identical_and_different_views():
    rng = np.random.default_rng(0)
    truth = rng.random((2, 40, 40, 3))
    alpha = np.zeros((2, 40, 40))
    alpha[:, 10:30, 10:30] = 1
    same = score_views(truth, alpha, truth, alpha, ["a", "b"])
    assert all(v.psnr == float("inf") and v.ssim == pytest.approx(1.0) and v.iou == 1.0 for v in same)
    assert all(v.lpips is None for v in same)
    off = score_views(np.clip(truth + 0.1, 0, 1), np.roll(alpha, 6, axis=1), truth, alpha, ["a", "b"])
    assert all(v.psnr < 25 and v.iou < 1.0 for v in off)
    # only the crop counts: damage outside 1.2x the box does not change PSNR
    far = truth.copy()
    far[:, :3, :3] = 0
    assert score_views(far, alpha, truth, alpha, ["a", "b"])[0].psnr == float("inf")
    assert psnr(np.zeros(4), np.full(4, 0.1)) == pytest.approx(20.0)
    assert iou(np.zeros((3, 3)), np.zeros((3, 3))) == 1.0


def test_evaluate_true_object_beats_a_wrong_one(scene_dir, monkeypatch, tmp_path):
    from roodi_toolkit.synth.scene import scene_from_record
    from roodi_toolkit.io.files import read_json

    monkeypatch.delenv("ROODI_LPIPS_WEIGHTS", raising=False)
    monkeypatch.setattr("torch.hub.get_dir", lambda: str(tmp_path / "no_hub"))
    record = read_json(scene_dir / "scene.json")
    scene = scene_from_record(record)
    target_id = record["targets"][0]["id"]
    target = next(o for o in scene.objects if o.id == target_id)
    other = next(o for o in scene.objects if o.id != target_id)
    good, _ = evaluate_object(mesh_cloud([target]), scene_dir, target_id)
    bad, _ = evaluate_object(mesh_cloud([other]), scene_dir, target_id)
    assert good.iou > 0.6 and bad.iou < 0.2
    # mesh base colours, not the rendered materials: the geometry (IoU) is the sharp test, PSNR only orders them
    assert good.psnr > bad.psnr
    assert good.lpips is None and good.lpips_status.startswith("unavailable")
    with pytest.raises(DatasetError, match="not an extraction target"):
        evaluate_object(mesh_cloud([target]), scene_dir, 999)


def test_evaluate_command(scene_dir, tmp_path, run_cli):
    from roodi_toolkit.io.files import read_json
    from roodi_toolkit.synth.scene import scene_from_record

    record = read_json(scene_dir / "scene.json")
    tid = record["targets"][1]["id"]
    target = next(o for o in scene_from_record(record).objects if o.id == tid)
    obj = tmp_path / "object.ply"
    write_ply(mesh_cloud([target]), obj)
    res = run_cli("evaluate", obj, scene_dir, "--object", tid, "--json", tmp_path / "s.json", "--renders",
                  tmp_path / "r", "--max-views", 3, "-q")
    assert res.exit_code == 0, res.stderr
    assert "IoU" in res.stdout and "PSNR" in res.stdout
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["views"] == 3 and len(scores["per_view"]) == 3 and scores["iou"] > 0.5
    assert len(list((tmp_path / "r").glob("*_render_vs_truth.png"))) == 3
    res = run_cli("evaluate", obj, scene_dir, "--object", "77", "-q")
    assert res.exit_code == 1 and "not an extraction target" in res.stderr
