"""The click segmenter's clicked region: a fill that leaked onto the surface the clicked object rests on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.pipeline.click import ClickSegmenter
from roodi_toolkit.pipeline.click_regions import (LEAK_MIN_GAUSSIANS, click_sides, cut_by_reach, fill_leaked, level_at,
                                               off_support, support_plane)


def _leaked_region(tilt: float = 0.0):
    """Points of a clicked region that ran from a box (0.4 wide, 0.5 high) onto the ground round it up to a reach of
    1.5: ground points [G, 3], box points [B, 3], all [G + B, 3], and which of all lie where the fill met its
    reach."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1.5, 1.5, size=(6000, 2))
    xy = xy[(np.linalg.norm(xy, axis=1) < 1.5) & (np.abs(xy).max(axis=1) > 0.2)]
    ground = np.column_stack([xy, tilt * xy[:, 0] + rng.normal(0, 0.003, len(xy))])
    top = np.column_stack([rng.uniform(-0.2, 0.2, (800, 2)), np.full(800, 0.5)])
    side = np.column_stack([np.full(600, 0.2), rng.uniform(-0.2, 0.2, 600), rng.uniform(0, 0.5, 600)])
    box = np.concatenate([top, side])
    box[:, 2] += tilt * box[:, 0]
    points = np.concatenate([ground, box])
    at_limit = np.zeros(len(points), bool)
    at_limit[:len(ground)] = np.linalg.norm(ground[:, :2], axis=1) > 1.4
    return ground, box, points, at_limit


@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_the_ground_a_fill_leaked_onto_is_found_and_the_object_is_not_on_it(tilt):
    ground, box, points, at_limit = _leaked_region(tilt)
    plane = support_plane(points, box[:1], at_limit)  # clicked on the box's top
    assert plane is not None
    on = plane[0]
    assert on[:len(ground)].mean() > 0.99
    assert on[len(ground):].mean() < 0.1  # the box's foot only


def test_no_support_without_a_leak_or_with_the_click_on_it():
    ground, box, points, at_limit = _leaked_region()
    assert support_plane(points, box[:1], np.zeros(len(points), bool)) is None  # the fill stopped by itself
    assert support_plane(points, ground[:1], at_limit) is None  # the click is on the ground: it asks for it
    # a region that is the box alone, its top a plane holding most of it, meets no reach: no support
    assert support_plane(box, box[:1], np.zeros(len(box), bool)) is None
    # a leak over no plane (a heap of clutter up to the reach): none either
    clutter = np.random.default_rng(1).uniform(-1.5, 1.5, size=(4000, 3))
    points = np.concatenate([clutter, box])
    assert support_plane(points, box[:1], np.repeat([True, False], [len(clutter), len(box)])) is None


def test_a_level_support_under_the_clicks_is_found_without_a_reach_when_up_is_known():
    """A fill from a click at an object's side runs over the ground in front of it to the ground's own edge, meeting
    no reach: with the scene's up known, the level plane the click stands above is the support."""
    ground, box, points, at_limit = _leaked_region()
    stopped = np.zeros(len(points), bool)
    side_click = box[800:801]  # on the box's side, above the ground
    up = np.array([0.0, 0.0, 1.0])
    assert support_plane(points, side_click, stopped) is None  # no up: only a reach tells a leak
    plane = support_plane(points, side_click, stopped, up)
    assert plane is not None
    on = plane[0]
    assert on[:len(ground)].mean() > 0.99 and on[len(ground):].mean() < 0.1
    assert support_plane(points, side_click, stopped, np.array([1.0, 0.0, 0.0])) is None  # the plane is not level
    assert support_plane(points, ground[:1], stopped, up) is None  # a click on the ground asks for the ground
    below = side_click - np.array([[0.0, 0.0, 1.0]])  # a click under the plane: it hangs from it, not on it
    assert support_plane(np.concatenate([points, below]), below, np.zeros(len(points) + 1, bool), up) is None


def test_a_level_face_of_the_object_itself_is_no_support():
    """A chair clicked on its back: its seat is level and under the click, but holds less than half of a region
    that stopped at the chair's edges; a box clicked on its side has its level top above the click."""
    rng = np.random.default_rng(2)
    seat = np.column_stack([rng.uniform(-0.25, 0.25, (650, 2)), np.full(650, 0.5)])
    back = np.column_stack([rng.uniform(-0.25, 0.25, 550), np.full(550, 0.25), rng.uniform(0.55, 1.0, 550)])
    legs = np.column_stack([np.repeat([[-0.2, -0.2], [0.2, 0.2]], 150, axis=0), rng.uniform(0, 0.45, 300)])
    chair = np.concatenate([seat, back, legs])
    up = np.array([0.0, 0.0, 1.0])
    assert support_plane(chair, back[:1], np.zeros(len(chair), bool), up) is None
    _, box, _, _ = _leaked_region()
    assert support_plane(box, box[800:801], np.zeros(len(box), bool), up) is None


