"""The weight-free fills of issue 22: the ``exemplar`` inpainter continues a texture where a trivial fill cannot, the
``symmetry`` inpainter restores the removed half of a mirror-symmetric object, both are plugins of the
``roodi_toolkit.inpainters`` group, and the refinement adopts what a 3D completion proposes and draws the fill."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.pipeline.exemplar import ExemplarInpainter, exemplar_fill
from roodi_toolkit.pipeline.inpaint import FillContext, OpenCVInpainter, get_inpainter, inpaint_views
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, fill_picture, object_cameras, seen_empty
from roodi_toolkit.pipeline.support import extrude_to_support, support_height
from roodi_toolkit.pipeline.symmetry import SymmetryInpainter, find_mirror, mirror_cloud
from roodi_toolkit.plugins import discover
from roodi_toolkit.render.renderer import TorchRenderer


def test_fills_are_plugins_of_the_inpainter_group():
    specs = {s.name: s for s in discover("inpainters")}
    assert {"exemplar", "symmetry"} <= set(specs)
    assert specs["exemplar"].origin == specs["symmetry"].origin == "roodi-toolkit"
    assert specs["exemplar"].load() is ExemplarInpainter and specs["symmetry"].load() is SymmetryInpainter
    assert isinstance(get_inpainter("symmetry", fallback="opencv").fallback, OpenCVInpainter)
    with pytest.raises(ConfigError):
        get_inpainter("exemplar", patch=4)
    with pytest.raises(ConfigError):
        SymmetryInpainter(fallback="symmetry")


def striped_object(size=48):
    """An object (a disc) with diagonal stripes on white, a hole in it, and the mask occlusion reasoning would make
    (the hole plus all of the background)."""
    yy, xx = np.mgrid[0:size, 0:size]
    disc = (xx - size / 2) ** 2 + (yy - size / 2) ** 2 < (0.42 * size) ** 2
    stripes = ((xx + yy) // 4) % 2 == 1
    img = np.ones((size, size, 3), np.float32)
    img[disc & stripes] = (0.8, 0.2, 0.1)
    img[disc & ~stripes] = (0.1, 0.3, 0.8)
    hole = disc & (np.abs(xx - size * 0.62) < size * 0.12) & (np.abs(yy - size / 2) < size * 0.15)
    return torch.from_numpy(img), torch.from_numpy(hole), torch.from_numpy(hole | ~disc)


def test_exemplar_continues_stripes_better_than_trivial_fills_and_keeps_known_pixels():
    truth, hole, mask = striped_object()
    corrupted = truth.clone()
    corrupted[mask] = 1.0
    out = ExemplarInpainter().inpaint(corrupted[None], mask[None])[0]
    assert torch.equal(out[~mask], corrupted[~mask])  # unmasked pixels exact
    err = (out - truth).abs()[hole].mean()
    mean_fill = (corrupted[~mask].mean(0) - truth[hole]).abs().mean()  # the object's mean colour
    smear = (OpenCVInpainter().inpaint(corrupted[None], mask[None])[0] - truth).abs()[hole].mean()
    assert err < 0.5 * mean_fill and err < 0.7 * smear
    # background far outside the object's outline stays as rendered
    assert torch.equal(out[:2], corrupted[:2])


def test_exemplar_copies_from_the_other_views_of_the_grid():
    truth, hole, mask = striped_object(32)
    views, masks = truth[None].repeat(4, 1, 1, 1), torch.zeros(4, 32, 32, dtype=torch.bool)
    masks[0] = mask  # only view 0 has a hole; the other three views show the whole object
    masks[1:] = mask & ~hole
    corrupted = views.clone()
    corrupted[masks] = 1.0
    out, _ = inpaint_views(ExemplarInpainter(), corrupted, masks)
    assert (out[0] - truth).abs()[hole].mean() < 0.15


def test_exemplar_fill_without_sources_says_so():
    img = np.zeros((8, 8, 3), np.float32)
    region = np.ones((8, 8), bool)
    region[0, 0] = False
    assert exemplar_fill(img, region, patch=3) is None


def symmetric_object(n=2500, seed=0):
    """A mirror-symmetric object about the plane x = 0.2 (an ellipsoid shell whose colour depends on y and z) and
    which of its Gaussians lie on the +x side (to be removed)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    p = d / np.linalg.norm(d, axis=1, keepdims=True) * [0.6, 0.35, 0.3]
    rgb = np.stack([0.5 + 0.8 * p[:, 1], 0.5 + 1.0 * p[:, 2], np.full(n, 0.4)], 1)
    cloud = GaussianCloud.from_activated(p + [0.2, 0, 0], scales=np.full((n, 3), 0.03), opacities=np.full(n, 0.95),
                                         rgb=np.clip(rgb, 0, 1))
    return cloud, p[:, 0] > 0.25


