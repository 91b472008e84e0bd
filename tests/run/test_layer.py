"""The run layer and the stages apart (issue 35): the stages name no file, the training loop hands checkpoints to a
callback, the distillation makes its frozen geometry once, and the run layer's training writes what it did."""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
from pathlib import Path

import numpy as np
import pytest
import torch

import roodi_toolkit.evaluate
import roodi_toolkit.pipeline
from roodi_toolkit.io.dataset import load_dataset
from roodi_toolkit.pipeline import distill, train
from roodi_toolkit.pipeline.distill import DistillConfig, distill_scene
from roodi_toolkit.pipeline.strategy import MCMCStrategy
from roodi_toolkit.pipeline.train import TrainConfig, Trainer
from roodi_toolkit.run.train import train_scene

from ..paths import REPO

# the modules of the package that read or write files: a stage imports none of them
FILE_MODULES = {"roodi_toolkit.io.files", "roodi_toolkit.io.model", "roodi_toolkit.io.ply", "roodi_toolkit.io.atomic",
                "roodi_toolkit.io.generated", "roodi_toolkit.io.splat", "roodi_toolkit.io.lpips_weights",
                "roodi_toolkit.io.masks", "roodi_toolkit.io.polygons"}
# every module of pipeline/ (train, segment and the click segmenter, distill, select, occlusion, inpaint, fine-tune
# and its perceptual loss, another tool's model frame, ...) and of evaluate/ (metrics, scoring, baselines, polygon
# masks, LPIPS), no exception
PIPELINE = sorted(f"roodi_toolkit.pipeline.{m.name}" for m in pkgutil.iter_modules(roodi_toolkit.pipeline.__path__))
EVALUATE = sorted(f"roodi_toolkit.evaluate.{m.name}" for m in pkgutil.iter_modules(roodi_toolkit.evaluate.__path__))
STAGES = tuple(importlib.import_module(name) for name in PIPELINE + EVALUATE)


def _imported(module) -> set[str]:
    """Return the modules ``module`` imports anywhere in it (relative imports resolved), and names it calls on
    ``open``/``Path``."""
    tree = ast.parse(inspect.getsource(module))
    package = module.__name__.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            found.update({base} | {f"{base}.{a.name}" for a in node.names})
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("open", "Path"):
            found.add(node.func.id)
    return found


@pytest.mark.parametrize("module", STAGES, ids=lambda m: m.__name__.rsplit(".", 1)[1])
def test_stages_open_name_and_check_no_file(module):
    """train, segment, distill, select, extract, joint training, occlusion, inpainting, fine-tuning (LPIPS handed
    in), the model-frame check (the scene handed in) and evaluation are functions of in-memory values: no file module,
    no path (their folders, mask folders, weights and pictures are the run layer's, roodi_toolkit/run)."""
    bad = _imported(module) & (FILE_MODULES | {"open", "Path", "pathlib", "pathlib.Path"})
    assert not bad, f"{module.__name__} touches files through {sorted(bad)}"


def test_the_stages_cover_what_read_files():
    """The modules that read a mask folder, another tool's model file, LPIPS weights and polygon files until issue 35
    are checked."""
    assert {"roodi_toolkit.pipeline.segment", "roodi_toolkit.pipeline.model_frame",
            "roodi_toolkit.pipeline.perceptual", "roodi_toolkit.pipeline.click"} <= set(PIPELINE)
    assert {"roodi_toolkit.evaluate.polygons", "roodi_toolkit.evaluate.lpips", "roodi_toolkit.evaluate.metrics",
            "roodi_toolkit.evaluate.benchmark"} <= set(EVALUATE)


def test_the_run_layer_is_where_the_commands_go():
    """The commands that make folders call the run layer, not the stages' folders."""
    cli = REPO / "roodi_toolkit" / "cli"
    for command, function in (("train", "roodi_toolkit.run.train import train_scene"),
                              ("distill", "roodi_toolkit.run.distill import run_distill"),
                              ("select", "roodi_toolkit.run.select import run_select"),
                              ("extract", "roodi_toolkit.run.extract import extract_objects"),
                              ("batch_extract", "roodi_toolkit.run.extract import prepare_scene"),
                              ("benchmark", "roodi_toolkit.run.benchmark import run_benchmark")):
        assert function in (cli / f"cmd_{command}.py").read_text(), command


