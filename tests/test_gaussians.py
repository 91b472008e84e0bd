import numpy as np
import pytest

from roodi_toolkit import CloudError, GaussianCloud
from roodi_toolkit.gaussians import SH_C0, quat_to_rotmat, sigmoid


def test_activations(cloud_factory):
    c = cloud_factory(20, sh_degree=2)
    np.testing.assert_allclose(c.opacities, 1 / (1 + np.exp(-c.opacity_logits.astype(np.float64))), rtol=1e-6)
    np.testing.assert_allclose(c.scales, np.exp(c.log_scales))
    np.testing.assert_allclose(c.rgb, 0.5 + SH_C0 * c.sh_dc)
    np.testing.assert_allclose(np.linalg.norm(c.quats_normalized, axis=1), 1.0, rtol=1e-6)
    assert c.sh.shape == (20, 9, 3)
    assert c.sh_degree == 2


def test_sigmoid_extremes_do_not_overflow():
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        out = sigmoid(np.array([-1e4, 0.0, 1e4], dtype=np.float32))
    np.testing.assert_allclose(out, [0.0, 0.5, 1.0])


def test_rotation_is_orthonormal_and_matches_scipy(cloud_factory):
    from scipy.spatial.transform import Rotation

    c = cloud_factory(30)
    R = c.rotations()
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    q = c.quats_normalized.astype(np.float64)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(R, ref, atol=1e-6)


def test_zero_quaternion_is_identity():
    np.testing.assert_array_equal(quat_to_rotmat(np.zeros((1, 4)))[0], np.eye(3))


def test_covariance_and_its_square_root(cloud_factory):
    from scipy.linalg import sqrtm

    c = cloud_factory(10)
    cov, root = c.covariances(), c.covariance_sqrts()
    for i in range(10):
        np.testing.assert_allclose(root[i] @ root[i], cov[i], rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(root[i], np.real(sqrtm(cov[i])), rtol=1e-6, atol=1e-12)


def test_select_carries_extras_and_normals(cloud_factory):
    c = cloud_factory(10, sh_degree=1, extras=True)
    c.normals = np.arange(30, dtype=np.float32).reshape(10, 3)
    mask = np.arange(10) % 3 == 0
    s = c.select(mask)
    assert len(s) == 4
    np.testing.assert_array_equal(s.extras["segment_id"], c.extras["segment_id"][mask])
    np.testing.assert_array_equal(s.normals, c.normals[mask])
    np.testing.assert_array_equal(s.sh_rest, c.sh_rest[mask])
    assert list(s.extras) == list(c.extras)


def test_select_rejects_wrong_mask(cloud_factory):
    c = cloud_factory(5)
    with pytest.raises(CloudError, match=r"shape \[5\]"):
        c.select(np.ones(4, dtype=bool))
    with pytest.raises(CloudError, match="out of range"):
        c.select(np.array([7]))


def test_validation_names_field_and_shape(cloud_factory):
    c = cloud_factory(5)
    with pytest.raises(CloudError, match=r"log_scales must have shape \[5, 3\], got \[5, 2\]"):
        c.with_fields(log_scales=np.zeros((5, 2), dtype=np.float32))
    with pytest.raises(CloudError, match="no SH degree"):
        c.with_fields(sh_rest=np.zeros((5, 5, 3), dtype=np.float32))
    with pytest.raises(CloudError, match="extra column 'bad'"):
        GaussianCloud(c.means, c.quats_wxyz, c.log_scales, c.opacity_logits, c.sh_dc, c.sh_rest,
                      extras={"bad": np.zeros(4)})


def test_concatenate_roundtrip(cloud_factory):
    c = cloud_factory(10, sh_degree=1, extras=True)
    joined = GaussianCloud.concatenate([c.select(np.arange(4)), c.select(np.arange(4, 10))])
    np.testing.assert_array_equal(joined.means, c.means)
    np.testing.assert_array_equal(joined.extras["weight"], c.extras["weight"])


def test_nonfinite_rows_and_require_finite(cloud_factory):
    c = cloud_factory(6, extras=True)
    c.means[1, 0] = np.nan
    c.sh_rest = np.zeros((6, 3, 3), dtype=np.float32)
    c.sh_rest[4, 0, 0] = np.inf
    c.extras["weight"][5] = -np.inf
    np.testing.assert_array_equal(np.flatnonzero(c.nonfinite_rows()), [1, 4, 5])
    with pytest.raises(CloudError, match="3 Gaussians have NaN/Inf values .*--filter-nan"):
        c.require_finite()
