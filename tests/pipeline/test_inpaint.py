"""The inpainter interface, run against every inpainter registered under ``roodi_toolkit.inpainters``; the grid
helpers; the built-in ``opencv`` inpainter; and a third-party inpainter registered from outside the package, both
through ``$ROODI_PLUGINS`` and as an installed distribution's entry point, driving the whole refinement.

The ``sdxl`` plugin runs here on a tiny randomly initialised pipeline (tests/tiny_sdxl.py); any other plugin runs with
its defaults, or is skipped with its own reason when it says it cannot run on this machine.
"""

from __future__ import annotations

import importlib
import sys
import textwrap

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError, PluginError
from roodi_toolkit.pipeline.inpaint import (Inpainter, OpenCVInpainter, from_grid, get_inpainter, inpaint_views,
                                   inpainter_names, to_grid)
from roodi_toolkit.plugins import discover

NAMES = [spec.name for spec in discover("inpainters")]


def test_builtin_opencv_is_registered():
    assert "opencv" in inpainter_names()
    assert [s.origin for s in discover("inpainters") if s.name == "opencv"] == ["roodi-toolkit"]


def _test_options(name, tmp_path_factory):
    if name == "sdxl":
        pytest.importorskip("diffusers")
        from ..tiny_sdxl import tiny_pipeline

        return {"pipeline": tiny_pipeline(tmp_path_factory.mktemp("tiny_sdxl")), "resolution": 32, "steps": 2}
    return {}


@pytest.fixture(scope="module", params=NAMES)
def inpainter(request, tmp_path_factory) -> Inpainter:
    cls = discover("inpainters")[NAMES.index(request.param)].load()
    assert isinstance(cls, type) and issubclass(cls, Inpainter), f"{request.param} is not an Inpainter subclass"
    ok, why = cls.available()
    if not ok:
        assert why, "an unavailable inpainter must say why"
        pytest.skip(f"{request.param}: {why}")
    return get_inpainter(request.param, **_test_options(request.param, tmp_path_factory))


def smooth_batch(b=2, h=24, w=24, seed=0):
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    base = torch.stack([x, y, 0.5 * (x + y)], dim=-1)
    images = (0.2 + 0.6 * base)[None].repeat(b, 1, 1, 1) + 0.02 * torch.rand(b, h, w, 3, generator=g)
    masks = torch.zeros(b, h, w, dtype=torch.bool)
    masks[:, 8:16, 6:14] = True
    masks[b - 1, 2:5, 18:22] = True
    corrupted = images.clone()
    corrupted[masks] = 0.0  # what is under the mask must not leak into the result
    return images, corrupted, masks


def test_interface_shapes_ranges_and_unmasked_pixels_unchanged(inpainter):
    _, corrupted, masks = smooth_batch()
    out = inpainter.inpaint(corrupted, masks)
    assert out.shape == corrupted.shape and out.dtype == torch.float32
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    assert torch.equal(out[~masks], corrupted[~masks])
    assert (out[masks] - corrupted[masks]).abs().mean() > 0.05  # the masked (black) pixels were filled


def test_interface_empty_mask_is_identity_and_runs_are_repeatable(inpainter):
    _, corrupted, masks = smooth_batch(b=1)
    assert torch.equal(inpainter.inpaint(corrupted, torch.zeros_like(masks)), corrupted)
    a = inpainter.inpaint(corrupted, masks, prompt="")
    b = inpainter.inpaint(corrupted, masks.float())  # float masks are thresholded at 0.5
    torch.testing.assert_close(a, b)


def test_interface_grid_of_four_views(inpainter):
    _, corrupted, masks = smooth_batch(b=4, h=16, w=16)
    out, grids = inpaint_views(inpainter, corrupted, masks)
    assert out.shape == (4, 16, 16, 3) and grids["before"].shape == (32, 32, 3) and grids["mask"].shape == (32, 32)
    assert torch.equal(out[~masks], corrupted[~masks])
    assert torch.equal(from_grid(grids["after"]), out)


