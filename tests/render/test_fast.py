"""The default compiled renderer against the dense reference and the torch tiled path: values, gradients, threads."""

from __future__ import annotations

import ctypes.util
import math
import os

import numba
import numpy as np
import pytest
import torch

from roodi_toolkit.cameras import intrinsics_from_fov, look_at
from roodi_toolkit.render.fast import rasterize_fast
from roodi_toolkit.render.rasterizer import rasterize, rasterize_dense_reference

from .test_rasterizer import F64, call, grads, random_scene


@pytest.mark.parametrize("sh_k, tile_size", [(16, 16), (9, 4), (4, 1), (1, 7), (0, 16)])
def test_matches_dense_reference_values_and_gradients(sh_k, tile_size):
    scene = random_scene(sh_k=sh_k)
    fast, g_fast = grads(rasterize_fast, scene, tile_size=tile_size)
    dense, g_dense = grads(rasterize_dense_reference, scene)
    assert 0.05 < fast.alpha.mean() < 0.95
    for name in ("rgb", "alpha", "depth", "features"):
        torch.testing.assert_close(getattr(fast, name), getattr(dense, name), atol=1e-5, rtol=0)
    for name, g in g_dense.items():
        scale = max(1.0, g.abs().max().item())
        torch.testing.assert_close(g_fast[name], g, atol=1e-5 * scale, rtol=0, msg=f"gradient of {name}")
    torch.testing.assert_close(fast.means2d_grad(), dense.means2d_grad(), atol=1e-5, rtol=0)
    torch.testing.assert_close(fast.depths, dense.depths)


def test_matches_the_torch_tiled_path_in_float32_with_its_footprints():
    scene = random_scene(n=600, seed=2, width=160, height=120, dtype=torch.float32)
    a, ga = grads(rasterize_fast, scene)
    b, gb = grads(rasterize, scene)
    for name in ("rgb", "alpha", "features"):
        # both composite in float32, the kernels with a polynomial exp: a few pixels where an alpha or transmittance
        # sits on a cut-off (1/255, 1e-4) are decided the other way
        diff = (getattr(a, name) - getattr(b, name)).abs()
        assert diff.max() < 1e-3 and (diff > 2e-5).float().mean() < 1e-3, name
    assert torch.equal(a.visible, b.visible) and torch.equal(a.radii, b.radii)
    for name in gb:
        scale = gb[name].abs().max().item()
        torch.testing.assert_close(ga[name], gb[name], atol=1e-4 * scale, rtol=0, msg=f"gradient of {name}")


def test_undrawn_gaussians_and_coefficients_past_the_degree_get_exact_zeros():
    """The backward writes its gradient arrays itself (they are not zeroed first): every row of a Gaussian the view
    does not draw, and every SH coefficient past ``sh_degree``, must still be exactly 0 (renders run twice, so that
    the second's arrays reuse memory the first's gradients filled)."""
    scene = random_scene(n=300, seed=4, sh_k=16, dtype=torch.float32)
    full = dict(scene, colors=scene["colors"][:, :4].clone())
    for _ in range(2):
        out, g = grads(rasterize_fast, scene, sh_degree=1)
    _, g_full = grads(rasterize_fast, full)
    assert torch.equal(g["colors"][:, 4:], torch.zeros_like(g["colors"][:, 4:]))
    torch.testing.assert_close(g["colors"][:, :4], g_full["colors"], atol=0, rtol=0)
    hidden = ~out.visible
    assert 10 < int(hidden.sum()) < 290
    for name in ("means", "quats_wxyz", "log_scales", "opacity_logits", "colors", "features"):
        assert torch.equal(g[name][hidden], torch.zeros_like(g[name][hidden])), name
        assert g[name][~hidden].abs().sum() > 0, name


