"""The click segmenter's free-standing test with a support's layer taken out (`click_parts.support_layer`): a person
standing on rough ground, a vase on a table over the floor, a mat lying on the ground; and the parts test
(`with_parts`) against one test per piece."""

from __future__ import annotations

import numpy as np

from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.pipeline.click import ClickSegmenter, solve_labels
from roodi_toolkit.pipeline.click_parts import is_part, pieces, standing_free, support_layer, with_parts

UP = np.array([0.0, 0.0, 1.0])


def _cloud(parts: list[np.ndarray]) -> tuple[GaussianCloud, np.ndarray]:
    means = np.concatenate(parts)
    labels = np.repeat(np.arange(len(parts)), [len(p) for p in parts])
    cloud = GaussianCloud.from_activated(means, scales=np.full((len(means), 3), 0.01),
                                         opacities=np.full(len(means), 0.9), rgb=np.full((len(means), 3), 0.2))
    return cloud, labels


def _person_on_ground():
    """A person (a body on the surfaces of two legs, 1.5 tall, the ground's dark colour) standing on a ground whose
    stones touch the feet, with a second ground far away (copies side by side: the first is not most of the scene).
    As in a splat, the ground holds more Gaussians per height than the legs."""
    rng = np.random.default_rng(0)

    def tube(x, n):  # a leg's surface
        a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.0, 0.8, n)
        return np.stack([x + 0.08 * np.cos(a), 0.08 * np.sin(a), z], axis=1)

    body = rng.uniform((-0.25, -0.15, 0.8), (0.25, 0.15, 1.5), (8000, 3))
    legs = np.concatenate([tube(-0.12, 2000), tube(0.12, 2000)])
    ground = rng.uniform((-2.0, -2.0, -0.005), (2.0, 2.0, 0.005), (80000, 3))
    stones = rng.uniform((-0.3, -0.3, 0.0), (0.3, 0.3, 0.02), (400, 3))  # rough ground at the feet
    other = rng.uniform((10.0, -2.0, -0.01), (14.0, 2.0, 0.01), (80000, 3))
    return _cloud([body, legs, ground, stones, other])


def _click(cloud: GaussianCloud, picked: np.ndarray):
    at_click = np.zeros(len(cloud))
    at_click[picked] = 1.0
    centre = cloud.means[picked].mean(axis=0)
    dist = np.linalg.norm(cloud.means[picked] - centre, axis=1)
    return at_click, centre, float(dist.max()), float(np.median(dist))


def test_a_person_on_the_ground_stands_free_without_the_grounds_layer():
    """A click on the chest: the person touches the ground (one piece with it, no free object), but without the
    ground's layer, found under the click in 3D, the whole person stands free: legs and body, not the ground."""
    cloud, labels = _person_on_ground()
    chest = np.flatnonzero((labels == 0) & (np.abs(cloud.means[:, 0]) < 0.08) & (cloud.means[:, 2] > 1.1)
                           & (cloud.means[:, 2] < 1.25))
    at_click, centre, radius0, spread = _click(cloud, chest)
    seg = ClickSegmenter()
    assert seg._parts(cloud, at_click, centre, radius0, limit=20.0) is None
    height, thickness = support_layer(cloud.means, centre, UP, spread, 20.0, at_click)
    round_feet = np.linalg.norm(cloud.means[:, :2], axis=1) < 0.6
    assert np.abs(height[(labels == 2) & round_feet]).max() < 0.02  # the ground's plane
    got, layer = standing_free(seg.settings, cloud, at_click, centre, radius0, 20.0, at_click > 0, height, thickness)
    assert layer[(labels == 2) & round_feet].all() and not layer[(labels <= 1) & (cloud.means[:, 2] > 0.2)].any()
    person = labels <= 1
    assert got[person & ~layer].all() and not got[labels == 2].any() and not got[labels == 4].any()


