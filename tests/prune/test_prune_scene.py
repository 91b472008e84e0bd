"""The default prune (local scene/object tests): planted floaters in a real splat, synthetic mixes, modes, filters,
and the ``prune`` command's --mode, --dry-run and --filter-value."""

from __future__ import annotations

import json

import numpy as np
import pytest

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.io.ply import read_ply, write_ply
from roodi_toolkit.prune.outliers import PruneConfig, remove_statistical_outliers
from roodi_toolkit.prune.scene import prune_cloud
from roodi_toolkit.synth.floaters import (BLOB, FAR, NEAR, OBJECT, SPECK, FloaterMix, plant_floaters,
                                          planted_floater_cloud, scene_extent)

from ..paths import SHARED_DATA

DATA = SHARED_DATA  # ../shared/data from the project root, or $ROODI_DATA
DONUT = DATA / "donut" / "point_cloud.ply"


@pytest.fixture(scope="module")
def donut():
    if not DONUT.exists():
        pytest.skip(f"real data not found at {DONUT} (see ../shared/data/README.md)")
    return read_ply(DONUT)


@pytest.mark.parametrize("seed", [0, 3])
def test_planted_floaters_in_the_real_donut_are_removed_and_its_content_kept(donut, seed):
    planted, labels = plant_floaters(donut, seed=seed)
    assert (labels == SPECK).sum() == 300 and (labels == BLOB).sum() == 300
    np.testing.assert_array_equal(planted.means[:len(donut)], donut.means)
    _, keep, report = prune_cloud(planted)
    assert report.mode == "object" and "largest connected piece" in report.mode_reason
    assert (~keep[labels == SPECK]).mean() >= 0.95
    assert (~keep[labels == BLOB]).mean() >= 0.95
    # the paper's rule removes 5.1% of this donut; the local tests well under 1% (its own detached specks)
    assert (~keep[labels == OBJECT]).mean() < 0.005


def test_the_real_donuts_inner_pieces_stay_without_photos(donut):
    # five detached pieces of 6-56 Gaussians lie inside the ring (0.4-0.7 of its 90% radius from the centre):
    # real content the link rule splits off; only the lone specks and pairs go without photos
    _, keep, report = prune_cloud(donut)
    _, keep_all, _ = prune_cloud(donut, max_piece=0)
    spared = keep & ~keep_all
    assert spared.sum() >= 100 and "109 Gaussians in 5 detached pieces of more than 3 stay" in report.mode_reason
    assert (~keep).mean() < 0.002


def test_the_real_donuts_oversized_gaussians_of_their_neighbours_colour_stay(donut):
    # 53 real candidates: 43 carry the colour of a neighbour (the optimiser's large patches) and stay without photos
    _, keep, report = prune_cloud(donut)
    _, keep_all, report_all = prune_cloud(donut, blob_colour=0.0)
    assert dict(report_all.stages)["oversized"] - dict(report.stages)["oversized"] == \
        report.statistics["oversized_colour_spared"] >= 30
    assert (keep >= keep_all).all() and "oversized Gaussians stay, each the colour of a neighbour" in report.mode_reason


def test_plant_floaters_follows_the_recipe(donut):
    centre, r90, size = scene_extent(donut)
    planted, labels = plant_floaters(donut, seed=3, n_specks=50, n_blobs=40)
    radius = np.linalg.norm(planted.means[labels == SPECK] - centre, axis=1) / r90
    assert radius.min() >= 1.4 - 1e-4 and radius.max() <= 2.5 + 1e-4
    blob_size = np.exp(planted.log_scales[labels == BLOB].astype(np.float64).mean(axis=1)) / size
    assert 7 < np.median(blob_size) < 22
    assert abs(float(planted.opacity_logits[labels != OBJECT].mean()) - 1.0) < 0.35


@pytest.mark.parametrize("surface", ["sphere", "torus"])
def test_default_prune_on_synthetic_mixes(surface):
    planted = planted_floater_cloud(FloaterMix(surface, n_object=8000, far_fraction=0.01, near_fraction=0.01), 1)
    _, keep, report = prune_cloud(planted.cloud)
    labels = planted.labels
    assert (~keep[labels == OBJECT]).mean() <= 0.01
    assert (~keep[labels == FAR]).mean() >= 0.9
    assert (~keep[labels == NEAR]).mean() >= 0.95
    assert [name for name, _ in report.stages[-3:]] == ["detached", "oversized", "fog"]
    assert dict(report.stages)["fog"] == 0  # no white or black fog in these clouds


def test_object_mode_drops_a_second_piece_only_without_a_size_limit():
    a = planted_floater_cloud(FloaterMix("sphere", n_object=3000, far_fraction=0, near_fraction=0), 0).cloud
    b = planted_floater_cloud(FloaterMix("torus", n_object=600, far_fraction=0, near_fraction=0), 1).cloud
    both = type(a).concatenate([a, b.with_fields(means=b.means + np.float32(5.0))])  # a second, detached object
    _, keep, report = prune_cloud(both)
    assert report.mode == "scene" and keep.mean() > 0.99
    # without photos a detached piece of more than max_piece Gaussians has structure: it stays, and the report says so
    _, keep, report = prune_cloud(both, mode="object")
    assert report.mode == "object" and keep.mean() > 0.99
    assert "600 Gaussians in 1 detached pieces of more than 3 stay" in report.mode_reason
    _, keep, report = prune_cloud(both, mode="object", max_piece=0)
    assert report.mode == "object" and not keep[3000:].any() and keep[:3000].mean() > 0.99