def test_mirror_cloud_is_an_involution_and_find_mirror_finds_the_plane():
    cloud, removed = symmetric_object()
    twice = mirror_cloud(mirror_cloud(cloud, [1, 0, 0], 0.2), [1, 0, 0], 0.2)
    np.testing.assert_allclose(twice.means, cloud.means, atol=1e-5)
    np.testing.assert_allclose(twice.covariances(), cloud.covariances(), atol=1e-6)
    m = find_mirror(cloud.select(~removed), up=(0, 0, 1))
    # the plane leans towards the seen part a little (find_mirror's docstring)
    assert abs(m.normal[0]) > 0.99 and abs(m.offset * np.sign(m.normal[0]) - 0.2) < 0.07 and m.agreement > 0.4


def test_symmetry_restores_the_removed_half_of_a_symmetric_object():
    cloud, removed = symmetric_object()
    cut = cloud.select(~removed)
    cams = object_cameras([0.2, 0, 0], 0.7, OcclusionConfig(size=32, seed=3))
    r = TorchRenderer()

    def render(c):
        p = GaussianParams.from_cloud(c)
        with torch.no_grad():
            outs = [r.render(p, cam, background=torch.ones(3)) for cam in cams]
        return torch.stack([o.rgb.clamp(0, 1) for o in outs]), torch.stack([o.alpha[..., 0] for o in outs])

    truth, truth_alpha = render(cloud)
    before, alpha = render(cut)
    mask = alpha < 0.5  # the background, where the missing half shows in the truth
    missing = (truth_alpha >= 0.5) & mask
    assert missing.float().mean() > 0.05
    context = FillContext(cut, cams, r, up=(0, 0, 1))
    filled, _ = inpaint_views(SymmetryInpainter(), before, mask, context=context)
    assert torch.equal(filled[~mask], before[~mask])
    err = (filled - truth).abs()[missing].mean()
    exemplar, _ = inpaint_views(ExemplarInpainter(), before, mask)
    assert err < 0.5 * (before - truth).abs()[missing].mean()  # the trivial fill: the background left as it was
    assert err < 0.7 * (exemplar - truth).abs()[missing].mean()
    # the proposed Gaussians are the removed half's mirror image: each near a removed Gaussian
    assert context.proposed is not None and len(context.proposed) > 0.5 * removed.sum()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(cloud.means[removed]).query(context.proposed.means)
    assert np.median(d) < 0.05  # under two Gaussian spacings (about 0.028) on an object 1.2 long
    # what a training view sees through is not proposed
    everything = np.ones(3, bool)
    context = FillContext(cut, cams, r, up=(0, 0, 1), seen_empty=lambda pts: np.broadcast_to(everything[:1], len(pts)))
    inpaint_views(SymmetryInpainter(), before, mask, context=context)
    assert context.proposed is None