def test_interface_rejects_bad_inputs(inpainter):
    images, _, masks = smooth_batch(b=1)
    with pytest.raises(ConfigError):
        inpainter.inpaint(images[0], masks[0])
    with pytest.raises(ConfigError):
        inpainter.inpaint(images, masks[:, :-1])
    with pytest.raises(ConfigError):
        inpainter.inpaint(images * 3, masks)


def test_grid_layout_and_round_trip():
    v = torch.stack([torch.full((3, 5), float(i)) for i in range(4)])
    g = to_grid(v)
    assert g.shape == (6, 10)
    assert g[0, 0] == 0 and g[0, 9] == 1 and g[5, 0] == 2 and g[5, 9] == 3
    x = torch.rand(6, 4, 3, 2)
    assert torch.equal(from_grid(to_grid(x, 2, 3), 2, 3), x)
    with pytest.raises(ConfigError):
        to_grid(torch.rand(3, 4, 4, 3))
    with pytest.raises(ConfigError):
        from_grid(torch.rand(5, 4, 3))


def test_opencv_fills_a_hole_in_a_gradient_and_respects_the_outline():
    images, corrupted, masks = smooth_batch(b=1, h=48, w=48)
    masks[:] = False
    masks[0, 14:34, 14:34] = True  # a large hole
    for levels in (1, 3):
        out = OpenCVInpainter(levels=levels).inpaint(corrupted, masks)
        assert (out[masks] - images[masks]).abs().mean() < 0.08
    # an object on white; the mask is its hole plus all of the background (as occlusion reasoning makes it)
    img = torch.ones(1, 48, 48, 3)
    obj = torch.zeros(48, 48, dtype=torch.bool)
    obj[10:38, 10:38] = True
    img[0][obj] = torch.tensor([0.8, 0.3, 0.1])
    hole = torch.zeros_like(obj)
    hole[20:28, 20:28] = True
    img[0][hole] = 1.0
    mask = (~obj | hole)[None]
    out = OpenCVInpainter().inpaint(img, mask)
    torch.testing.assert_close(out[0][hole], torch.tensor([0.8, 0.3, 0.1]).expand(64, 3), atol=0.02, rtol=0)
    far = torch.zeros_like(obj)
    far[:4] = True
    assert torch.equal(out[0][far], img[0][far])  # background far outside the outline is left as rendered
    everything = OpenCVInpainter(extent="all").inpaint(img, mask)
    assert (everything[0][far] - 1).abs().max() > 0.1  # "all" smears the object over the background
    with pytest.raises(ConfigError):
        OpenCVInpainter(method="magic")


def test_get_inpainter_errors():
    with pytest.raises(PluginError, match="available: .*opencv"):
        get_inpainter("no-such-inpainter")
    with pytest.raises(PluginError, match="does not take"):
        get_inpainter("opencv", colour="red")


# -------------------------------------------------------------------------------------------- third-party plugins

PLUGIN_SOURCE = textwrap.dedent('''
    """A third party's inpainter: fills the mask with the mean colour of the unmasked pixels."""
    import torch
    from roodi_toolkit.pipeline.inpaint import Inpainter

    class MeanInpainter(Inpainter):
        name = "mean"

        def fill(self, images, masks, prompt):
            out = images.clone()
            for b in range(images.shape[0]):
                known = images[b][~masks[b]]
                out[b][masks[b]] = known.mean(dim=0) if len(known) else 0.5
            return out
''')


