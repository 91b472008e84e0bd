"""Issue 37: what no training view saw gets Gaussians. A sleeve hides the lower half of a cylinder from every view:
the weight-free fill builds a wall of new, opaque Gaussians down to the floor, the see-through test does not carve
it away behind a thin, half-transparent sleeve, and the refinement frames its views round the completed object and
draws the hidden part before and after."""

from __future__ import annotations

import json

import numpy as np
import torch

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, object_extent, seen_empty, seen_through
from roodi_toolkit.pipeline.support import extrude_to_support, shell_to_support
from roodi_toolkit.render.renderer import TorchRenderer

RIM = 0.6  # the sleeve's rim: the cylinder below it is never seen


def ring(n, radius, z0, z1, rng, *, scale, opacity, rgb, sh_degree=0):
    """Gaussians on a vertical cylinder's surface (round the z axis) between heights z0 and z1."""
    a = rng.uniform(0, 2 * np.pi, n)
    p = np.c_[radius * np.cos(a), radius * np.sin(a), rng.uniform(z0, z1, n)]
    op = np.full(n, opacity) if np.isscalar(opacity) else opacity
    cloud = GaussianCloud.from_activated(p, scales=np.full((n, 3), scale), opacities=op,
                                         rgb=np.broadcast_to(np.asarray(rgb, float), (n, 3)), sh_degree=sh_degree)
    cloud.sh_rest[:] = rng.normal(0, 0.1, cloud.sh_rest.shape)  # view-dependent colour the fill does not copy
    return cloud


def trained_like_top(seed=0):
    """The seen top of a green cylinder (radius 0.2, 0 to 1 high) as a trained model holds it: sparse and
    half-transparent Gaussians; and the intact cylinder."""
    rng = np.random.default_rng(seed)
    seen = ring(300, 0.2, RIM, 1.0, rng, scale=0.025, opacity=rng.uniform(0.15, 0.5, 300), rgb=(0.2, 0.5, 0.25),
                sh_degree=1)
    whole = ring(6000, 0.2, 0.0, 1.0, rng, scale=0.02, opacity=0.95, rgb=(0.2, 0.5, 0.25), sh_degree=1)
    return seen, whole


def side_views(n=4, size=40, elevation=15.0):
    el = np.radians(elevation)
    return [Camera(look_at([3 * np.cos(a) * np.cos(el), 3 * np.sin(a) * np.cos(el), 0.5 + 3 * np.sin(el)],
                           [0, 0, 0.5]), intrinsics_from_fov(0.6, size, size), size, size)
            for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]


def alphas(cloud, cams):
    p = GaussianParams.from_cloud(cloud)
    with torch.no_grad():
        return np.stack([TorchRenderer().render(p, c).alpha[..., 0].numpy() for c in cams])


def test_the_wall_covers_what_a_sleeve_hid_where_copies_of_a_sparse_band_leave_gaps():
    seen, whole = trained_like_top()
    wall = shell_to_support(seen, (0, 0, 1), 0.0)
    # new Gaussians on the hidden part's surface, from the floor to the band, flat along it and opaque
    r = np.linalg.norm(wall.means[:, :2], axis=1)
    assert len(wall) > 200 and np.abs(r - 0.2).max() < 0.03
    assert wall.means[:, 2].min() > 0 and wall.means[:, 2].max() < RIM + 0.05
    radial = np.c_[wall.means[:, :2] / r[:, None], np.zeros(len(wall))]
    thin = np.argmin(wall.scales, axis=1)
    thin_axis = wall.rotations()[np.arange(len(wall)), :, thin]
    assert np.abs(np.sum(thin_axis * radial, axis=1)).min() > 0.99  # the thinnest axis points across the wall
    np.testing.assert_allclose(wall.opacities, 0.9, atol=1e-5)
    np.testing.assert_allclose(np.median(wall.rgb, axis=0), (0.2, 0.5, 0.25), atol=0.01)  # the band's colour
    assert wall.sh_degree == seen.sh_degree == 1 and np.abs(wall.sh_rest).max() == 0
    # the hidden part's pixels in views from the side: the wall covers them, copies of the band do not
    from scipy.ndimage import binary_erosion

    cams = side_views()
    hidden = (alphas(whole, cams) > 0.5) & (alphas(seen, cams) < 0.5)
    hidden = np.stack([binary_erosion(h) for h in hidden])  # inside its outline (the truth's Gaussians are round)
    assert hidden.sum() > 300
    covered = (alphas(GaussianCloud.concatenate([seen, wall]), cams) > 0.5)[hidden].mean()
    copies = (alphas(GaussianCloud.concatenate([seen, extrude_to_support(seen, (0, 0, 1), 0.0)]), cams)
              > 0.5)[hidden].mean()
    assert covered > 0.97 > copies + 0.05
    # no gap to fill, or too few band Gaussians: nothing
    assert len(shell_to_support(seen, (0, 0, 1), RIM + 0.1)) == 0
    assert len(shell_to_support(seen.select(np.arange(2)), (0, 0, 1), 0.0)) == 0


