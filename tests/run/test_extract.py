"""extract: every stage chained on a tiny generated scene, stage reuse on a re-run, ablation switches."""

import json

import pytest

from roodi_toolkit import read_ply

from ..object_scene import tree_digest


@pytest.fixture
def tiny_scene(tiny_kitchen):
    record = json.loads((tiny_kitchen / "scene.json").read_text())
    return tiny_kitchen, record["targets"][0]["id"]


def test_extract_chains_every_stage_and_reuses_them(tiny_scene, tmp_path, run_cli, monkeypatch):
    from dataclasses import replace

    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.run.extract import extract_objects
    from roodi_toolkit.pipeline.finetune import FinetuneConfig
    from roodi_toolkit.pipeline.occlusion import OcclusionConfig
    from roodi_toolkit.pipeline.strategy import MCMCStrategy
    from roodi_toolkit.pipeline.train import TrainConfig

    scene, target = tiny_scene
    config = ExtractConfig(
        train=TrainConfig(iterations=40, init="depth", init_num_points=800, eval_every=0, checkpoint_every=20,
                          strategy=MCMCStrategy(cap_max=1000, refine_start_iter=10, refine_every=10)),
        distill=DistillConfig(iterations=40), occlusion=OcclusionConfig(size=32, opening_reference=0, opening_size=5),
        finetune=FinetuneConfig(iterations=4))
    out = tmp_path / "out"
    report = extract_objects(scene, out, [target], config=config)
    obj = read_ply(out / f"object_{target}" / "object.ply")
    assert len(obj) == report["objects"][str(target)]["gaussians"] > 0
    assert not any(k.startswith("object_feature_") for k in obj.extras)
    assert (out / "distill" / "object_classifier.pt").is_file()
    assert (out / f"object_{target}" / "object.png").is_file() and (out / f"object_{target}" / "fill.png").is_file()
    assert list((out / f"object_{target}" / "debug").iterdir())
    saved = json.loads((out / "report.json").read_text())
    assert saved["objects"][str(target)]["inpainter"] == "opencv" and saved["reused"] == []
    again = extract_objects(scene, out, [target], config=config)
    assert again["reused"] == ["train", "distill", f"object {target}"] and again["recomputed"] == []
    # other settings: the extract command refuses to replace what a finished stage made (nothing is written) ...
    from roodi_toolkit.errors import OutputError

    made = {p.name: p.read_bytes() for p in (out / f"object_{target}").iterdir() if p.is_file()}
    with pytest.raises(OutputError, match=rf"object_{target}: the object {target} there was made with other settings "
                                          r"\(inpainter changed\) and would be replaced; give --overwrite"):
        extract_objects(scene, out, [target], config=replace(config, inpainter="exemplar"), replace_changed=False)
    assert {p.name: p.read_bytes() for p in (out / f"object_{target}").iterdir() if p.is_file()} == made
    with pytest.raises(OutputError, match=r"the distill there was made with other settings \(config changed\)"):
        extract_objects(scene, out, [target], config=replace(config, distill=DistillConfig(iterations=41)),
                        replace_changed=False)
    # ... while the library's re-runs (the benchmark's) make again only the stages they change, and say why
    changed = extract_objects(scene, out, [target], config=replace(config, threshold=0.4))
    assert changed["reused"] == ["train", "distill"]
    assert changed["recomputed"] == [f"object {target} (threshold changed)"]
    changed = extract_objects(scene, out, [target], config=replace(config, distill=DistillConfig(iterations=41)))
    assert changed["reused"] == ["train"] and changed["recomputed"][0] == "distill (config changed)"
    # the ablation without inpainting starts from the trained and distilled scene, which are only read
    inputs = {d: tree_digest(d) for d in (scene, out / "scene", out / "distill")}
    ablation = extract_objects(scene, tmp_path / "no_inpaint", [target], model_dir=out / "scene",
                               distill_dir=out / "distill", config=replace(config, inpaint=False, prune=False))
    assert ablation["reused"] == [] and ablation["distill_dir"] == str(out / "distill")
    again = extract_objects(scene, tmp_path / "no_inpaint", [target], model_dir=out / "scene", overwrite=True,
                            distill_dir=out / "distill", config=replace(config, inpaint=False, prune=False))
    assert len(read_ply(tmp_path / "no_inpaint" / f"object_{target}" / "object.ply")) >= len(
        read_ply(out / f"object_{target}" / "selected.ply"))
    # with --model alone it distils into its own folder; the model and data folders stay byte-identical
    alone = extract_objects(scene, tmp_path / "from_model", [target], model_dir=out / "scene",
                            config=replace(config, inpaint=False))
    assert alone["distill_dir"] == str(tmp_path / "from_model" / "distill")
    assert {d: tree_digest(d) for d in (scene, out / "scene", out / "distill")} == inputs
    with pytest.raises(OutputError, match="inside the input folder"):
        extract_objects(scene, out / "scene" / "x", [target], model_dir=out / "scene", config=config)
    # the run reads fine-tuning's LPIPS weights and hands the network in: used when there, required by "lpips"
    import torch

    from roodi_toolkit.errors import ConfigError
    from roodi_toolkit.io.lpips_weights import ENV_WEIGHTS, write_lpips
    from roodi_toolkit.lpips import LPIPS

    lpips_config = replace(config, finetune=replace(config.finetune, perceptual="lpips"))
    monkeypatch.delenv(ENV_WEIGHTS, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "empty_hub"))
    with pytest.raises(ConfigError, match="perceptual loss 'lpips' unavailable: no local LPIPS weights"):
        extract_objects(scene, tmp_path / "lpips", [target], model_dir=out / "scene", distill_dir=out / "distill",
                        config=lpips_config)
    torch.manual_seed(0)
    monkeypatch.setenv(ENV_WEIGHTS, str(write_lpips(LPIPS(), tmp_path / "lpips.pt")))
    used = extract_objects(scene, tmp_path / "lpips", [target], model_dir=out / "scene", distill_dir=out / "distill",
                           config=lpips_config)
    assert used["objects"][str(target)]["perceptual_loss"] == "lpips"