def test_without_photos_lone_specks_go_and_small_clumps_stay():
    a = planted_floater_cloud(FloaterMix("sphere", n_object=3000, far_fraction=0, near_fraction=0), 0).cloud
    far = a.select(np.arange(40))
    clump = far.with_fields(means=far.means * np.float32(0.02) + np.float32(3.0))  # 40 Gaussians in one piece
    lone = a.select(np.arange(3)).with_fields(means=np.array([[4, 0, 0], [0, 4, 0], [0, 0, -4]], np.float32))
    cloud = type(a).concatenate([a, clump, lone])
    _, keep, _ = prune_cloud(cloud, mode="object")
    assert keep[3000:3040].all() and not keep[3040:].any()
    _, keep, _ = prune_cloud(cloud, mode="object", max_piece=40)
    assert not keep[3000:].any()


def test_oversized_blobs_the_colour_of_their_neighbours_stay_below_blob_sure():
    from roodi_toolkit.gaussians import GaussianCloud

    a = planted_floater_cloud(FloaterMix("sphere", n_object=3000, far_fraction=0, near_fraction=0), 0).cloud
    size = float(np.exp(np.median(a.log_scales.astype(np.float64).mean(axis=1))))
    host = np.array([10, 500, 1000, 1500])  # blobs centred on these surface Gaussians

    def blobs(multiple: float, rgb: np.ndarray) -> GaussianCloud:
        return GaussianCloud.from_activated(a.means[host].astype(np.float64), scales=np.full((4, 3), size * multiple),
                                            opacities=np.full(4, 0.7), rgb=rgb, sh_degree=a.sh_degree)

    own = np.clip(a.rgb[host].astype(np.float64), 0, 1)
    black = np.zeros((4, 3))  # the surface's colours lie in 0.1-0.9 per channel: >= 0.17 from black
    cloud = GaussianCloud.concatenate([a, blobs(4, own), blobs(4, black), blobs(8, own)])
    _, keep, report = prune_cloud(cloud)
    scores = report.mean_distances[3000:]
    assert (scores[:8] > 0.5).all() and (scores[:8] < 2.0).all() and (scores[8:] > 2.0).all()
    assert keep[:3000].all()
    assert keep[3000:3004].all()  # oversized, but the colour of a neighbour and under --blob-sure
    assert not keep[3004:].any()  # foreign colour, or above --blob-sure whatever the colour
    _, keep, _ = prune_cloud(cloud, blob_colour=0.0)
    assert not keep[3000:].any() and keep[:3000].all()
    _, keep, _ = prune_cloud(cloud, blob_sure=1e9)
    assert keep[3000:3004].all() and keep[3008:].all() and not keep[3004:3008].any()
    with pytest.raises(ConfigError, match="blob_colour"):
        PruneConfig(blob_colour=-0.1)
    # a one-colour cloud gives the colour nothing to go on: every candidate goes, and the report says why
    grey = cloud.with_fields(sh_dc=np.zeros_like(cloud.sh_dc))
    _, keep, report = prune_cloud(grey)
    assert keep[:3000].all() and not keep[3000:].any() and "nearly one colour" in report.mode_reason


def test_a_round_blob_of_foreign_colour_among_large_gaussians_goes_whatever_its_score():
    """In a coarse region (sparse, large Gaussians) a blob 10x the scene's median size scores low; the foreign-blob
    test takes it when it is round and of a colour none of its neighbours has."""
    from roodi_toolkit.gaussians import SH_C0, GaussianCloud

    def sphere(n: int, seed: int) -> GaussianCloud:
        return planted_floater_cloud(FloaterMix("sphere", n_object=n, far_fraction=0, near_fraction=0), seed).cloud

    fine, coarse = sphere(3000, 0), sphere(1000, 1)
    grey = np.full((1000, 3), 0.5)
    coarse = coarse.with_fields(means=coarse.means * np.float32(3) + np.float32([0, 0, 3.5]),
                                log_scales=coarse.log_scales + np.float32(np.log(3)),
                                sh_dc=((grey - 0.5) / SH_C0).astype(np.float32))  # touches the fine sphere
    size = float(np.exp(np.median(fine.log_scales.astype(np.float64).mean(axis=1))))

    def blobs(first: int, rgb: np.ndarray, flat: float = 1.0) -> GaussianCloud:
        scales = np.full((4, 3), size * 10)
        scales[:, 2] *= flat
        return GaussianCloud.from_activated(coarse.means[first::250].astype(np.float64), scales=scales,
                                            opacities=np.full(4, 0.7), rgb=np.broadcast_to(rgb, (4, 3)),
                                            sh_degree=fine.sh_degree)

    red = np.array([1.0, 0.0, 0.0])
    cloud = GaussianCloud.concatenate([fine, coarse, blobs(0, red), blobs(80, grey[:4]), blobs(160, red, 0.3)])
    _, keep, report = prune_cloud(cloud)
    assert (report.mean_distances[4000:] < 0.5).all()  # under --blob-score: the oversized score misses them all
    assert keep[:4000].all()
    assert not keep[4000:4004].any()  # round, foreign colour
    assert keep[4004:4012].all()  # a neighbour's colour; flat
    assert report.statistics["oversized_foreign"] == 4 and "4 round Gaussians" in report.mode_reason
    _, keep, _ = prune_cloud(cloud, foreign_size=0)
    assert keep.all()
    _, keep, _ = prune_cloud(cloud, foreign_size=20)
    assert keep.all()
    with pytest.raises(ConfigError, match="foreign_size"):
        PruneConfig(foreign_size=0.5)