def sleeve_scene(seed=1):
    """The seen top, a thin half-transparent sleeve round the cylinder's lower part (radius 0.24, up to the rim)
    and a floor, as a trained scene holds them: nothing inside the sleeve."""
    rng = np.random.default_rng(seed)
    seen, whole = trained_like_top(seed)
    sleeve = ring(1500, 0.24, 0.0, RIM, rng, scale=0.02, opacity=0.35, rgb=(0.6, 0.3, 0.3), sh_degree=1)
    g = rng.uniform(-1.5, 1.5, size=(4000, 2))
    g = g[np.linalg.norm(g, axis=1) > 0.25]  # the floor inside the sleeve was never seen
    floor = GaussianCloud.from_activated(np.c_[g, np.zeros(len(g))], scales=np.full((len(g), 3), 0.05),
                                         opacities=np.full(len(g), 0.95), rgb=np.full((len(g), 3), 0.85), sh_degree=1)
    return seen, whole, GaussianCloud.concatenate([floor, sleeve, seen])


def training_views(n=8, size=32, elevation=35.0):
    el = np.radians(elevation)
    return [Camera(look_at([3 * np.cos(a) * np.cos(el), 3 * np.sin(a) * np.cos(el), 3 * np.sin(el)], [0, 0, 0.4]),
                   intrinsics_from_fov(0.9, size, size), size, size, name=f"t{k}")
            for k, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False))]


def test_seen_through_counts_the_alpha_in_front_where_the_expected_depth_looks_past_a_thin_wall():
    """A half-transparent wall 2 in front of the camera, an opaque one 5 away: the expected depth between them
    (about 2.9) lies beyond a point just behind the thin wall, which it calls seen through; the alpha in front of
    that point (0.7) says the view did not see it."""
    cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(0.6, 24, 24), 24, 24)
    walls = GaussianCloud.from_activated(np.array([[0.0, -1.0, 0.0], [0.0, 2.0, 0.0]]),
                                         scales=np.array([[3.0, 0.01, 3.0], [3.0, 0.01, 3.0]]),
                                         opacities=np.array([0.7, 0.99]), rgb=np.full((2, 3), 0.5))
    with torch.no_grad():
        depth = TorchRenderer().render(GaussianParams.from_cloud(walls), cam).depth[..., 0].numpy()
    rng = np.random.default_rng(0)
    xz = rng.uniform(-0.3, 0.3, (50, 2))
    behind = np.c_[xz[:, 0], np.full(50, -0.8), xz[:, 1]]  # between the walls, hidden by the thin one
    before = np.c_[xz[:, 0], np.full(50, -1.5), xz[:, 1]]  # in front of it
    masks = np.zeros((1, 24, 24), bool)
    assert seen_empty(behind, [cam], masks, depth[None], 0.05).all()
    assert not seen_through(behind, [cam], masks, walls, 0.05).any()
    assert seen_through(before, [cam], masks, walls, 0.05).all()
    masks[:] = True  # the object's own pixels are never seen through
    assert not seen_through(before, [cam], masks, walls, 0.05).any()