def tiny_refine_inputs():
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
    from roodi_toolkit.gaussians import GaussianCloud

    rng = np.random.default_rng(0)
    d = rng.normal(size=(300, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * 0.5
    obj = GaussianCloud.from_activated(pts, scales=np.full((300, 3), 0.08), opacities=np.full(300, 0.9),
                                       rgb=np.tile([0.8, 0.2, 0.2], (300, 1)))
    card_pts = np.c_[rng.uniform(-0.3, 0.3, 200), np.full(200, -1.2), rng.uniform(-0.3, 0.3, 200)]
    card = GaussianCloud.from_activated(card_pts, scales=np.full((200, 3), 0.06), opacities=np.full(200, 0.9),
                                        rgb=np.tile([0.1, 0.8, 0.1], (200, 1)))
    scene = GaussianCloud.concatenate([obj, card])
    cams = [Camera(look_at([3 * np.cos(a), 3 * np.sin(a), 1.0], [0, 0, 0]), intrinsics_from_fov(0.8, 24, 24), 24, 24)
            for a in np.linspace(0, 2 * np.pi, 4, endpoint=False)]
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.render.renderer import TorchRenderer

    params = GaussianParams.from_cloud(obj)
    with torch.no_grad():
        outs = [TorchRenderer().render(params, c, background=torch.ones(3)) for c in cams]
    images = torch.stack([o.rgb.clamp(0, 1) for o in outs])
    masks = torch.stack([o.alpha[..., 0] > 0.5 for o in outs])
    return obj, scene, images, cams, masks


def _run_refine_with(name, tmp_path):
    from roodi_toolkit.pipeline.finetune import FinetuneConfig, refine_object
    from roodi_toolkit.run.refine import write_refine_debug
    from roodi_toolkit.pipeline.occlusion import OcclusionConfig

    obj, scene, images, cams, masks = tiny_refine_inputs()
    res = refine_object(obj, scene, images, cams, masks, inpainter=name, occlusion=OcclusionConfig(size=24),
                        finetune=FinetuneConfig(iterations=4))
    write_refine_debug(res, tmp_path / "debug")
    assert res.inpainter == "mean"
    # the mean inpainter's signature: every masked pixel of the grid has one colour
    grid_mask = to_grid(res.occlusion.mask)
    after = to_grid(res.inpainted)
    filled = after[grid_mask]
    assert filled.shape[0] > 0 and (filled - filled[0]).abs().max() < 1e-6
    assert (tmp_path / "debug" / "grid_after.png").is_file()
    return res


def test_third_party_inpainter_via_env_var(tmp_path, monkeypatch):
    (tmp_path / "third_party_inpaint.py").write_text(PLUGIN_SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("ROODI_PLUGINS", "inpainters:mean=third_party_inpaint:MeanInpainter")
    assert "mean" in inpainter_names()
    _run_refine_with("mean", tmp_path)


def test_third_party_inpainter_as_installed_distribution(tmp_path, monkeypatch):
    """A distribution on sys.path with the two lines of packaging docs/plugins.md shows (as pip would install it)."""
    site = tmp_path / "site"
    (site / "roodi_mean").mkdir(parents=True)
    (site / "roodi_mean" / "__init__.py").write_text(PLUGIN_SOURCE)
    info = site / "roodi_mean-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: roodi-mean\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[roodi_toolkit.inpainters]\nmean = roodi_mean:MeanInpainter\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delenv("ROODI_PLUGINS", raising=False)
    importlib.invalidate_caches()
    specs = {s.name: s for s in discover("inpainters")}
    assert specs["mean"].origin == "roodi-mean"
    _run_refine_with("mean", tmp_path)
    sys.modules.pop("roodi_mean", None)


def test_broken_third_party_inpainter_is_reported_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv("ROODI_PLUGINS", "inpainters:broken=no_such_module_xyz:Thing")
    assert "opencv" in inpainter_names()
    with pytest.raises(PluginError, match="broken"):
        get_inpainter("broken")
    (tmp_path / "not_an_inpainter.py").write_text("class Thing:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("ROODI_PLUGINS", "inpainters:thing=not_an_inpainter:Thing")
    with pytest.raises(PluginError, match="not a roodi_toolkit.pipeline.inpaint.Inpainter"):
        get_inpainter("thing")
