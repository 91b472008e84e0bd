"""Statistical outlier removal: Open3D equivalence, semantics, filters, the report, and the floater target."""

from __future__ import annotations

import numpy as np
import pytest

from roodi_toolkit.errors import CloudError, ConfigError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.prune.outliers import (NeighborDistances, PruneConfig, outlier_mask, paper_threshold, PruneReport,
                                    remove_statistical_outliers, robust_threshold)
from roodi_toolkit.synth.floaters import FAR, NEAR, OBJECT, STANDARD_MIXES, FloaterMix, planted_floater_cloud
from roodi_toolkit.prune.wasserstein import w2_sq


def _cloud(means: np.ndarray, seed: int = 0, log_scale: float = -4.0) -> GaussianCloud:
    rng = np.random.default_rng(seed)
    n = len(means)
    return GaussianCloud(means=np.asarray(means, dtype=np.float32),
                         quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32),
                         log_scales=rng.normal(log_scale, 0.3, size=(n, 3)).astype(np.float32),
                         opacity_logits=rng.normal(size=n).astype(np.float32),
                         sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
                         sh_rest=np.zeros((n, 0, 3), np.float32),
                         extras={"id": np.arange(n, dtype=np.int32)})


@pytest.mark.parametrize("k,alpha,seed", [(16, 2.0, 0), (8, 1.0, 1), (30, 0.5, 2), (4, 3.0, 3)])
def test_euclidean_paper_rule_keeps_exactly_what_open3d_keeps(k, alpha, seed):
    import open3d as o3d

    rng = np.random.default_rng(seed)
    pts = np.concatenate([rng.normal(size=(3000, 3)), rng.uniform(-6, 6, size=(60, 3))]).astype(np.float32)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    _, kept = pcd.remove_statistical_outlier(nb_neighbors=k + 1, std_ratio=alpha)
    expected = np.zeros(len(pts), dtype=bool)
    expected[np.asarray(kept)] = True
    _, keep, report = remove_statistical_outliers(_cloud(pts), k=k, alpha=alpha, distance="euclidean", rule="paper")
    assert 0 < (~expected).sum() < len(pts)
    assert np.array_equal(keep, expected)


def test_w2_mean_distances_follow_the_definition():
    rng = np.random.default_rng(4)
    cloud = _cloud(rng.normal(size=(300, 3)), log_scale=-1.5)
    k = 5
    dist = NeighborDistances(cloud, PruneConfig(k=k, compute_dtype="float64"))
    n = len(cloud)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    d2 = np.sum((cloud.means[:, None, :].astype(np.float64) - cloud.means[None, :, :]) ** 2, axis=2)
    np.fill_diagonal(d2, np.inf)
    nearest = np.argsort(d2, axis=1, kind="stable")[:, :k]
    rows = np.repeat(np.arange(n), k)
    w2 = w2_sq(cloud.means[rows], cloud.quats_wxyz[rows], cloud.log_scales[rows], cloud.means[nearest.ravel()],
               cloud.quats_wxyz[nearest.ravel()], cloud.log_scales[nearest.ravel()]).reshape(n, k)
    np.testing.assert_allclose(dist.mean, w2.mean(axis=1), rtol=1e-10)
    # paper rule: mean + alpha * sample std of d_i, keep <=
    flagged = outlier_mask(dist, PruneConfig(k=k, rule="paper", alpha=1.0))
    thr = dist.mean.mean() + 1.0 * dist.mean.std(ddof=1)
    assert np.array_equal(flagged, dist.mean > thr)
    assert paper_threshold(dist.mean, 1.0) == pytest.approx(thr)


def test_duplicate_centres_are_not_outliers():
    rng = np.random.default_rng(5)
    surface = rng.normal(size=(2000, 3))
    surface /= np.linalg.norm(surface, axis=1, keepdims=True)
    dup_rows = rng.choice(2000, 100, replace=False)
    means = np.concatenate([surface, np.repeat(surface[dup_rows], 25, axis=0)])  # groups of 26 > K + 1
    cloud = _cloud(means, log_scale=-4.0)
    cloud = cloud.with_fields(quats_wxyz=np.tile([1, 0, 0, 0], (len(means), 1)).astype(np.float32),
                              log_scales=np.full((len(means), 3), -4.0, np.float32))
    for rule in ("robust", "paper", "clip"):
        for distance in ("w2", "euclidean"):
            _, keep, report = remove_statistical_outliers(cloud, k=16, rule=rule, distance=distance)
            assert keep[2000:].all(), (rule, distance)
            assert report.mean_distances[2000:].min() == 0.0