def test_refine_frames_the_completed_object_and_draws_its_hidden_part(tmp_path):
    from roodi_toolkit.pipeline.finetune import FinetuneConfig, refine_object
    from roodi_toolkit.run.refine import write_refine_debug

    seen, whole, scene = sleeve_scene()
    cams = training_views()
    params = GaussianParams.from_cloud(scene)
    params.features = torch.from_numpy(np.r_[np.zeros(len(scene) - len(seen)), np.ones(len(seen))])[:, None].float()
    with torch.no_grad():
        outs = [TorchRenderer().render(params, c, background=torch.ones(3)) for c in cams]
    images = torch.stack([o.rgb.clamp(0, 1) for o in outs])
    masks = torch.stack([o.features[..., 0] > 0.5 for o in outs])
    res = refine_object(seen, scene, images, cams, masks, inpainter="symmetry",
                        occlusion=OcclusionConfig(size=32), finetune=FinetuneConfig(iterations=2),
                        up=(0, 0, 1))
    write_refine_debug(res, tmp_path)
    record = json.loads((tmp_path / "refine.json").read_text())
    assert abs(record["support"]) < 0.05 and record["completion_gaussians"] > 100 and res.proposed > 100
    # the views frame the object with its completion, not the seen top alone
    top_centre, top_radius = object_extent(seen)
    assert res.occlusion.centre[2] < top_centre[2] - 0.2 and res.occlusion.radius > top_radius + 0.2
    from scipy.ndimage import binary_erosion

    hidden_views = (alphas(whole, res.occlusion.cameras) > 0.5) & (alphas(seen, res.occlusion.cameras) < 0.5)
    hidden_views = np.stack([binary_erosion(h) for h in hidden_views])
    assert hidden_views.sum() > 200 and (alphas(res.cloud, res.occlusion.cameras) > 0.5)[hidden_views].mean() > 0.9
    # the fallback leaves the background round the completed silhouette as it was
    shown = res.occlusion.object_alpha.numpy() >= 0.5
    outside = ~(alphas(GaussianCloud.concatenate([seen, whole]), res.occlusion.cameras) > 0.05) & ~shown
    assert outside.sum() > 500 and np.abs(res.inpainted.numpy()[outside] - 1.0).max() < 0.02
    assert (tmp_path / "hidden_part.png").is_file()


def test_support_is_found_under_a_seen_part_a_third_of_the_object_high():
    """A plant whose pot a sleeve hides: the seen leaves (0.24 to 0.3 high, 0.06 wide) are a fifth of its height,
    the floor 0.24 under them, a sleeve's rim at 0.2 round the pot: the support is the floor."""
    from roodi_toolkit.pipeline.support import support_height

    rng = np.random.default_rng(4)
    leaves = GaussianCloud.from_activated(np.c_[rng.normal(0, 0.03, (200, 2)), rng.uniform(0.24, 0.3, 200)],
                                          scales=np.full((200, 3), 0.01), opacities=np.full(200, 0.8),
                                          rgb=np.full((200, 3), 0.3))
    rim = ring(120, 0.09, 0.195, 0.205, rng, scale=0.01, opacity=0.9, rgb=(0.5, 0.2, 0.2))
    g = rng.uniform(-0.5, 0.5, size=(3000, 2))
    g = g[np.linalg.norm(g, axis=1) > 0.1]  # not inside the sleeve
    floor = GaussianCloud.from_activated(np.c_[g, rng.normal(0, 0.002, len(g))], scales=np.full((len(g), 3), 0.02),
                                         opacities=np.full(len(g), 0.9), rgb=np.full((len(g), 3), 0.7))
    support = support_height(leaves, GaussianCloud.concatenate([floor, rim, leaves]), (0, 0, 1))
    assert support is not None and abs(support) < 0.02