def test_a_thicker_layer_shaves_the_stones_off_the_feet():
    """Rough ground round the feet, stones up to 0.035 high, a tenth of the person: over the first layer (0.02,
    from a click on the head) they join the feet and the piece still stands (its foot under a tenth of it); the next
    layer leaves them out and loses the legs' slice alone, so that piece is the person."""
    rng = np.random.default_rng(4)
    cloud0, labels0 = _person_on_ground()
    person = cloud0.means[labels0 <= 1]
    stones = rng.uniform((-0.5, -0.5, 0.0), (0.5, 0.5, 0.035), (1200, 3))
    stones = stones[np.linalg.norm(stones[:, :2], axis=1) < 0.5]
    ground = cloud0.means[(labels0 == 2) | (labels0 == 4)]
    cloud, labels = _cloud([person, stones, ground])
    head = np.flatnonzero((labels == 0) & (cloud.means[:, 2] > 1.4) & (np.abs(cloud.means[:, 0]) < 0.1))
    at_click, centre, radius0, spread = _click(cloud, head)
    limit = 4.0
    height, thickness = support_layer(cloud.means, centre, UP, spread, limit, at_click)
    assert thickness < 0.035  # the first layer leaves the tallest stones
    got, layer = standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, limit, at_click > 0,
                               height, thickness)
    assert not got[labels >= 1].any()
    assert got[(labels == 0) & (cloud.means[:, 2] > 0.1)].all()


def test_a_click_on_the_foot_in_the_layer_finds_the_person_a_click_beside_it_nothing():
    """A click on the bottom of a leg, lower than the layer that leaves the stones out: its weight moves to the leg
    just over the layer, and the person stands free as from the chest. A click on the stones a hand's width from the
    foot has nothing over them within the layer's thickness: no object."""
    cloud, labels = _person_on_ground()
    leg = (labels == 1) & (cloud.means[:, 0] < 0)
    foot = np.flatnonzero(leg & (cloud.means[:, 2] < 0.03))
    at_click, centre, radius0, spread = _click(cloud, foot)
    limit = 4.0
    height, thickness = support_layer(cloud.means, centre, UP, spread, limit, at_click)
    assert at_click[height <= thickness].sum() > 0.5 * at_click.sum()  # most of the click is in the layer
    got, layer = standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, limit, at_click > 0,
                               height, thickness)
    assert not got[labels >= 2].any() and got[(labels <= 1) & ~layer].all()
    beside = np.linalg.norm(cloud.means[:, :2] - [-0.12, 0.0], axis=1)
    stones = np.flatnonzero((labels == 3) & (beside > 0.18) & (beside < 0.22) & (cloud.means[:, 1] < -0.1))
    at_click, centre, radius0, spread = _click(cloud, stones)
    support = support_layer(cloud.means, centre, UP, spread, limit, at_click)
    assert support is not None  # over the plane: the layer's test decides
    assert standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, limit, at_click > 0,
                         *support) is None


def test_an_object_lying_on_the_support_is_left_to_the_growth():
    """A flat slab lying on the ground (a mat): without the ground's layer it is a piece, but most of it lies just
    over the layer at every thickness: no object standing on the support."""
    rng = np.random.default_rng(3)
    mat = rng.uniform((-0.5, -0.5, 0.005), (0.5, 0.5, 0.04), (6000, 3))
    ground = rng.uniform((-2.0, -2.0, -0.005), (2.0, 2.0, 0.005), (80000, 3))
    other = rng.uniform((10.0, -2.0, -0.005), (14.0, 2.0, 0.005), (80000, 3))
    cloud, labels = _cloud([mat, ground, other])
    picked = np.flatnonzero((labels == 0) & (np.linalg.norm(cloud.means[:, :2], axis=1) < 0.15))
    at_click, centre, radius0, spread = _click(cloud, picked)
    support = support_layer(cloud.means, centre, UP, spread, 20.0, at_click)
    assert support is None or standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, 20.0,
                                            at_click > 0, *support) is None


def test_the_support_is_the_table_under_the_vase_not_the_floor():
    """A vase on a table top 0.7 over a wide floor: its support is the table top, the highest level plane under it,
    and without it the vase stands free; the table and the floor stay out."""
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 2 * np.pi, 3000)
    h = rng.uniform(0.7, 1.1, 3000)
    vase = np.stack([0.08 * np.cos(a), 0.08 * np.sin(a), h], axis=1)
    top = rng.uniform((-0.5, -0.5, 0.698), (0.5, 0.5, 0.702), (20000, 3))
    legs = np.concatenate([rng.uniform((x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.69), (800, 3))
                           for x in (-0.45, 0.45) for y in (-0.45, 0.45)])
    floor = rng.uniform((-4.0, -4.0, -0.01), (4.0, 4.0, 0.01), (80000, 3))
    other = rng.uniform((10.0, -4.0, -0.01), (18.0, 4.0, 0.01), (80000, 3))
    cloud, labels = _cloud([vase, top, legs, floor, other])
    side = np.flatnonzero((labels == 0) & (cloud.means[:, 0] < -0.03) & (cloud.means[:, 2] > 0.8))
    at_click, centre, radius0, spread = _click(cloud, side)
    limit = 2.0  # a tabletop capture's box
    height, thickness = support_layer(cloud.means, centre, UP, spread, limit, at_click)
    assert np.abs(height[(labels == 1) & (np.abs(cloud.means[:, :2]).max(axis=1) < 0.2)]).max() < 0.01
    got, layer = standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, limit, at_click > 0,
                               height, thickness)
    assert not layer[(labels == 0) & (cloud.means[:, 2] > 0.73)].any()
    assert got is not None and got[(labels == 0) & ~layer].all() and not got[labels >= 1].any()