def test_gradcheck_full_pipeline():
    g = torch.Generator().manual_seed(11)
    n = 6
    means = torch.randn(n, 3, generator=g, dtype=F64) * 0.3
    quats = torch.randn(n, 4, generator=g, dtype=F64)
    log_scales = torch.log(torch.rand(n, 3, generator=g, dtype=F64) * 0.1 + 0.08)
    opacity_logits = torch.randn(n, generator=g, dtype=F64) * 0.5
    sh = torch.randn(n, 9, 3, generator=g, dtype=F64) * 0.3
    features = torch.randn(n, 2, generator=g, dtype=F64)
    w2c = torch.tensor(look_at([0.2, -2.5, 0.4], [0, 0, 0]), dtype=F64)
    K = torch.tensor(intrinsics_from_fov(math.radians(50), 14, 11), dtype=F64)

    def fn(m, q, s, o, c, f, bg):
        out = rasterize_fast(m, q, s, o, c, w2c, K, 14, 11, features=f, background=bg, tile_size=4)
        return torch.cat([out.rgb.reshape(-1), out.alpha.reshape(-1), out.depth.reshape(-1),
                          out.features.reshape(-1)])

    bg = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    inputs = [t.requires_grad_() for t in (means, quats, log_scales, opacity_logits, sh, features, bg)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_only_colours_or_features_trained():
    """With the geometry frozen (distillation, colour fitting) only the requested gradients are computed, and they
    equal the full backward's."""
    scene = random_scene(n=200, seed=5)
    _, full = grads(rasterize_fast, scene)
    for leaf in ("colors", "features"):
        s = {k: (v.clone().requires_grad_() if k == leaf else v) for k, v in scene.items()}
        out = call(rasterize_fast, s)
        (out.rgb * 0.5 + 0 * out.alpha).sum().backward() if leaf == "colors" else out.features.sum().backward()
        assert s[leaf].grad is not None and s[leaf].grad.abs().sum() > 0
        assert out.grad_source is None
    s = {k: (v.clone().requires_grad_() if k == "features" else v) for k, v in scene.items()}
    out = call(rasterize_fast, s)
    out.features.sum().backward()
    s2 = {k: (v.clone().requires_grad_() if k in ("features", "means") else v) for k, v in scene.items()}
    out2 = call(rasterize_fast, s2)
    out2.features.sum().backward()
    torch.testing.assert_close(s["features"].grad, s2["features"].grad, atol=1e-12, rtol=0)
    assert full["features"].shape == s["features"].grad.shape


def test_same_result_bit_for_bit_whatever_the_threads(monkeypatch):
    scene = random_scene(n=800, seed=3, width=96, height=64, dtype=torch.float32)
    runs = []
    for threads in ("1", "1", str(min(3, numba.config.NUMBA_NUM_THREADS))):
        monkeypatch.setenv("ROODI_THREADS", threads)
        runs.append(grads(rasterize_fast, scene))
    (a, ga), *others = runs
    for b, gb in others:  # each pixel is composited by one worker; pair gradients are added in pair order
        assert torch.equal(a.rgb, b.rgb) and torch.equal(a.alpha, b.alpha)
        assert all(torch.equal(ga[k], gb[k]) for k in ga)


@pytest.mark.skipif("NUMBA_THREADING_LAYER" in os.environ or "NUMBA_THREADING_LAYER_PRIORITY" in os.environ,
                    reason="the user chose numba's threading layer")
@pytest.mark.skipif(ctypes.util.find_library("gomp") is None, reason="no GNU OpenMP runtime (libgomp1) here")
def test_the_kernels_run_on_openmp_and_their_forks_are_known_unsafe():
    """numba's OpenMP layer where libgomp is installed (the set-up installs it); once it has run, a forked process
    could not run the kernels, and :func:`cores.fork_safe` says so (the batch pool's choice)."""
    from roodi_toolkit.render import cores

    cores.set_workers()
    assert cores.layer() == "omp"
    assert not cores.fork_safe()


def test_degenerate_inputs_give_finite_gradients_and_empty_views_the_background():
    scene = random_scene(n=40, seed=3, dtype=torch.float32)
    scene["opacity_logits"][:5] = -1e4
    scene["log_scales"][5:8] = -30.0
    scene["quats_wxyz"][8] = 0.0
    out, g = grads(rasterize_fast, scene)
    for name, grad in g.items():
        assert torch.isfinite(grad).all(), name
    assert (g["opacity_logits"][:5] == 0).all()
    z = torch.zeros(0, 3, dtype=F64)
    empty = rasterize_fast(z, torch.zeros(0, 4, dtype=F64), z, torch.zeros(0, dtype=F64), z,
                           torch.eye(4, dtype=F64), torch.tensor(intrinsics_from_fov(1.0, 8, 6), dtype=F64), 8, 6,
                           background=torch.tensor([1.0, 0.0, 0.0], dtype=F64))
    assert empty.rgb.shape == (6, 8, 3) and (empty.rgb[..., 0] == 1).all() and (empty.alpha == 0).all()


def test_features_alone_equal_the_full_rendering_and_its_gradients():
    from roodi_toolkit.render.fast import rasterize_features

    scene = random_scene(n=300, seed=6, n_features=5)
    full = call(rasterize_fast, {**scene, "background": None})
    leaves = {k: scene[k].clone().requires_grad_() for k in ("means", "quats_wxyz", "log_scales", "opacity_logits",
                                                            "features")}
    feats, alpha = rasterize_features(leaves["means"], leaves["quats_wxyz"], leaves["log_scales"],
                                      leaves["opacity_logits"], leaves["features"], scene["world_to_camera"],
                                      scene["K"], scene["width"], scene["height"], near=scene["near"])
    torch.testing.assert_close(feats, full.features, atol=1e-12, rtol=0)
    torch.testing.assert_close(alpha, full.alpha, atol=1e-12, rtol=0)
    # the same loss on the features and alpha alone: the same gradients as through the full rendering
    g = torch.Generator().manual_seed(1)
    wf, wa = torch.randn(feats.shape, generator=g, dtype=F64), torch.randn(alpha.shape, generator=g, dtype=F64)
    (feats * wf + alpha * wa).sum().backward()
    s = {k: (v.clone().requires_grad_() if k in leaves else v) for k, v in scene.items()}
    out = call(rasterize_fast, {**s, "background": None})
    (out.features * wf + out.alpha * wa).sum().backward()
    for k in leaves:
        torch.testing.assert_close(leaves[k].grad, s[k].grad, atol=1e-10, rtol=1e-10, msg=k)


def test_same_image_bit_for_bit_whatever_the_tile_size():
    """A pixel's arithmetic uses only its own coordinates and each Gaussian counts only inside its footprint box, so
    tiles of any size (4x4 blocks cut at a tile's and the image's edges) give the same image and walk decisions."""
    scene = random_scene(n=400, seed=8, width=45, height=31, dtype=torch.float32)
    ref = call(rasterize_fast, scene, tile_size=16)
    for tile_size in (1, 3, 4, 7, 13, 20, 32, 64):  # 20, 32: tiles of 25 and 64 blocks
        out = call(rasterize_fast, scene, tile_size=tile_size)
        for name in ("rgb", "alpha", "depth", "features"):
            assert torch.equal(getattr(out, name), getattr(ref, name)), (tile_size, name)


def test_many_channels_match_the_dense_reference():
    """13 features alone (four groups of four channels, the last padded) against the dense reference: values and
    gradients."""
    from roodi_toolkit.render.fast import rasterize_features

    scene = random_scene(n=120, seed=9, n_features=13)
    leaves = {k: scene[k].clone().requires_grad_() for k in ("means", "opacity_logits", "features")}
    feats, alpha = rasterize_features(leaves["means"], scene["quats_wxyz"], scene["log_scales"],
                                      leaves["opacity_logits"], leaves["features"], scene["world_to_camera"],
                                      scene["K"], scene["width"], scene["height"], near=scene["near"], tile_size=8)
    g = torch.Generator().manual_seed(2)
    wf, wa = torch.randn(feats.shape, generator=g, dtype=F64), torch.randn(alpha.shape, generator=g, dtype=F64)
    (feats * wf + alpha * wa).sum().backward()
    s = {k: (v.clone().requires_grad_() if k in leaves else v) for k, v in scene.items()}
    dense = call(rasterize_dense_reference, s)
    (dense.features * wf + dense.alpha * wa).sum().backward()
    torch.testing.assert_close(feats, dense.features, atol=1e-5, rtol=0)
    torch.testing.assert_close(alpha, dense.alpha, atol=1e-5, rtol=0)
    for k in leaves:
        scale = max(1.0, s[k].grad.abs().max().item())
        torch.testing.assert_close(leaves[k].grad, s[k].grad, atol=1e-5 * scale, rtol=0, msg=k)


@pytest.mark.parametrize("case", ["wide", "narrow", "equal", "float64", "one", "none"])
def test_depth_order_is_a_stable_argsort_of_the_drawn_depths(case):
    """The radix sort over the keys' span: keys spanning every bit (negative, tiny and huge depths), a narrow span
    (one pass), all equal (no bit differs), float64 depths (sorted as their float32 values), one or no drawn one."""
    from roodi_toolkit.render import tiles

    rng = np.random.default_rng(9)
    n = 5000
    depths = {"wide": rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n),
              "narrow": 3.0 + rng.integers(0, 40, n) * 2.0 ** -20,
              "equal": np.full(n, 2.5), "float64": rng.random(n) * 7.0 + 0.3, "one": rng.random(n),
              "none": rng.random(n)}[case]
    depths = depths.astype(np.float64 if case == "float64" else np.float32)
    ntiles = (rng.random(n) < 0.7).astype(np.int64)
    if case in ("one", "none"):
        ntiles[:] = 0
        ntiles[n // 2] = 1 if case == "one" else 0
    drawn = np.flatnonzero(ntiles)
    want = drawn[np.argsort(depths[drawn].astype(np.float32), kind="stable")]
    for workers in (1, 2, 5):
        assert np.array_equal(tiles.depth_order(ntiles, depths, workers), want), workers


@pytest.mark.parametrize("n", [1000, 300_000])
def test_pair_sums_are_added_in_pair_order_whatever_the_workers(n):
    """Each Gaussian's sum of its pairs' values, added in pair order (np.add.at's order), bit for bit, for any
    number of workers; 300k Gaussians of six values (7.2 MB of sums) take the prefetching loop."""
    from roodi_toolkit.render import kernels

    rng = np.random.default_rng(12)
    m = 2 * n
    lists = rng.integers(0, n, m).astype(np.int32)
    values = rng.standard_normal((m, 6)).astype(np.float32)
    assert n * 6 * 4 > kernels.REDUCE_PREFETCH_BYTES or n < 300_000
    want = np.zeros((n, 6), np.float32)
    np.add.at(want, lists, values)
    for workers in (1, 2, 3):
        got = np.full((n, 6), np.nan, np.float32)  # every row written, zeros included
        kernels.reduce_pairs(lists, values, got, workers)
        assert np.array_equal(got, want), workers


def test_tile_binning_keeps_depth_order_whatever_the_workers():
    """Every tile's run is the drawn Gaussians touching it, in depth order (ties in id order), for any number of
    workers: checked against a plain loop over the tiles."""
    import numpy as np

    from roodi_toolkit.render import tiles

    rng = np.random.default_rng(4)
    n, width, height, tile = 300, 53, 37, 8
    x0, y0 = rng.integers(0, width, n), rng.integers(0, height, n)
    bounds = np.stack([x0, np.minimum(x0 + rng.integers(0, 20, n), width - 1), y0,
                       np.minimum(y0 + rng.integers(0, 20, n), height - 1)], axis=1).astype(np.int32)  # [N, 4]
    ntiles = (rng.random(n) < 0.8).astype(np.int64)
    depths = rng.integers(0, 50, n).astype(np.float32)  # ties on purpose
    want = np.flatnonzero(ntiles)[np.argsort(depths[ntiles > 0], kind="stable")]
    for workers in (1, 2, 3, 7):
        assert np.array_equal(tiles.depth_order(ntiles, depths, workers), want), workers
    order = want
    tiles_x = -(-width // tile)
    for workers in (1, 2, 3):
        lists, starts, counts = tiles.bin_tiles(order, bounds, width, height, tile, workers)
        for t in range(tiles_x * -(-height // tile)):
            tx, ty = t % tiles_x, t // tiles_x
            want = [g for g in order if bounds[g, 0] // tile <= tx <= bounds[g, 1] // tile
                    and bounds[g, 2] // tile <= ty <= bounds[g, 3] // tile]
            assert lists[starts[t]:starts[t] + counts[t]].tolist() == want, (workers, t)


def _tree(v: np.ndarray, op) -> float:
    """The kernels' fixed tree over 16 lanes: lane q with q + 8, then the first four with the last four, and so on."""
    while len(v) > 1:
        v = op(v[: len(v) // 2], v[len(v) // 2:])
    return v[0]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lane_updates_equal_the_scalar_code_bit_for_bit(dtype):
    """A channel's updates (LLVM vector intrinsics) give exactly the values of the scalar code they replace, in
    float32 and float64."""
    import numba as nb

    from roodi_toolkit.render.vectors import _lanes_axpy, _lanes_scale

    @nb.njit
    def run(x, y, a):
        z = y.copy()
        _lanes_axpy(z, x, a)
        u = y.copy()
        _lanes_scale(u, x, a)
        return z, u

    rng = np.random.default_rng(3)
    for _ in range(20):
        x = (rng.standard_normal(16) * 10.0 ** rng.uniform(-3, 3, 16)).astype(dtype)
        y = rng.standard_normal(16).astype(dtype)
        a = dtype(rng.standard_normal())
        z, u = run(x, y, a)
        assert np.array_equal(z, y + x * a) and np.array_equal(u, x * a)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_many_lane_sums_at_once_equal_the_scalar_tree_bit_for_bit(dtype):
    """The sums and dot products of several rows at once (the backward's six geometry gradients and its channels,
    rows side by side in each vector) give each row's scalar tree exactly (lane q with q + 8, then four with four, two
    with two, one with one), for 6 rows and for 1, 2, 4 and 8 channel groups (4 to 32 rows: an odd row out at each
    step is paired with itself)."""
    import numba as nb

    from roodi_toolkit.render.lanes import _stack_empty
    from roodi_toolkit.render.vectors import _lane_dots, _lane_sums_into

    def compile_for(groups):
        @nb.njit
        def run(x, rows):
            out = nb.carray(_stack_empty(groups, rows.dtype), (len(groups) * 64,))
            six = nb.carray(_stack_empty(96, rows.dtype), (6, 16))
            six[:, :] = rows[:6]
            chans = nb.carray(_stack_empty(groups, rows.dtype), (4 * len(groups), 16))
            chans[:, :] = rows[:4 * len(groups)]
            first = np.zeros((1, 6), rows.dtype)  # 0 + each sum: the sum itself
            _lane_sums_into(six, 6, first, 0)
            _lane_dots(x, chans, groups, out)
            return first[0], out[:4 * len(groups)].copy()

        return run

    rng = np.random.default_rng(4)
    for groups in [(0,), (0, 0), (0,) * 4, (0,) * 8]:
        run = compile_for(groups)
        for _ in range(5):
            rows = (rng.standard_normal((32, 16)) * 10.0 ** rng.uniform(-3, 3, (32, 16))).astype(dtype)
            x = rng.standard_normal(16).astype(dtype)
            six, dots = run(x, rows)
            assert [float(v) for v in six] == [float(_tree(r, np.add)) for r in rows[:6]]
            assert [float(v) for v in dots] == [float(_tree(x * r, np.add)) for r in rows[:len(dots)]]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lane_sums_added_into_a_row_touch_only_that_row_and_equal_the_scalar_tree(dtype):
    """The backward adds its pairs' sums straight into their rows (no store and reload): each element gets its row's
    scalar tree added by one addition, bit for bit, for the six geometry gradients and 1, 2 and 4 channel groups
    (4 to 16 columns, added four, two, one at a time); the other rows and the columns past ``count`` are untouched."""
    import numba as nb

    from roodi_toolkit.render.lanes import _stack_empty
    from roodi_toolkit.render.vectors import _lane_dots_into, _lane_sums_into

    def compile_for(groups):
        @nb.njit
        def run(x, rows, geom, chan, at):
            six = nb.carray(_stack_empty(96, rows.dtype), (6, 16))
            six[:, :] = rows[:6]
            chans = nb.carray(_stack_empty(groups, rows.dtype), (4 * len(groups), 16))
            chans[:, :] = rows[:4 * len(groups)]
            _lane_sums_into(six, 6, geom, at)
            _lane_dots_into(x, chans, groups, chan, at)

        return run

    rng = np.random.default_rng(5)
    for groups in [(0,), (0, 0), (0,) * 4]:
        run = compile_for(groups)
        k = 4 * len(groups)
        for at in (0, 2, 4):
            rows = (rng.standard_normal((16, 16)) * 10.0 ** rng.uniform(-3, 3, (16, 16))).astype(dtype)
            x = rng.standard_normal(16).astype(dtype)
            geom = rng.standard_normal((5, 7)).astype(dtype)  # a column past the six: untouched
            chan = rng.standard_normal((5, k)).astype(dtype)
            geom0, chan0 = geom.copy(), chan.copy()
            run(x, rows, geom, chan, at)
            want_geom = geom0.copy()
            want_geom[at, :6] = [g + _tree(r, np.add) for g, r in zip(geom0[at, :6], rows[:6])]
            want_chan = chan0.copy()
            want_chan[at] = [c + _tree(x * r, np.add) for c, r in zip(chan0[at], rows[:k])]
            assert np.array_equal(geom, want_geom) and np.array_equal(chan, want_chan)


@pytest.mark.parametrize("tile", [4, 10, 16, 64])
def test_forward_marks_exactly_the_blocks_each_pair_blended_in(tile):
    """The forward's marks (what the backward walks) are the tile's 4x4 blocks where each (tile, Gaussian) pair
    blended at least one pixel: checked against every blend the view lists (``compositing_pairs``), tiles of 1 to 256
    blocks (64 pixels: four 64-bit words a pair). A render without gradients keeps none."""
    from roodi_toolkit.render import fast

    s = random_scene(n=400, seed=5, sh_k=0, n_features=0, width=97, height=71)
    arrays = [s[k].numpy() for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "colors")]
    view = fast.make_view(s["world_to_camera"], s["K"], s["width"], s["height"], near=s["near"], tile=tile)
    proj = fast.project(*arrays, 0, view)
    bins = fast.bin_gaussians(proj, view)
    *_, marks = fast.composite(bins, proj, fast.channels_of(proj, None), view, want_marks=True)
    pixels, ids, _ = fast.compositing_pairs(bins, proj, view)
    tiles_x, nbx = -(-view.width // tile), -(-tile // 4)
    py, px = pixels // view.width, pixels % view.width
    blended = set(zip(((py // tile) * tiles_x + px // tile).tolist(), ids.tolist(),
                      (((py % tile) // 4) * nbx + (px % tile) // 4).tolist()))
    marked = set()
    for t in np.flatnonzero(bins.counts):
        for j in range(bins.starts[t], bins.starts[t] + bins.counts[t]):
            for w, word in enumerate(marks[j].tolist()):
                marked |= {(int(t), int(bins.lists[j]), 64 * w + b) for b in range(64) if word >> b & 1}
    assert marks.shape == (len(bins.lists), -(-nbx * nbx // 64)) and len(blended) > 100
    assert marked == blended
    assert fast.composite(bins, proj, fast.channels_of(proj, None), view)[4] is None
    with torch.no_grad():
        assert not fast._differentiable(*(s[k].requires_grad_() for k in ("means", "colors")))
    assert fast._differentiable(s["means"])


def test_backward_refuses_marks_that_are_not_the_forwards():
    """The backward walks the forward's marks: an array of another shape is refused with an error, never read past
    its end."""
    from roodi_toolkit.render import fast, kernels

    s = random_scene(n=60, seed=2, sh_k=0, n_features=0)
    arrays = [s[k].numpy() for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "colors")]
    view = fast.make_view(s["world_to_camera"], s["K"], s["width"], s["height"], near=s["near"])
    proj = fast.project(*arrays, 0, view)
    bins = fast.bin_gaussians(proj, view)
    channels = fast.channels_of(proj, None)
    _, t_final, last, _, marks = fast.composite(bins, proj, channels, view, want_marks=True)
    m, (H, W) = len(bins.lists), t_final.shape
    head = (bins.lists, bins.starts, bins.counts, bins.busy, fast.records(proj, channels), channels,
            kernels.channel_groups(4), W, H, view.tile, 1, t_final, last)
    tail = (np.ones((H, W, 4), channels.dtype), np.zeros((H, W), channels.dtype), np.zeros(4),
            np.zeros((m, 6), channels.dtype), np.zeros((m, 4), channels.dtype), True)
    kernels.composite_backward(*head, marks, *tail)
    with pytest.raises(ValueError, match="marks"):
        kernels.composite_backward(*head, np.zeros((0, 1), np.uint64), *tail)