def test_extract_command_replaces_an_object_only_with_overwrite(tiny_scene, tmp_path, run_cli):
    """Re-running extract with other settings replaced object.ply without --overwrite ("made again: object 2
    (inpainter changed)"); now it says what changed and how to go on, and writes nothing."""
    scene, target = tiny_scene
    common = ("--object", str(target), "--iterations", "40", "--init", "depth", "--distill-iterations", "40",
              "--no-inpaint", "-q")
    res = run_cli("extract", scene, tmp_path / "o", *common, "--threshold", "0.1")
    assert res.exit_code == 0, res.stderr
    ply = tmp_path / "o" / f"object_{target}" / "object.ply"
    before = ply.read_bytes()
    res = run_cli("extract", scene, tmp_path / "o", *common, "--threshold", "0.15")
    assert res.exit_code == 1 and "threshold changed" in res.stderr and "--overwrite" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and ply.read_bytes() == before


def test_extract_command_errors(tiny_scene, tmp_path, run_cli):
    scene, _ = tiny_scene
    res = run_cli("extract", scene, tmp_path / "o", "-q")
    assert res.exit_code == 2 and "--object" in res.stderr
    res = run_cli("extract", tmp_path / "missing", tmp_path / "o", "--object", "1", "--iterations", "2", "-q")
    assert res.exit_code == 1 and "dataset not found" in res.stderr


def test_tiny_selection_skips_pruning_and_says_so(tiny_scene, tmp_path):
    from dataclasses import replace

    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.run.extract import extract_objects
    from roodi_toolkit.prune.outliers import PruneConfig
    from roodi_toolkit.pipeline.train import TrainConfig

    scene, target = tiny_scene
    config = ExtractConfig(train=TrainConfig(iterations=40, init="depth", init_num_points=800, eval_every=0),
                           distill=DistillConfig(iterations=40), inpaint=False)
    config = replace(config, prune_config=PruneConfig(k=100_000))  # more neighbours than any selection has
    report = extract_objects(scene, tmp_path / "o", [target], config=config)
    assert "prune_skipped" in report["objects"][str(target)]


def test_an_unfinished_scene_is_resumed_with_its_settings_and_refused_with_others(tiny_scene, tmp_path, monkeypatch):
    """A training run stopped after a checkpoint (no final scene PLY): extract resumes it when the settings are the
    same and, without ``--overwrite``, refuses to train afresh over it when they are not."""
    import shutil
    from dataclasses import replace

    from roodi_toolkit.errors import OutputError
    from roodi_toolkit.io.model import checkpoint_file
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.run import extract as extract_run
    from roodi_toolkit.run.extract import prepare_scene
    from roodi_toolkit.run.train import train_scene
    from roodi_toolkit.pipeline.train import TrainConfig

    scene, _ = tiny_scene
    config = ExtractConfig(train=TrainConfig(iterations=20, init="depth", init_num_points=400, eval_every=0,
                                             checkpoint_every=10, random_background=False))
    out = tmp_path / "out"
    train_scene(scene.resolve(), out / "scene", config.train, downscale=1.0)
    shutil.rmtree(out / "scene" / "point_cloud" / "iteration_20")  # stopped before writing its final scene
    assert checkpoint_file(out / "scene").is_file()
    with pytest.raises(OutputError, match=r"the train there was made with other settings \(iterations changed\) "
                                          r"and would be replaced; give --overwrite"):
        prepare_scene(scene, out, config=replace(config, train=replace(config.train, iterations=30)),
                      replace_changed=False)
    calls = []

    def stop(*args, **kwargs):
        calls.append(kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(extract_run, "train_scene", stop)
    for overwrite, resumed in ((False, True), (True, False)):
        with pytest.raises(KeyboardInterrupt):
            prepare_scene(scene, out, config=config, replace_changed=False, overwrite=overwrite)
        assert calls[-1]["resume"] is resumed and calls[-1]["overwrite"] is not resumed