def test_robust_threshold_ignores_a_heavy_tail():
    rng = np.random.default_rng(6)
    d = np.exp(rng.normal(0, 0.3, 10000))
    thr, med, mad = robust_threshold(d, 4.0)
    contaminated = np.concatenate([d, np.full(300, 1e6)])
    thr2, _, _ = robust_threshold(contaminated, 4.0)
    assert thr == pytest.approx(np.exp(4 * 0.3), rel=0.05)  # 1.4826 * MAD estimates sigma = 0.3
    assert thr2 == pytest.approx(thr, rel=0.1)  # 3% contamination moves it by a few percent
    assert paper_threshold(contaminated, 2.0) > 1e4  # the paper's statistics are dragged by the tail


def test_filters_and_report_counts():
    planted = planted_floater_cloud(FloaterMix("sphere", n_object=3000), seed=0)
    cloud = planted.cloud
    n = len(cloud)
    means = cloud.means.copy()
    means[:5] = np.nan
    cloud = cloud.with_fields(means=means)
    with pytest.raises(CloudError, match="--filter-nan"):
        remove_statistical_outliers(cloud)
    low = cloud.opacities < 0.1
    pruned, keep, report = remove_statistical_outliers(cloud, filter_nan=True, min_opacity=0.1,
                                                       box=(-1.5, -1.5, -1.5, 1.5, 1.5, 0.8),
                                                       sphere=(0, 0, 0, 1.2))
    stages = dict(report.stages)
    assert stages["nonfinite"] == 5
    assert stages["min_opacity"] == int((low & ~cloud.nonfinite_rows()).sum())
    assert stages["box"] > 0 and stages["sphere"] > 0 and stages["statistical"] >= 0
    assert sum(stages.values()) == n - len(pruned) == n - keep.sum()
    assert not keep[:5].any() and not keep[low].any()
    assert np.all(pruned.means[:, 2] <= 0.8)
    assert np.all(np.linalg.norm(pruned.means, axis=1) <= 1.2 + 1e-6)
    # kept Gaussians in input order with every column
    np.testing.assert_array_equal(pruned.means, cloud.means[keep])
    np.testing.assert_array_equal(pruned.sh_rest, cloud.sh_rest[keep])
    # the per-Gaussian distances line up with the evaluated input rows, and the threshold separates them
    assert len(report.evaluated) == len(report.mean_distances) == len(report.first_mean_distances)
    statistical_removed = ~keep[report.evaluated]
    assert np.array_equal(statistical_removed, report.mean_distances > report.threshold)
    summary = report.to_dict()
    assert summary["kept_count"] == len(pruned) and summary["removed_count"] == n - len(pruned)
    assert {"rule", "neighbours_and_distances", "total"} <= set(summary["timings_s"]) | {"rule"}


def test_extras_carried_and_keep_mask_applies_to_other_data():
    planted = planted_floater_cloud(FloaterMix("box", n_object=2000), seed=1)
    cloud = planted.cloud
    cloud.extras["label"] = planted.labels.astype(np.int32)
    pruned, keep, _ = remove_statistical_outliers(cloud)
    np.testing.assert_array_equal(pruned.extras["label"], planted.labels[keep])


def test_config_errors():
    with pytest.raises(ConfigError, match="rule"):
        PruneConfig(rule="nope")
    with pytest.raises(ConfigError, match="needs distance 'w2'"):
        PruneConfig(neighbors="w2", distance="euclidean")
    with pytest.raises(ConfigError, match="box"):
        PruneConfig(box=(1, 0, 0, 0, 1, 1))
    with pytest.raises(ConfigError, match="at least 17 Gaussians"):
        remove_statistical_outliers(_cloud(np.zeros((10, 3))))
    with pytest.raises(CloudError, match="no Gaussians left"):
        remove_statistical_outliers(_cloud(np.random.default_rng(0).normal(size=(50, 3))), sphere=(9, 9, 9, 0.1))


