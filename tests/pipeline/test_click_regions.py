"""The click segmenter's clicked region: a fill that leaked onto the surface the clicked object rests on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.pipeline.click import ClickSegmenter
from roodi_toolkit.pipeline.click_regions import support_leak


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
    on = support_leak(points, box[:1], at_limit)  # clicked on the box's top
    assert on is not None
    assert on[:len(ground)].mean() > 0.99
    assert on[len(ground):].mean() < 0.1  # the box's foot only


def test_no_support_without_a_leak_or_with_the_click_on_it():
    ground, box, points, at_limit = _leaked_region()
    assert support_leak(points, box[:1], np.zeros(len(points), bool)) is None  # the fill stopped by itself
    assert support_leak(points, ground[:1], at_limit) is None  # the click is on the ground: it asks for it
    # a region that is the box alone, its top a plane holding most of it, meets no reach: no support
    assert support_leak(box, box[:1], np.zeros(len(box), bool)) is None
    # a leak over no plane (a heap of clutter up to the reach): none either
    clutter = np.random.default_rng(1).uniform(-1.5, 1.5, size=(4000, 3))
    points = np.concatenate([clutter, box])
    assert support_leak(points, box[:1], np.repeat([True, False], [len(clutter), len(box)])) is None


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
    kept = ClickSegmenter._off_support(cam, depth, region, beyond, seeds)
    assert np.array_equal(kept, top)
    assert np.array_equal(ClickSegmenter._off_support(cam, depth, top, beyond, seeds), top)  # no leak: unchanged
