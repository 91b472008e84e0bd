"""Tests of ``roodi_toolkit.viz.inspect`` and ``roodi-toolkit inspect``: off screen, on planted-floater clouds."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

os.environ["PYVISTA_OFF_SCREEN"] = "true"
pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

from roodi_toolkit.viz import inspect as insp  # noqa: E402
from roodi_toolkit.errors import ConfigError  # noqa: E402
from roodi_toolkit.prune.outliers import remove_statistical_outliers  # noqa: E402
from roodi_toolkit.synth.floaters import FAR, NEAR, FloaterMix, planted_floater_cloud  # noqa: E402

SIZE = (320, 240)
RED = np.array([255, 0, 0])


@pytest.fixture(scope="module")
def planted():
    """A unit sphere of 2000 surface Gaussians, 80 far floaters and 6 near-surface oversized ones."""
    return planted_floater_cloud(FloaterMix("sphere", n_object=2000, far_fraction=0.04, near_fraction=0.003), seed=3)


@pytest.fixture(scope="module")
def pruned(planted):
    return remove_statistical_outliers(planted.cloud)


def colour_mask(img: np.ndarray, colour=RED, tol: int = 24) -> np.ndarray:
    """Return ``[H, W]`` pixels within ``tol`` of ``colour`` in every channel."""
    return np.all(np.abs(img[..., :3].astype(int) - np.asarray(colour)) <= tol, axis=-1)


def visible_centres(plotter, points: np.ndarray, occluder_radius: float = 1.02) -> np.ndarray:
    """Return which points are in front of the camera and not hidden behind the unit sphere (the object)."""
    cam = np.asarray(plotter.camera.position)
    d = points - cam
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    # first intersection of the ray cam + t u with the sphere |x| = r
    b = u @ cam
    disc = b * b - (cam @ cam - occluder_radius ** 2)
    t_hit = -b - np.sqrt(np.maximum(disc, 0))
    hidden = (disc > 0) & (t_hit > 0) & (t_hit < length)
    return ~hidden


def near_any(mask: np.ndarray, pixels: np.ndarray, radius: int) -> np.ndarray:
    """Return for each pixel position (col, row) whether ``mask`` has a True pixel within ``radius``."""
    h, w = mask.shape
    out = np.zeros(len(pixels), dtype=bool)
    for i, (c, r) in enumerate(np.round(pixels).astype(int)):
        r0, r1, c0, c1 = max(r - radius, 0), min(r + radius + 1, h), max(c - radius, 0), min(c + radius + 1, w)
        out[i] = r0 < r1 and c0 < c1 and mask[r0:r1, c0:c1].any()
    return out


# ---------------------------------------------------------------------------------------------- geometry
def test_ellipsoid_mesh_lies_on_the_sigma_surface_with_gradient_normals():
    rng = np.random.default_rng(0)
    means = rng.normal(size=(5, 3))
    q = rng.normal(size=(5, 4))
    from roodi_toolkit.gaussians import quat_to_rotmat

    rot = quat_to_rotmat(q)
    scales = np.exp(rng.normal(-2, 1, size=(5, 3)))
    scales[0, 2] = 1e-4 * scales[0, 0]  # a nearly flat Gaussian
    mesh = insp.ellipsoid_mesh(means, rot, scales, sigmas=2.0)
    g = mesh.point_data["gaussian"]
    assert mesh.n_points == 5 * 42 and mesh.is_all_triangles and mesh.n_cells == 5 * 80
    cov_inv = np.einsum("nij,nj,nkj->nik", rot, 1.0 / scales ** 2, rot)
    x = np.asarray(mesh.points, dtype=np.float64) - means[g]
    mahalanobis2 = np.einsum("pi,pij,pj->p", x, cov_inv[g], x)
    np.testing.assert_allclose(mahalanobis2, 4.0, rtol=2e-3)
    grad = np.einsum("pij,pj->pi", cov_inv[g], x)
    grad /= np.linalg.norm(grad, axis=1, keepdims=True)
    normals = np.asarray(mesh.point_data["Normals"], dtype=np.float64)
    # the flat Gaussian's gradient is ill-conditioned from float32 points: compare the others
    assert np.all(np.einsum("pi,pi->p", grad, normals)[g > 0] > 0.999)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-5)


def test_ellipsoid_mesh_refuses_mismatched_shapes():
    with pytest.raises(ConfigError, match="means"):
        insp.ellipsoid_mesh(np.zeros((3, 3)), np.zeros((2, 3, 3)), np.ones((3, 3)))


def test_footprint_scale_is_geometric_mean_of_two_largest(cloud_factory):
    cloud = cloud_factory(20)
    s = np.sort(cloud.scales, axis=1)
    np.testing.assert_allclose(insp.footprint_scales(cloud), np.sqrt(s[:, 1] * s[:, 2]), rtol=1e-6)


def test_robust_sphere_ignores_a_few_strays():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(5000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    pts[:10] *= 50.0
    centre, radius = insp.robust_sphere(pts)
    assert np.linalg.norm(centre) < 0.05 and 0.98 < radius < 1.05


@pytest.mark.parametrize("camera", insp.CAMERAS)
def test_camera_frames_the_object_from_each_direction(camera):
    plotter = pv.Plotter(off_screen=True, window_size=list(SIZE))
    try:
        insp.frame_camera(plotter, [1.0, 2.0, 3.0], 0.5, camera)
        ring = np.array([1.0, 2.0, 3.0]) + 0.5 * np.vstack([np.eye(3), -np.eye(3)])
        px, front = insp.project_points(plotter, ring)
        assert front.all()
        assert np.all((px >= 0) & (px <= np.array(SIZE))), px
        centre_px, _ = insp.project_points(plotter, np.array([[1.0, 2.0, 3.0]]))
        np.testing.assert_allclose(centre_px[0], np.array(SIZE) / 2, atol=1e-6)
    finally:
        plotter.close()


# ---------------------------------------------------------------------------------------------- screenshots
@pytest.mark.parametrize("glyphs", ["splats", "ellipsoids"])
def test_screenshot_shows_highlight_where_the_removed_floaters_are(planted, pruned, glyphs):
    keep = pruned.keep_mask
    removed = ~keep
    assert removed[planted.labels == FAR].all()  # the fixture's premise: pruning finds the far floaters
    plotter = insp.plot_cloud(planted.cloud, keep, glyphs=glyphs, window_size=SIZE)
    try:
        img = insp.screenshot_image(plotter)
        centres = planted.cloud.means.astype(np.float64)
        px, front = insp.project_points(plotter, centres)
        # kept splats and ellipsoids reach about 3 footprint sigmas past the surface and tint what is behind them
        halo = 3.0 * float(np.quantile(insp.footprint_scales(planted.cloud)[planted.labels == 0], 0.99))
        visible = front & visible_centres(plotter, centres, 1.0 + halo)
        camera_position = plotter.camera.position
    finally:
        plotter.close()
    assert img.shape == (SIZE[1], SIZE[0], 3) and img.dtype == np.uint8
    assert img.reshape(-1, 3).std(axis=0).max() > 20  # not blank
    red = colour_mask(img)
    inside = np.all((px >= 2) & (px < np.array(SIZE) - 2), axis=1)
    # recall: every visible far floater in the frame has highlight pixels at its centre
    far = (planted.labels == FAR) & visible & inside
    assert far.sum() >= 3
    assert near_any(red, px[far], 2).all()
    # precision: highlight-coloured pixels lie on removed Gaussians (their marker or their own footprint, drawn to
    # 3 sigma), not on kept ones
    rows, cols = np.nonzero(red)
    sel = removed & front
    depth = np.linalg.norm(centres[sel] - np.asarray(camera_position), axis=1)
    focal_px = SIZE[1] / (2 * np.tan(np.radians(insp.VIEW_ANGLE_DEG) / 2))
    reach = insp.HIGHLIGHT_MARKER_PIXELS + 3 * planted.cloud.scales[sel].max(axis=1) * focal_px / depth
    gap = np.hypot(cols[:, None] - px[sel][None, :, 0], rows[:, None] - px[sel][None, :, 1]) - reach[None, :]
    assert np.all(gap.min(axis=1) <= 1.0)


def test_nothing_removed_means_no_highlight_colour(planted):
    plotter = insp.plot_cloud(planted.cloud, None, glyphs="splats", window_size=SIZE)
    try:
        img = insp.screenshot_image(plotter)
    finally:
        plotter.close()
    assert img.reshape(-1, 3).std(axis=0).max() > 20
    assert not colour_mask(img).any()


def test_highlight_none_and_show_removed(planted, pruned):
    plotter = insp.plot_cloud(planted.cloud, pruned.keep_mask, highlight=None, glyphs="splats", window_size=SIZE)
    try:
        assert not colour_mask(insp.screenshot_image(plotter)).any()
    finally:
        plotter.close()
    plotter = insp.plot_cloud(planted.cloud, pruned.keep_mask, show="removed", highlight="#00ff00",
                              glyphs="splats", window_size=SIZE)
    try:
        img = insp.screenshot_image(plotter)
        assert colour_mask(img, (0, 255, 0)).sum() > 20
    finally:
        plotter.close()
    with pytest.raises(ConfigError, match="nothing to show"):
        insp.plot_cloud(planted.cloud, np.ones(len(planted.cloud), dtype=bool), show="removed")


def test_glyphs_auto_switches_on_size(planted, monkeypatch):
    from pyvista.plotting.mapper import PointGaussianMapper

    def mappers(**kw):
        plotter = insp.plot_cloud(planted.cloud, None, window_size=SIZE, **kw)
        try:
            return [type(a.mapper) for a in plotter.renderer.actors.values()]
        finally:
            plotter.close()

    assert PointGaussianMapper not in mappers(glyphs="auto")  # 2086 Gaussians <= 20,000: ellipsoids
    assert PointGaussianMapper in mappers(glyphs="splats")
    monkeypatch.setattr(insp, "ELLIPSOID_MAX_GAUSSIANS", 1000)
    assert PointGaussianMapper in mappers(glyphs="auto")
    assert PointGaussianMapper not in mappers(glyphs="ellipsoids")


def test_color_by_distance_needs_distances_and_maps_nan_for_filtered(planted):
    with pytest.raises(ConfigError, match="distances"):
        insp.plot_cloud(planted.cloud, None, color_by="distance")
    result = remove_statistical_outliers(planted.cloud, min_opacity=0.7)
    d = insp.distances_per_gaussian(result.report, len(planted.cloud))
    filtered = planted.cloud.opacities < 0.7
    assert np.isnan(d[filtered]).all() and np.isfinite(d[~filtered]).all()
    np.testing.assert_array_equal(d[result.report.evaluated], result.report.mean_distances)
    plotter = insp.plot_cloud(planted.cloud, result.keep_mask, color_by="distance", distances=d,
                              glyphs="splats", window_size=SIZE)
    try:
        assert plotter.scalar_bars  # the colour bar is there
        assert insp.screenshot_image(plotter).shape == (SIZE[1], SIZE[0], 3)
    finally:
        plotter.close()


def test_bad_options_are_config_errors(planted):
    with pytest.raises(ConfigError, match="show"):
        insp.plot_cloud(planted.cloud, show="all")
    with pytest.raises(ConfigError, match="keep_mask"):
        insp.plot_cloud(planted.cloud, np.ones(3, dtype=bool))
    with pytest.raises(ConfigError, match="highlight"):
        insp.plot_cloud(planted.cloud, highlight="blurple")


# ---------------------------------------------------------------------------------------------- histogram
def test_histogram_figure_marks_the_report_threshold(pruned):
    report = pruned.report
    fig = insp.histogram_figure(report)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log"
    vertical = [line.get_xdata()[0] for line in ax.get_lines() if line.get_label().startswith("threshold")]
    assert vertical == [report.threshold]
    d = report.mean_distances
    assert fig._roodi_removed_share == pytest.approx(np.mean(d > report.threshold))
    assert any(f"{np.mean(d > report.threshold):.2%}" in t.get_text() for t in ax.texts)


# ---------------------------------------------------------------------------------------------- CLI
@pytest.fixture(scope="module")
def planted_ply(planted, tmp_path_factory):
    from roodi_toolkit.io.ply import write_ply

    path = tmp_path_factory.mktemp("inspect") / "planted.ply"
    write_ply(planted.cloud, path)
    return path


def test_cli_histogram_threshold_matches_prune_report(run_cli, planted_ply, tmp_path):
    from PIL import Image

    options = ["--rule", "paper", "--alpha", "2.5", "--k", "8", "--min-opacity", "0.05"]
    res = run_cli("prune", planted_ply, tmp_path / "out.ply", "--report", tmp_path / "r.json", *options)
    assert res.exit_code == 0, res.stderr
    res = run_cli("inspect", planted_ply, "--histogram", tmp_path / "h.png", *options)
    assert res.exit_code == 0, res.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    with Image.open(tmp_path / "h.png") as img:
        assert img.format == "PNG" and img.width > 300
        assert float(img.text["roodi:threshold"]) == report["threshold"]
        statistical = [s["removed"] for s in report["stages"] if s["stage"] == "statistical"][0]
        evaluated = report["input_count"] - sum(s["removed"] for s in report["stages"] if s["stage"] != "statistical")
        assert float(img.text["roodi:removed_share"]) == pytest.approx(statistical / evaluated)
    assert f"above {report['threshold']:.4g}" in res.stdout


def test_cli_screenshot_size_and_highlight(run_cli, planted_ply, tmp_path):
    from roodi_toolkit.io.files import read_image

    res = run_cli("inspect", planted_ply, "--view-png", tmp_path / "s.png", "--window-size", "300x200",
                  "--highlight", "#ff00ff", "--camera", "+z")
    assert res.exit_code == 0, res.stderr
    img = read_image(tmp_path / "s.png")
    assert img.shape[:2] == (200, 300)
    assert colour_mask(img, (255, 0, 255)).sum() >= 10
    # an alpha so large that nothing is removed: no highlight colour at all
    res = run_cli("inspect", planted_ply, "--view-png", tmp_path / "n.png", "--window-size", "300x200",
                  "--highlight", "#ff00ff", "--camera", "+z", "--alpha", "1000")
    assert res.exit_code == 0, res.stderr
    img = read_image(tmp_path / "n.png")
    assert img.reshape(-1, img.shape[-1]).std(axis=0).max() > 20
    assert not colour_mask(img, (255, 0, 255)).any()


def test_cli_errors(run_cli, planted_ply, tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    res = run_cli("inspect", planted_ply)
    assert res.exit_code == 1 and "--screenshot" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = run_cli("inspect", planted_ply, "--window")
    assert res.exit_code == 1 and "no display" in res.stderr
    res = run_cli("inspect", planted_ply, "--screenshot", tmp_path / "x.png", "--highlight", "blurple")
    assert res.exit_code == 2 and "--highlight" in res.stderr
    res = run_cli("inspect", planted_ply, "--screenshot", tmp_path / "x.png", "--window-size", "0x10")
    assert res.exit_code == 2
    res = run_cli("inspect", planted_ply, "--screenshot", planted_ply)
    assert res.exit_code == 1 and "same file" in res.stderr
    res = run_cli("inspect", planted_ply, "--histogram", tmp_path / "h.png", "--filter-box", "1,2")
    assert res.exit_code == 2 and "--filter-box" in res.stderr
    res = run_cli("inspect", tmp_path / "missing.ply", "--histogram", tmp_path / "h.png")
    assert res.exit_code == 1


def test_inspect_and_prune_share_the_pruning_options():
    """``inspect`` prunes exactly as ``prune``: same option names, types, defaults and help (every command-line
    setting of PruneConfig and PhotoSettings); the options' round trip to the config is tests/cli/test_settings.py's."""
    from roodi_toolkit.cli.cmd_inspect import inspect as inspect_cmd
    from roodi_toolkit.cli.cmd_prune import prune
    from roodi_toolkit.cli.settings import option_names
    from roodi_toolkit.prune.config import PhotoSettings, PruneConfig

    shared = (*option_names(PruneConfig), *option_names(PhotoSettings))

    def describe(command):
        return {p.name: (tuple(p.opts), repr(p.type), p.default, p.help, p.is_flag, p.show_default)
                for p in command.params if p.name in shared}

    ours, theirs = describe(inspect_cmd), describe(prune)
    assert set(ours) == set(shared)
    assert ours == theirs


def test_cli_default_shows_what_the_default_prune_removes(run_cli, planted_ply, tmp_path):
    """Without options ``inspect`` runs ``prune``'s default (the local tests), not the statistical rule: the same
    mode, the same counts, and a histogram of the blob scores (linear axis) whose removed share is the prune's."""
    from PIL import Image

    res = run_cli("prune", planted_ply, tmp_path / "out.ply", "--report", tmp_path / "r.json")
    assert res.exit_code == 0, res.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["mode"] in ("scene", "object") and report["removed_count"] > 0
    res = run_cli("inspect", planted_ply, "--histogram", tmp_path / "h.png", "--view-png", tmp_path / "s.png",
                  "--window-size", "300x200", "--camera", "+z")
    assert res.exit_code == 0, res.stderr
    assert res.stdout.startswith(f"{report['mode']} mode (auto): ")
    assert (f"judged {report['input_count']:,} Gaussians: {report['removed_count']:,} would go, "
            f"{report['kept_count']:,} would stay") in res.stdout
    with Image.open(tmp_path / "h.png") as img:
        assert float(img.text["roodi:threshold"]) == report["threshold"] == 0.5
        # no filter ran, so every Gaussian was evaluated
        assert float(img.text["roodi:removed_share"]) == pytest.approx(report["removed_count"] / report["input_count"])
    from roodi_toolkit.io.files import read_image

    assert colour_mask(read_image(tmp_path / "s.png")).sum() >= 10
    # asking for an option of the statistical rule asks for that rule, as in prune
    res = run_cli("inspect", planted_ply, "--histogram", tmp_path / "h2.png", "--rule", "paper")
    assert res.exit_code == 0, res.stderr
    assert res.stdout.startswith("statistical mode: ")


def test_histogram_of_blob_scores_is_linear_and_shades_every_removed(planted):
    from roodi_toolkit.prune.scene import prune_cloud

    result = prune_cloud(planted.cloud)
    report = result.report
    fig = insp.histogram_figure(report, keep=result.keep_mask)
    ax = fig.axes[0]
    assert ax.get_xscale() == "linear" and "blob score" in ax.get_xlabel()
    removed = ~result.keep_mask[report.evaluated]
    assert removed.any() and fig._roodi_removed_share == pytest.approx(removed.mean())
    # without the keep mask, only the oversized limit is known
    fig = insp.histogram_figure(report)
    assert fig._roodi_removed_share == pytest.approx(np.mean(report.mean_distances > report.threshold))
    # the colour bar of --color-by distance is linear for blob scores (negative values are real scores)
    d = insp.distances_per_gaussian(report, len(planted.cloud))
    assert (d < 0).any()
    plotter = insp.plot_cloud(planted.cloud, result.keep_mask, color_by="distance", distances=d,
                              distance_label=insp.distance_label(report), distance_log=insp.distance_is_log(report),
                              off_screen=True, window_size=SIZE, glyphs="splats")
    plotter.close()