def _config(**kw) -> TrainConfig:
    base = dict(iterations=12, init_num_points=300, eval_every=0, checkpoint_every=5,
                strategy=MCMCStrategy(cap_max=400, refine_start_iter=4, refine_every=4))
    return TrainConfig(**{**base, **kw})


def test_the_training_loop_hands_checkpoints_to_its_callback(tiny_kitchen):
    """The loop calls back every checkpoint_every steps and after the last one; the callback changes nothing of the
    result (the run layer writes the checkpoints)."""
    ds = load_dataset(tiny_kitchen)
    steps, states = [], []

    def keep(trainer: Trainer) -> None:
        steps.append(trainer.step)
        states.append(trainer.state_dict())

    with_callback = train.train(Trainer(ds, _config()), on_checkpoint=keep)
    alone = train.train(Trainer(ds, _config()))
    assert steps == [5, 10, 12]
    assert states[-1]["step"] == 12 and len(with_callback.history) == len(alone.history)
    np.testing.assert_array_equal(with_callback.cloud.means, alone.cloud.means)
    # a trainer restored from the step-10 state ends where the uninterrupted one did
    resumed = Trainer(ds, _config())
    resumed.load_state_dict(states[1])
    finished = train.train(resumed)
    assert finished.steps_run == 2
    np.testing.assert_array_equal(finished.cloud.means, alone.cloud.means)


def test_train_scene_writes_the_checkpoint_the_loop_hands_it(tiny_kitchen, tmp_path):
    result = train_scene(tiny_kitchen, tmp_path / "m", _config())
    state = torch.load(tmp_path / "m" / "checkpoints" / "latest.pt", weights_only=False)
    assert state["step"] == result.iterations == 12
    assert (tmp_path / "m" / "cfg.json").is_file() and (tmp_path / "m" / "training.png").is_file()


def test_distillation_makes_its_frozen_geometry_once(tiny_kitchen, monkeypatch):
    """distill_scene made GaussianParams.from_cloud three times (training, scoring, picture): once now."""
    ds = load_dataset(tiny_kitchen)
    scene = Trainer(ds, _config(iterations=1)).to_cloud()
    calls = []
    made = distill.GaussianParams.from_cloud

    def counted(*args, **kwargs):
        calls.append(1)
        return made(*args, **kwargs)

    monkeypatch.setattr(distill.GaussianParams, "from_cloud", counted)
    result = distill_scene(scene, ds, config=DistillConfig(iterations=3), holdout_every=4)
    assert len(calls) == 1
    assert result.summary["held_out"]["pairs"] > 0  # the held-out views were scored (with the same geometry)


def test_an_atomic_training_run_leaves_a_whole_model_folder_or_none(tiny_kitchen, tmp_path):
    """atomic=True (the train command's): stopped before the first checkpoint, no folder; stopped after it, the
    checkpoint with its cfg.json and nothing else of the model; the library's default writes as it goes."""
    def stop_at(step):
        def on_step(trainer, info):
            if trainer.step == step:
                raise KeyboardInterrupt
        return on_step

    with pytest.raises(KeyboardInterrupt):
        train_scene(tiny_kitchen, tmp_path / "early", _config(), on_step=stop_at(3), atomic=True)
    assert not (tmp_path / "early").exists()
    with pytest.raises(KeyboardInterrupt):
        train_scene(tiny_kitchen, tmp_path / "later", _config(), on_step=stop_at(7), atomic=True)
    made = sorted(p.relative_to(tmp_path / "later").as_posix() for p in (tmp_path / "later").rglob("*") if p.is_file())
    assert made == ["cfg.json", "checkpoints/latest.pt"]
    assert torch.load(tmp_path / "later" / "checkpoints" / "latest.pt", weights_only=False)["step"] == 5
    with pytest.raises(KeyboardInterrupt):
        train_scene(tiny_kitchen, tmp_path / "plain", _config(), on_step=stop_at(3))
    assert (tmp_path / "plain" / "cfg.json").is_file()  # written before the first step