def test_statistical_mode_is_the_unchanged_rule():
    planted = planted_floater_cloud(FloaterMix("torus", n_object=3000), seed=0)
    for rule in ("paper", "robust"):
        _, keep, report = prune_cloud(planted.cloud, mode="statistical", rule=rule)
        _, expected, _ = remove_statistical_outliers(planted.cloud, rule=rule)
        np.testing.assert_array_equal(keep, expected)
        assert report.mode == "statistical"


def test_value_ranges_filter_before_the_tests():
    cloud = planted_floater_cloud(FloaterMix("sphere", n_object=2000, far_fraction=0, near_fraction=0), 0).cloud
    _, keep, report = prune_cloud(cloud, value_ranges=(("z", 0.0, 10.0), ("opacity", 0.7, 1.0)))
    z_ok = cloud.means[:, 2] >= 0
    assert not keep[~z_ok].any() and not keep[cloud.opacities < 0.7].any()
    stages = dict(report.stages)
    assert stages["z in [0, 10]"] == int((~z_ok).sum())
    with pytest.raises(ConfigError, match="value range"):
        PruneConfig(value_ranges=(("colour", 0, 1),))
    with pytest.raises(ConfigError, match="mode"):
        PruneConfig(mode="fast")


def test_cli_dry_run_writes_report_and_picture_only(run_cli, tmp_path):
    planted = planted_floater_cloud(FloaterMix("sphere", n_object=3000), 0)
    src = tmp_path / "in.ply"
    write_ply(planted.cloud, src)
    out = tmp_path / "clean.ply"
    res = run_cli("prune", src, out, "--dry-run")
    assert res.exit_code == 0, res.stderr
    assert "would go" in res.stdout and res.stdout.startswith("object mode (auto)")
    assert not out.exists()
    summary = json.loads((tmp_path / "clean.prune.json").read_text())
    assert summary["dry_run"] and summary["mode"] == "object" and summary["output"] is None
    assert (tmp_path / "clean.prune.png").stat().st_size > 1000
    res = run_cli("prune", src, out, "--rule", "paper", "--report", tmp_path / "r.json")
    assert res.exit_code == 0 and res.stdout.startswith("statistical mode")
    assert json.loads((tmp_path / "r.json").read_text())["config"]["rule"] == "paper"
    res = run_cli("prune", src, out, "--overwrite", "--filter-value", "size,0,1")
    assert res.exit_code == 2 and "--filter-value" in res.stderr
    res = run_cli("prune", src, out, "--overwrite", "--filter-value", "scale,0,0.5", "--mode", "scene")
    assert res.exit_code == 0, res.stderr
    assert (read_ply(out).scales.max(axis=1) <= 0.5).all()
    res = run_cli("prune", src, out, "--overwrite", "--max-piece", "-1")
    assert res.exit_code == 2 and "--max-piece" in res.stderr
    res = run_cli("prune", src, out, "--overwrite", "--max-piece", "0", "--report", tmp_path / "m.json")
    assert res.exit_code == 0, res.stderr
    assert json.loads((tmp_path / "m.json").read_text())["config"]["max_piece"] == 0
    for bad in (-1, 2.5, True):
        with pytest.raises(ConfigError, match="max_piece"):
            PruneConfig(max_piece=bad)


def test_white_background_fog_is_detected_and_removed():
    planted = planted_floater_cloud(FloaterMix("sphere", n_object=4000, far_fraction=0, near_fraction=0), 2)
    rng = np.random.default_rng(0)
    n = 600  # a faint white haze around the object, as training on a white background leaves
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    haze = type(planted.cloud).from_activated(direction * rng.uniform(1.4, 2.6, (n, 1)),
                                              scales=np.full((n, 3), 0.05), opacities=rng.uniform(0.005, 0.05, n),
                                              rgb=np.ones((n, 3)))
    cloud = type(haze).concatenate([planted.cloud, haze])
    _, keep, report = prune_cloud(cloud)
    assert not keep[4000:].any() and keep[:4000].mean() > 0.99
    assert "white-background fog" in report.mode_reason
    _, keep, report = prune_cloud(cloud, background="none", mode="scene")
    assert dict(report.stages)["fog"] == 0
