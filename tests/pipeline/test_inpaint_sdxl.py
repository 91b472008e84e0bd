"""The ``sdxl`` inpainter plugin end to end on a tiny randomly initialised SD-XL inpainting pipeline.

The pipeline is built here from tiny configs (9-channel inpainting UNet with SD-XL's text-time conditioning, a small
VAE, two small CLIP text encoders, a tokenizer from a vocabulary written here), so nothing is downloaded; the hub is
forced offline for the whole module.
"""

from __future__ import annotations

import os

import pytest
import torch

pytest.importorskip("diffusers", reason="the sdxl inpainter tests need diffusers (pip install -e '.[dev]')")
pytest.importorskip("transformers", reason="the sdxl inpainter tests need transformers")
roodi_sdxl = pytest.importorskip("roodi_sdxl", reason="the roodi-sdxl plugin is not installed")

from roodi_toolkit.errors import PluginError  # noqa: E402
from roodi_toolkit.pipeline.inpaint import get_inpainter, inpaint_views  # noqa: E402

from ..tiny_sdxl import tiny_pipeline  # noqa: E402


@pytest.fixture(autouse=True)
def _offline(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("TRANSFORMERS_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))  # an empty cache: nothing cached can leak in
    monkeypatch.delenv("ROODI_SDXL_MODEL", raising=False)


def views(seed=0, n=4, size=24):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(n, size, size, 3, generator=g)
    masks = torch.zeros(n, size, size, dtype=torch.bool)
    masks[:, 6:18, 8:20] = True
    return images, masks


def test_tiny_sdxl_end_to_end_grid_native_resolution_and_composite(tmp_path, monkeypatch):
    pipe = tiny_pipeline(tmp_path)
    seen = {}
    original_call = type(pipe).__call__

    def spy(self, *args, **kwargs):
        seen.update(size=kwargs["image"].size, mask_size=kwargs["mask_image"].size, prompt=kwargs["prompt"],
                    height=kwargs["height"], width=kwargs["width"])
        return original_call(self, *args, **kwargs)

    monkeypatch.setattr(type(pipe), "__call__", spy)
    inp = get_inpainter("sdxl", pipeline=pipe, resolution=64, steps=2, seed=3)
    images, masks = views()
    out, grids = inpaint_views(inp, images, masks)
    # the 2x2 grid of 24 px views (48x48) went in as one image at the model's native size, with no prompt
    assert seen == {"size": (64, 64), "mask_size": (64, 64), "prompt": "", "height": 64, "width": 64}
    assert out.shape == images.shape and grids["after"].shape == (48, 48, 3)
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    assert torch.equal(out[~masks], images[~masks])  # unmasked pixels exactly unchanged
    assert (out[masks] - images[masks]).abs().mean() > 0.02  # the masked ones were redrawn
    again, _ = inpaint_views(get_inpainter("sdxl", pipeline=pipe, resolution=64, steps=2, seed=3), images, masks)
    torch.testing.assert_close(again, out)  # seeded


def test_sdxl_loads_from_local_folder_offline(tmp_path):
    folder = tmp_path / "sdxl-tiny"
    tiny_pipeline(tmp_path).save_pretrained(folder)
    inp = get_inpainter("sdxl", model=str(folder), resolution=32, steps=2)
    images, masks = views(n=1, size=32)
    out = inp.inpaint(images, masks)
    assert out.shape == images.shape and torch.equal(out[~masks], images[~masks])


def test_sdxl_missing_weights_raise_one_clear_line(tmp_path):
    inp = get_inpainter("sdxl", steps=1)  # default: the hub id, from the (empty) local cache only
    images, masks = views(n=1, size=16)
    with pytest.raises(PluginError) as err:
        inp.inpaint(images, masks)
    msg = str(err.value)
    assert "\n" not in msg and roodi_sdxl.MODEL_ID in msg and "local" in msg
    with pytest.raises(PluginError, match="folder"):
        get_inpainter("sdxl", model=str(tmp_path)).inpaint(images, masks)  # an empty folder


def test_sdxl_env_var_names_model(tmp_path, monkeypatch):
    monkeypatch.setenv("ROODI_SDXL_MODEL", str(tmp_path))
    assert get_inpainter("sdxl").model == str(tmp_path)
    assert os.environ["HF_HUB_OFFLINE"] == "1"