def test_w2_neighbour_mode_runs_and_catches_floaters():
    planted = planted_floater_cloud(FloaterMix("torus", n_object=3000, far_fraction=0.01, near_fraction=0.01), 2)
    _, keep, report = remove_statistical_outliers(planted.cloud, neighbors="w2")
    assert keep[planted.labels == OBJECT].mean() >= 0.99
    assert not keep[planted.labels == FAR].any()
    assert (~keep[planted.labels == NEAR]).mean() >= 0.95


def test_default_rule_meets_the_floater_target_on_every_mix():
    """Issue 3's target: >= 95% of each floater kind removed and <= 1% of the object lost, every standard mix."""
    config = PruneConfig()
    failures = []
    for mix in STANDARD_MIXES:
        planted = planted_floater_cloud(mix, seed=0)
        flagged = outlier_mask(NeighborDistances(planted.cloud, config), config)
        lab = planted.labels
        far = flagged[lab == FAR].mean() if (lab == FAR).any() else 1.0
        near = flagged[lab == NEAR].mean() if (lab == NEAR).any() else 1.0
        lost = flagged[lab == OBJECT].mean()
        if far < 0.95 or near < 0.95 or lost > 0.01:
            failures.append(f"{mix.name}: far {far:.3f} near {near:.3f} object lost {lost:.4f}")
    assert not failures, "\n".join(failures)


def test_paper_rule_misses_near_floaters_that_the_default_catches():
    """The motivation for the default: far floaters inflate mean + alpha * std and hide the near ones."""
    planted = planted_floater_cloud(FloaterMix("sphere", n_object=20_000, far_fraction=0.01, near_fraction=0.01), 0)
    dist = NeighborDistances(planted.cloud, PruneConfig())
    paper = outlier_mask(dist, PruneConfig(rule="paper", alpha=2.0))
    assert paper[planted.labels == NEAR].mean() < 0.5


def test_robust_rule_does_not_erode_a_regular_grid():
    """Over half the distances equal (MAD 0) and re-evaluation rounds must not peel the boundary layer by layer."""
    from roodi_toolkit import GaussianCloud

    g = np.stack(np.meshgrid(np.arange(30.0), np.arange(30.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
    grid = GaussianCloud.from_activated(g, scales=np.full((len(g), 3), 0.2), opacities=np.full(len(g), 0.9),
                                        rgb=np.full((len(g), 3), 0.5))
    _, keep, report = remove_statistical_outliers(grid)
    _, keep_paper, _ = remove_statistical_outliers(grid, rule="paper")
    # statistical outlier removal flags a clean grid's corners (the paper's pass does too), but no more than that
    assert keep.sum() >= keep_paper.sum() and keep.mean() > 0.85, report.to_dict()
    far = GaussianCloud.concatenate([grid, GaussianCloud.from_activated(
        np.array([[100.0, 100.0, 50.0]]), scales=np.full((1, 3), 0.2), opacities=[0.9], rgb=[[0.5, 0.5, 0.5]])])
    _, keep2, _ = remove_statistical_outliers(far)
    assert not keep2[-1] and keep2[:-1].mean() > 0.85


def test_memoised_rounds_equal_full_recomputation():
    """Later rounds recompute only rows whose candidates were cleared: the result equals recomputing every row."""

    class NoMemo(NeighborDistances):
        def mean_excluding(self, flagged, threshold=None, only=None):
            self._memo = None
            return super().mean_excluding(flagged, threshold, only)

    for mix in STANDARD_MIXES[:3] + STANDARD_MIXES[-4:-3]:
        planted = planted_floater_cloud(mix, seed=1)
        config = PruneConfig()
        a, b = PruneReport(input_count=len(planted.cloud)), PruneReport(input_count=len(planted.cloud))
        fast = outlier_mask(NeighborDistances(planted.cloud, config), config, a)
        full = outlier_mask(NoMemo(planted.cloud, config), config, b)
        assert np.array_equal(fast, full) and a.iterations == b.iterations
        np.testing.assert_array_equal(a.mean_distances, b.mean_distances)