def test_a_level_support_under_a_tall_object_is_found_though_it_holds_less_of_the_region():
    """A person on the ground clicked on a leg: the fill runs up the legs and over some ground round the feet, so the
    ground holds less than half of the region; nothing of the region lies under it, so it is the support still
    (a chair's seat under a click on its back has the chair's legs under it: not the support, above)."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.4, 0.4, size=(1500, 2))
    ground = np.column_stack([xy, rng.normal(0, 0.002, len(xy))])
    legs = np.column_stack([rng.uniform(-0.15, 0.15, 3500), rng.uniform(-0.05, 0.05, 3500), rng.uniform(0, 0.9, 3500)])
    points = np.concatenate([ground, legs])
    up = np.array([0.0, 0.0, 1.0])
    plane = support_plane(points, legs[legs[:, 2] > 0.3][:1], np.zeros(len(points), bool), up)
    assert plane is not None
    on = plane[0]
    assert on[:len(ground)].mean() > 0.99 and on[len(ground):].mean() < 0.05
    hanging = np.concatenate([points, legs - np.array([0.0, 0.0, 0.95])])  # as much again under the plane
    assert support_plane(hanging, legs[legs[:, 2] > 0.3][:1], np.zeros(len(hanging), bool), up) is None


def test_a_region_cut_by_the_reach_is_told_from_one_that_ends_at_an_edge():
    """The fill reached the reach across a smooth surface (the same depth on both sides): cut; where the depth jumps
    there (an occluding edge), or only a few pixels touch it, not cut."""
    depth = np.full((40, 40), 2.0)
    region = np.zeros((40, 40), bool)
    region[5:35, 5:20] = True
    beyond = np.zeros((40, 40), bool)
    beyond[5:35, 20:30] = True  # right of the region, past the reach
    assert cut_by_reach(depth, region, beyond, 0.03)
    stepped = depth.copy()
    stepped[:, 20:] = 3.0
    assert not cut_by_reach(stepped, region, beyond, 0.03)
    corner = np.zeros((40, 40), bool)
    corner[5, 20] = True
    assert not cut_by_reach(depth, region, corner, 0.03)
    assert not cut_by_reach(depth, np.zeros((40, 40), bool), beyond, 0.03)


def test_a_click_on_the_ground_is_level_and_one_on_a_wall_is_not():
    """The reach is not doubled from a click on a level surface (the ground, a table top): the surface round the
    clicked pixel, seen by a camera 45 degrees above it, is level; a wall facing the camera is not; without the
    scene's up nothing is."""
    size = 64
    cam = Camera(look_at([0.0, -2.0, 2.0], [0.0, 0.0, 0.0]), intrinsics_from_fov(math.radians(60), size, size),
                 size, size, 0.01, 100.0, "v0")
    rows, cols = np.mgrid[0:size, 0:size]
    rays = cam.backproject(np.column_stack([rows.ravel(), cols.ravel()]), np.ones(size * size))  # at depth 1
    centre = np.asarray(cam.backproject(np.array([[0, 0]]), np.zeros(1)))[0]  # the camera centre (depth 0)
    # the depth at which each pixel's ray meets the ground z = 0: camera z + t (ray z - camera z) = 0 at depth t
    ground = (centre[2] / (centre[2] - rays[:, 2])).reshape(size, size)
    up = np.array([0.0, 0.0, 1.0])
    valid = np.ones((size, size), bool)
    assert level_at(cam, ground, valid, (size // 2, size // 2), up)
    wall = np.full((size, size), 2.0)  # a fronto-parallel surface: its normal is the viewing direction
    assert not level_at(cam, wall, valid, (size // 2, size // 2), up)
    assert not level_at(cam, ground, valid, (size // 2, size // 2), None)


def test_the_clicked_region_loses_the_ground_it_leaked_onto():
    """A camera looking down on a flat-topped object standing on the ground: a region that ran over the ground up to
    the fill's reach keeps the object's top alone; one that did not reach it is left as it was."""
    size = 96
    cam = Camera(look_at([0.0, -0.01, 3.0], [0.0, 0.0, 0.0]), intrinsics_from_fov(math.radians(60), size, size),
                 size, size, 0.01, 100.0, "v0")
    rows, cols = np.mgrid[0:size, 0:size]
    r = np.hypot(rows - size / 2, cols - size / 2)
    top = r < 12  # the object's top, 0.5 above the ground
    depth = np.where(top, 2.5, 3.0)
    region = r < 40  # the fill ran on over the ground to its reach
    beyond = r >= 40
    seeds = [(size // 2, size // 2)]
    kept, flat = off_support(cam, depth, region, beyond, seeds, surface=depth > 0)
    assert np.array_equal(kept, top)
    assert np.array_equal(flat, ~top)  # the ground's plane over the whole image
    kept, flat = off_support(cam, depth, top, beyond, seeds)
    assert np.array_equal(kept, top) and not flat.any()  # no leak: unchanged


def test_the_click_sides_meet_at_a_crease():
    """Two faces meeting in a ridge (a box's edge, two look-alikes' sides), one depth fill over both: the pixels go
    to the click on each face up to the ridge, though the negative click is much nearer it than the click; on one
    flat face the negative click takes pixels short of that column. (OpenCV's watershed leaves the image's border
    pixels to neither.)"""
    h, w = 24, 60
    cols = np.broadcast_to(np.arange(w, dtype=float), (h, w))
    ridge = np.where(cols < 30, 3.0 - 0.01 * cols, 2.7 + 0.01 * (cols - 30))  # the faces turn at column 30
    area = np.ones((h, w), bool)
    mine, theirs = click_sides(ridge, area, [(12, 3)], [(12, 34)])
    assert mine[1:-1, 1:30].all() and theirs[1:-1, 31:-1].all()
    assert not (mine & theirs).any()
    mine, theirs = click_sides(3.0 - 0.01 * cols, area, [(12, 3)], [(12, 34)])
    assert theirs[1:-1, 27:30].all() and mine[1:-1, 1:20].all()


def _staircase(steps: float = 0.012) -> np.ndarray:
    """The depth [60, 60] of a trained splat's surface seen at an angle, as the click's fill sees it: each pixel the
    depth of its largest-weight Gaussian, constant over 5x5-pixel footprints, ``steps`` (relative) deeper row of
    footprints after row; a wall 20% behind it on the right."""
    depth = np.repeat(np.repeat(2.0 * (1.0 + steps) ** np.arange(12), 5)[:, None], 60, axis=1)
    depth[:, 40:] = 3.0
    return depth


def test_a_fill_from_one_gaussians_footprint_has_not_leaked_when_it_reaches_the_surface():
    """The clicked Gaussian's footprint is a plateau of one depth at small tolerances; the step onto the footprints
    round it (the whole surface) is no leak. The same jump from a region of several Gaussians is one."""
    depth = _staircase()
    plateau = np.zeros(depth.shape, bool)
    plateau[20:25, 10:15] = True
    surface = np.zeros(depth.shape, bool)
    surface[:, :40] = True
    assert not fill_leaked(plateau, surface, depth, 20, 2.0)
    several = np.zeros(depth.shape, bool)
    several[15:30, 10:15] = True  # three rows of footprints: three depths
    assert not fill_leaked(several, surface, depth, 20, 2.0)  # under LEAK_MIN_GAUSSIANS: a plateau still
    several[10:30, 10:15] = True
    assert LEAK_MIN_GAUSSIANS == 4 and fill_leaked(several, surface, depth, 20, 2.0)
    assert not fill_leaked(several, several | plateau, depth, 20, 2.0)  # grew by less than the ratio


def test_a_click_on_one_gaussians_footprint_fills_the_surface_and_stops_at_the_wall():
    """The click's fill from one footprint of the staircase: the whole surface (its steps, 1.2%, within the largest
    tolerance), not the wall behind it; it stopped at the footprint when the step onto the surface was a leak."""
    depth = _staircase()
    fill, _ = ClickSegmenter()._competing_fill(depth, np.ones(depth.shape, bool), np.ones(depth.shape, bool),
                                               [(22, 12)], [])
    surface = np.zeros(depth.shape, bool)
    surface[:, :40] = True
    assert (fill == surface).all()


def test_a_fill_from_a_strip_under_a_thousandth_of_the_image_has_not_leaked():
    """A click at a steep edge fills a strip along it (the man's back: 79 pixels at 400 x 400), then the surface
    behind: under LEAK_MIN_SHARE of the image, no leak; above it, the same jump is one."""
    depth = np.repeat(np.linspace(2.0, 2.4, 400)[:, None], 400, axis=1)  # a distinct depth in every row
    strip = np.zeros(depth.shape, bool)
    strip[100:108, 200:210] = True  # 80 pixels, 8 depths
    surface = np.zeros(depth.shape, bool)
    surface[50:250, 100:300] = True
    assert not fill_leaked(strip, surface, depth, 20, 2.0)
    strip[100:120, 200:210] = True  # 200 pixels: over 0.1% of 160,000
    assert fill_leaked(strip, surface, depth, 20, 2.0)
