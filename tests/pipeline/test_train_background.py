"""The training background: random by default for images with alpha (3DGS practice), recorded in cfg.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from roodi_toolkit.cameras import orbit_cameras
from roodi_toolkit.io.blender import write_blender_transforms
from roodi_toolkit.io.dataset import load_dataset
from roodi_toolkit.io.files import write_image
from roodi_toolkit.pipeline.train import TrainConfig, Trainer
from roodi_toolkit.run.train import train_scene

TINY = dict(iterations=2, init="random", init_num_points=40, eval_every=0, checkpoint_every=1, sh_degree=0)


def _scene(root: Path, alpha: bool) -> Path:
    cams = orbit_cameras([0, 0, 0], 3.0, 3, width=12, height=10)
    (root / "train").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):
        write_image(rng.integers(0, 256, (10, 12, 4 if alpha else 3), dtype=np.uint8), root / "train" / f"r_{i}.png")
    write_blender_transforms(root / "transforms_train.json", cams, [f"./train/r_{i}" for i in range(3)])
    return root


@pytest.mark.parametrize("alpha", [True, False])
def test_random_background_follows_the_alpha_and_is_recorded(tmp_path: Path, alpha: bool) -> None:
    data = _scene(tmp_path / "data", alpha)
    train_scene(data, tmp_path / "m", TrainConfig(**TINY))
    cfg = json.loads((tmp_path / "m" / "cfg.json").read_text())
    assert cfg["random_background"] is alpha and cfg["dataset_has_alpha"] is alpha
    # an explicit choice is kept
    train_scene(data, tmp_path / "f", TrainConfig(**TINY, random_background=False))
    assert json.loads((tmp_path / "f" / "cfg.json").read_text())["random_background"] is False


def test_trainer_resolves_the_default_and_uses_it(tmp_path: Path) -> None:
    ds = load_dataset(_scene(tmp_path, True))
    trainer = Trainer(ds, TrainConfig(**TINY))
    assert trainer.config.random_background is True
    assert trainer.state_dict()["config"]["random_background"] is True
    before = trainer.generator.get_state().clone()
    trainer.train_step()
    # the random colour is drawn from the trainer's generator (beyond the view order)
    fixed = Trainer(ds, TrainConfig(**TINY, random_background=False))
    fixed.train_step()
    assert not np.array_equal(trainer.generator.get_state().numpy(), fixed.generator.get_state().numpy())
    assert not np.array_equal(before.numpy(), trainer.generator.get_state().numpy())


def test_cli_train_background_flags(tmp_path: Path, run_cli) -> None:
    data = _scene(tmp_path / "data", True)
    res = run_cli("train", data, tmp_path / "m", "--iterations", "1", "--init", "random", "--init-points", "40",
                  "--sh-degree", "0", "--fixed-background", "-q")
    assert res.exit_code == 0, res.stderr
    assert json.loads((tmp_path / "m" / "cfg.json").read_text())["random_background"] is False


def test_random_background_on_opaque_photos_is_drawn_and_rendered(tmp_path: Path) -> None:
    """Asked for on images without alpha, the random colour is still drawn and rendered behind the Gaussians (an
    uncovered pixel then costs loss whatever its colour); the photos themselves are left as they are."""
    ds = load_dataset(_scene(tmp_path, False))
    seen = []

    class Recording:
        def __init__(self, inner):
            self.inner = inner

        def render(self, params, camera, **kw):
            seen.append(np.asarray(kw["background"], dtype=np.float64).copy())
            return self.inner.render(params, camera, **kw)

        def __getattr__(self, name):
            return getattr(self.inner, name)

    trainer = Trainer(ds, TrainConfig(**TINY, random_background=True))
    gt_before = ds.images[0].clone()
    trainer.renderer = Recording(trainer.renderer)
    trainer.train_step()
    trainer.train_step()
    assert len(seen) == 2 and not np.allclose(seen[0], seen[1])
    assert not np.allclose(seen[0], ds.background)
    assert np.array_equal(ds.images[0].numpy(), gt_before.numpy())