def test_no_support_layer_for_a_click_on_the_ground_or_without_an_up():
    """A click on the ground is in the layer it would take out; without the scene's up nothing is level."""
    cloud, labels = _person_on_ground()
    ground = np.flatnonzero((labels == 2) & (np.abs(cloud.means[:, 0] - 1.5) < 0.1) & (np.abs(cloud.means[:, 1]) < 0.1))
    at_click, centre, radius0, spread = _click(cloud, ground)
    support = support_layer(cloud.means, centre, UP, spread, 20.0, at_click)
    assert support is None or standing_free(ClickSegmenter().settings, cloud, at_click, centre, radius0, 20.0,
                                            at_click > 0, *support) is None
    chest = np.flatnonzero((labels == 0) & (cloud.means[:, 2] > 1.1) & (cloud.means[:, 2] < 1.25))
    at_click, centre, _, spread = _click(cloud, chest)
    assert support_layer(cloud.means, centre, None, spread, 20.0, at_click) is None


def test_with_parts_takes_the_pieces_is_part_takes():
    """The parts test with the body's trees built once takes exactly the pieces that one test per piece takes: near
    the body and mostly of its colours, on a slab with pieces round it of its colour or of others."""
    s = ClickSegmenter().settings
    rng = np.random.default_rng(0)
    for _ in range(3):
        pos = np.concatenate([rng.uniform(-1, 1, (3000, 3)) * [1, 1, 0.05]] +
                             [rng.normal(size=(rng.integers(3, 60), 3)) * 0.02 + rng.uniform(-1.5, 1.5, 3)
                              for _ in range(80)])
        rgb = np.full((len(pos), 3), 0.5)
        rgb[3000:] = np.where(rng.random((len(pos) - 3000, 1)) < 0.5, 0.5, rng.uniform(0, 1, (len(pos) - 3000, 3)))
        piece = pieces(pos, s.part_spacing)
        main = int(np.bincount(piece).argmax())
        sizes = np.bincount(piece)
        want = piece == main
        for other in np.flatnonzero((sizes >= 3) & (sizes <= sizes[main])):
            if other != main and is_part(s, pos, rgb, piece == other, piece == main):
                want |= piece == other
        got = with_parts(s, pos, rgb, piece, main)
        assert (got == want).all() and want.sum() > (piece == main).sum()


def test_the_growths_labels_by_conjugate_gradients_match_the_direct_solve():
    """The growth's system (a colour-weighted k-nearest-neighbour graph's Laplacian, its free block, plus the colour
    pull on the diagonal) solved iteratively gives the direct solution's labels."""
    from scipy import sparse
    from scipy.sparse.linalg import spsolve
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    pos = rng.uniform(0, 1, (4000, 3))
    rgb = rng.uniform(0, 1, (4000, 3))
    _, nb = cKDTree(pos).query(pos, k=11)
    i, j = np.repeat(np.arange(4000), 10), nb[:, 1:].reshape(-1)
    w = np.exp(-((rgb[i] - rgb[j]) ** 2).sum(1) / (2 * 0.1 ** 2))
    A = sparse.coo_matrix((w, (i, j)), shape=(4000, 4000)).tocsr()
    A = A.maximum(A.T)
    L = sparse.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    free = pos[:, 0] > 0.2  # the seeds on one side
    system = (L[free][:, free] + sparse.diags(np.full(int(free.sum()), 0.1))).tocsr()
    rhs = -(L[free][:, ~free] @ np.ones(int((~free).sum()))) + 0.1 * rng.uniform(0, 1, int(free.sum()))
    got = solve_labels(system, rhs)
    assert np.abs(got - spsolve(system.tocsc(), rhs)).max() < 1e-6