def _bottle(n: int = 3000, seed: int = 0):
    """A vertical cylinder's surface (radius 0.2, z 0 to 1, a colour band) standing on z = 0; its part under z = 0.5
    is the one a sleeve hid."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, 1, n)
    p = np.c_[0.2 * np.cos(a), 0.2 * np.sin(a), z]
    rgb = np.c_[np.full(n, 0.2), 0.5 + 0.3 * np.sin(a), np.full(n, 0.3)]
    cloud = GaussianCloud.from_activated(p, scales=np.full((n, 3), 0.02), opacities=np.full(n, 0.9), rgb=rgb)
    return cloud, z < 0.5


def test_support_height_and_extrusion_complete_what_a_sleeve_hid():
    cloud, hidden = _bottle()
    seen = cloud.select(~hidden)
    rng = np.random.default_rng(1)
    floor = GaussianCloud.from_activated(np.c_[rng.uniform(-1.5, 1.5, (4000, 2)), np.zeros(4000)],
                                         scales=np.full((4000, 3), 0.03), opacities=np.full(4000, 0.9),
                                         rgb=np.full((4000, 3), 0.8))
    sleeve_floor = floor.select(np.linalg.norm(floor.means[:, :2], axis=1) > 0.35)  # no floor seen inside the sleeve
    support = support_height(seen, GaussianCloud.concatenate([sleeve_floor, seen]), (0, 0, 1))
    assert support is not None and abs(support) < 0.03
    out = extrude_to_support(seen, (0, 0, 1), support)
    assert out.means[:, 2].min() >= support - 1e-6 and out.means[:, 2].max() < 0.5 + 0.1 * 0.5
    assert 0.8 * hidden.sum() < len(out) < 1.5 * hidden.sum()  # the object's own density, not a pile-up
    # the copies lie on the hidden part's surface, end where the support begins and take the band's mean colour
    r = np.linalg.norm(out.means[:, :2], axis=1)
    assert np.abs(r - 0.2).max() < 1e-5
    spread = np.sqrt(out.covariances()[:, 2, 2])
    assert (out.means[:, 2] - 2 * spread >= support - 1e-6).all()
    z = seen.means[:, 2]
    lowest = np.quantile(z, 0.02)
    band = seen.select(z <= lowest + 0.1 * (z.max() - lowest))  # the slab extrude_to_support copies
    np.testing.assert_allclose(out.rgb, np.broadcast_to(band.rgb.mean(axis=0), out.rgb.shape), atol=1e-5)
    as_is = extrude_to_support(seen, (0, 0, 1), support, mean_colour=False, reach=0.0)
    assert len(as_is) > len(out) and np.ptp(as_is.rgb, axis=0).max() > 0.1  # the band repeated, colours and all
    from scipy.spatial import cKDTree

    d, _ = cKDTree(out.means).query(cloud.means[hidden])
    assert np.quantile(d, 0.95) < 0.08  # every hidden point has a copy near it
    assert support_height(seen, seen, (0, 0, 1)) is None  # nothing under the object: no support
    assert len(extrude_to_support(seen, (0, 0, 1), 0.7)) == 0  # a support above the lowest point: nothing to do


def test_symmetry_inpainter_proposes_the_extrusion_and_respects_what_views_see_through():
    cloud, hidden = _bottle(1500)
    seen = cloud.select(~hidden)
    cams = object_cameras([0, 0, 0.5], 0.6, OcclusionConfig(size=24, seed=2))
    r = TorchRenderer()
    p = GaussianParams.from_cloud(seen)
    with torch.no_grad():
        outs = [r.render(p, cam, background=torch.ones(3)) for cam in cams]
    before = torch.stack([o.rgb.clamp(0, 1) for o in outs])
    mask = torch.stack([o.alpha[..., 0] for o in outs]) < 0.5
    inp = SymmetryInpainter(mirror=False)  # the extrusion alone
    context = FillContext(seen, cams, r, up=(0, 0, 1), support=0.0)
    inpaint_views(inp, before, mask, context=context)
    assert inp.last_extruded > 0 and context.proposed is not None
    assert context.proposed.means[:, 2].max() < 0.52 and len(context.proposed) > 0.5 * hidden.sum()
    # a view that saw empty space under z = 0.25 keeps the copies out of it
    context = FillContext(seen, cams, r, up=(0, 0, 1), support=0.0, seen_empty=lambda pts: pts[:, 2] < 0.25)
    inpaint_views(inp, before, mask, context=context)
    assert context.proposed is not None and context.proposed.means[:, 2].min() >= 0.25
    # without a known support (or with extrude=False) nothing is proposed
    for inpainter, ctx in ((inp, FillContext(seen, cams, r, up=(0, 0, 1))),
                           (SymmetryInpainter(mirror=False, extrude=False),
                            FillContext(seen, cams, r, up=(0, 0, 1), support=0.0))):
        inpaint_views(inpainter, before, mask, context=ctx)
        assert ctx.proposed is None


def test_seen_empty_and_fill_picture():
    cloud, _ = symmetric_object(400)
    cams = object_cameras([0.2, 0, 0], 0.7, OcclusionConfig(size=16, seed=1))
    masks = np.zeros((4, 16, 16), bool)
    depths = np.zeros((4, 16, 16))
    assert seen_empty(cloud.means, cams, masks, depths, 0.01).all()  # nothing anywhere: all seen through
    assert not seen_empty(cloud.means, cams, ~masks, depths, 0.01).any()  # the object everywhere
    before, after = torch.ones(4, 16, 16, 3), torch.zeros(4, 16, 16, 3)
    filled = torch.zeros(4, 16, 16, dtype=torch.bool)
    filled[:, 4:12, 4:12] = True
    pic = fill_picture(before, after, filled, gap=2)  # 16 px views are drawn 8 times larger
    assert pic.shape == (2 * 128 + 2, 4 * 128 + 6, 3)
    assert tuple(pic[32, 32]) == pytest.approx((1.0, 0.1, 0.1))  # the outline, in both rows
    assert tuple(pic[130 + 32, 32]) == pytest.approx((1.0, 0.1, 0.1))
    assert tuple(pic[64, 64]) == pytest.approx((1.0, 0.775, 0.775))  # inside: tinted
    assert tuple(pic[0, 0]) == (1.0, 1.0, 1.0)


def test_refine_with_symmetry_adopts_the_proposed_gaussians_and_draws_the_fill(tmp_path):
    from roodi_toolkit.pipeline.finetune import FinetuneConfig, refine_object
    from roodi_toolkit.run.refine import write_refine_debug

    cloud, removed = symmetric_object(1500)
    cut = cloud.select(~removed)
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at

    # training views from the -x side only: the removed +x half is never seen (not seen empty either)
    cams = [Camera(look_at([0.2 + 3 * np.cos(a), 3 * np.sin(a), 1.0], [0.2, 0, 0]), intrinsics_from_fov(0.8, 24, 24),
                   24, 24) for a in np.radians([150.0, 180.0, 210.0])]
    p = GaussianParams.from_cloud(cut)
    with torch.no_grad():
        outs = [TorchRenderer().render(p, c, background=torch.ones(3)) for c in cams]
    images = torch.stack([o.rgb.clamp(0, 1) for o in outs])
    masks = torch.stack([o.alpha[..., 0] > 0.5 for o in outs])
    res = refine_object(cut, cut, images, cams, masks, inpainter="symmetry", occlusion=OcclusionConfig(size=24),
                        finetune=FinetuneConfig(iterations=2), up=(0, 0, 1))
    write_refine_debug(res, tmp_path)
    record = json.loads((tmp_path / "refine.json").read_text())
    assert record["proposed_gaussians"] == res.proposed and record["mirror"]["agreement"] > 0.5
    assert len(res.cloud) == len(cut) + res.proposed
    assert (tmp_path / "fill_before_after.png").is_file() and (tmp_path / "fill_views.png").is_file()
    assert res.filled is not None and res.filled.shape == (4, 24, 24)
    off = refine_object(cut, cut, images, cams, masks, inpainter="symmetry", occlusion=OcclusionConfig(size=24),
                        finetune=FinetuneConfig(iterations=2, adopt_proposed=False), up=(0, 0, 1))
    assert len(off.cloud) == len(cut)
