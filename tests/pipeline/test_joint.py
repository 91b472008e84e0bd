"""Single-stage training (the "w/o two-stage" ablation): features learned with the geometry, MCMC-safe, resumable."""

import torch

from roodi_toolkit.pipeline.distill import DistillConfig
from roodi_toolkit.pipeline.select import select_object
from roodi_toolkit.pipeline.strategy import MCMCStrategy
from roodi_toolkit.pipeline.train import TrainConfig

CONFIG = TrainConfig(iterations=30, init="depth", init_num_points=600, eval_every=0, checkpoint_every=10,
                     strategy=MCMCStrategy(cap_max=900, refine_start_iter=5, refine_every=5))


def _trainer(tiny_kitchen):
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.pipeline.joint import JointTrainer
    from roodi_toolkit.pipeline.segment import FilesSegmenter, SegmentPrompt

    ds = load_dataset(tiny_kitchen)
    masks = FilesSegmenter().segment(ds, SegmentPrompt())
    return JointTrainer(ds, CONFIG, masks, DistillConfig())


def test_object_loss_falls_and_moves_the_geometry(tiny_kitchen):
    trainer = _trainer(tiny_kitchen)

    def object_loss():
        out = trainer.renderer.render(trainer.params, trainer.dataset.cameras[0])  # features set: rendered
        return trainer._extra_loss(out, 0)

    before = float(object_loss().detach())
    start = trainer.num_gaussians
    for _ in range(30):
        trainer.train_step()
    # growth added Gaussians: the features grew with them
    assert trainer.num_gaussians > start
    assert trainer.params["features"].shape == (trainer.num_gaussians, 16)
    assert float(object_loss().detach()) < 0.7 * before
    # the object loss reaches the geometry (single stage): alone it gives the positions a gradient
    trainer.params["means"].grad = None
    object_loss().backward()
    assert trainer.params["means"].grad is not None and trainer.params["means"].grad.abs().sum() > 0


def test_state_round_trip_continues_identically(tiny_kitchen):
    a = _trainer(tiny_kitchen)
    for _ in range(7):
        a.train_step()
    state = a.state_dict()
    b = _trainer(tiny_kitchen)
    b.load_state_dict(state)
    for _ in range(4):
        a.train_step()
        b.train_step()
    for k in a.params:
        assert torch.equal(a.params[k], b.params[k]), k
    assert torch.equal(a.classifier_params["weight"], b.classifier_params["weight"])


def test_train_joint_writes_a_distilled_model(tiny_kitchen, tmp_path):
    import json

    from roodi_toolkit.run.train import train_joint

    _, distilled = train_joint(tiny_kitchen, tmp_path / "m", CONFIG)
    cloud, classifier = distilled.cloud, distilled.classifier
    assert classifier.num_classes >= 4 and classifier.labels.get(0) == "background"
    target = json.loads((tiny_kitchen / "scene.json").read_text())["targets"][0]["id"]
    sel = select_object(cloud, classifier, target, prune=False)
    assert 0 < len(sel.cloud) < len(cloud)


def test_extract_single_stage(tiny_kitchen, tmp_path, run_cli):
    import json

    from roodi_toolkit import read_ply
    from roodi_toolkit.pipeline.extract import ExtractConfig
    from roodi_toolkit.run.extract import extract_objects

    target = json.loads((tiny_kitchen / "scene.json").read_text())["targets"][0]["id"]
    config = ExtractConfig(train=CONFIG, distill=DistillConfig(iterations=1), inpaint=False, prune=False,
                           single_stage=True)
    report = extract_objects(tiny_kitchen, tmp_path / "o", [target], config=config)
    assert report["distill"]["single_stage"] is True and report["config"]["single_stage"] is True
    assert len(read_ply(tmp_path / "o" / f"object_{target}" / "object.ply")) > 0
    res = run_cli("extract", tiny_kitchen, tmp_path / "o2", "--object", str(target), "--single-stage", "--model",
                  tmp_path / "o" / "scene", "-q")
    assert res.exit_code == 1 and "single-stage" in res.stderr
