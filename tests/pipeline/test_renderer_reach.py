"""A renderer plugin reaches every stage: ``train`` and ``extract`` run on it with the built-in rasterizer disabled.

The test plugin is registered as a third party registers one during development (``$ROODI_PLUGINS``), counts its
calls, and renders with the slow dense reference (:func:`rasterize_dense_reference`); the tiled ``rasterize`` and
``compositing_pairs`` are patched to fail, so any stage that still draws with the built-in renderer fails the run.
"""

from __future__ import annotations

import json
import sys
import types
from collections import Counter
from functools import partial

import pytest
import torch
from click.testing import CliRunner

from roodi_toolkit.render import rasterizer
from roodi_toolkit.render.renderer import Renderer, has_compositing_weights


class DenseCountingRenderer(Renderer):
    """Renders with the dense reference and counts its calls (by what was drawn: colour or features)."""

    name = "dense-counting"
    calls: Counter = Counter()

    def render(self, params, camera, *, background=None, sh_degree=None):
        DenseCountingRenderer.calls["features" if params.features is not None else "colour"] += 1
        dtype = params.dtype
        bg = None if background is None else torch.as_tensor(background, dtype=dtype)
        return rasterizer.rasterize_dense_reference(
            params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, params.colors,
            torch.as_tensor(camera.world_to_camera, dtype=dtype), torch.as_tensor(camera.K, dtype=dtype),
            camera.width, camera.height, near=camera.near, far=camera.far, features=params.features, background=bg,
            sh_degree=sh_degree)


@pytest.fixture
def plugin(monkeypatch):
    module = types.ModuleType("fake_dense_renderer_plugin")
    module.DenseCountingRenderer = DenseCountingRenderer
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setenv("ROODI_PLUGINS", f"renderers:dense-counting={module.__name__}:DenseCountingRenderer")

    def built_in(*args, **kwargs):
        raise AssertionError("the built-in rasterizer was called although --renderer dense-counting was given")

    monkeypatch.setattr(rasterizer, "rasterize", built_in)
    monkeypatch.setattr(rasterizer, "compositing_pairs", built_in)
    DenseCountingRenderer.calls.clear()
    return DenseCountingRenderer


def _cli(*args: str) -> None:
    from roodi_toolkit.cli.main import app

    result = CliRunner().invoke(app, [str(a) for a in args], catch_exceptions=False)
    assert result.exit_code == 0, result.output


def test_train_and_extract_run_on_a_renderer_plugin(tiny_kitchen, tmp_path, monkeypatch, plugin):
    from roodi_toolkit.pipeline import extract
    from roodi_toolkit.pipeline.finetune import FinetuneConfig
    from roodi_toolkit.pipeline.occlusion import OcclusionConfig

    assert not has_compositing_weights(plugin())  # distillation must take the dense path
    model = tmp_path / "model"
    _cli("train", tiny_kitchen, model, "--iterations", "4", "--init-points", "300", "--cap-max", "320",
         "--eval-every", "0", "--checkpoint-every", "4", "--renderer", "dense-counting", "-q")
    trained = plugin.calls["colour"]
    assert trained >= 4 + 1  # every training step, and the held-out views and pictures
    # the stages' defaults (256 px object views, 100 fine-tuning steps) are sized for the tiled renderer
    monkeypatch.setattr(extract, "ExtractConfig", partial(
        extract.ExtractConfig, occlusion=OcclusionConfig(size=24, opening_reference=0, opening_size=3),
        finetune=FinetuneConfig(iterations=4)))
    target = json.loads((tiny_kitchen / "scene.json").read_text())["targets"][0]["id"]
    out = tmp_path / "out"
    _cli("extract", tiny_kitchen, out, "--object", target, "--model", model, "--distill-iterations", "10",
         "--threshold", "0.1", "--renderer", "dense-counting", "-q")
    assert (out / f"object_{target}" / "object.ply").is_file()
    assert plugin.calls["features"] >= 10  # distillation, held-out scoring and its picture
    # occlusion (4 object + 4 scene views), training-view depths, fine-tuning and the pictures
    assert plugin.calls["colour"] - trained >= 8 + 4
