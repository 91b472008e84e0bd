"""GaussianParams: exact round trip with GaussianCloud, shape checks naming the shape, the mapping the strategy edits."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import CloudError
from roodi_toolkit.params import PARAM_NAMES, GaussianParams

from .conftest import make_cloud

FIELDS = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_exact(degree):
    cloud = make_cloud(40, sh_degree=degree, seed=degree)
    params = GaussianParams.from_cloud(cloud)
    assert tuple(params.sh_dc.shape) == (40, 3) and tuple(params.sh_rest.shape) == (40, (degree + 1) ** 2 - 1, 3)
    back = params.to_cloud()
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(cloud, name), err_msg=name)
        assert getattr(back, name).dtype == np.float32
    torch.testing.assert_close(params.colors, torch.as_tensor(cloud.sh), rtol=0, atol=0)


def test_trainable_params_are_copies_and_leaves():
    cloud = make_cloud(10, sh_degree=1)
    params = GaussianParams.from_cloud(cloud, requires_grad=True)
    assert all(isinstance(t, torch.nn.Parameter) and t.is_leaf for t in params.values())
    with torch.no_grad():
        for t in params.values():
            t.add_(1.0)
    np.testing.assert_array_equal(params.to_cloud().means, cloud.means + 1.0)
    assert not np.array_equal(params.to_cloud().means, cloud.means)
    opt = torch.optim.Adam(params.param_groups({"means": 0.1, "log_scales": 0.01}))
    assert [g["params"][0] is params[g["name"]] for g in opt.param_groups] == [True, True]


def test_sh_degree_padding_and_cutting():
    cloud = make_cloud(5, sh_degree=1)
    padded = GaussianParams.from_cloud(cloud, sh_degree=3)
    assert padded.sh_degree == 3 and tuple(padded.sh_rest.shape) == (5, 15, 3)
    torch.testing.assert_close(padded.sh_rest[:, :3], torch.as_tensor(cloud.sh_rest), rtol=0, atol=0)
    assert (padded.sh_rest[:, 3:] == 0).all()
    cut = GaussianParams.from_cloud(cloud, sh_degree=0)
    assert cut.sh_degree == 0 and tuple(cut.sh_rest.shape) == (5, 0, 3)


def test_features_from_columns_or_tensor_and_back():
    cloud = make_cloud(6, extras=True)
    params = GaussianParams.from_cloud(cloud, features=["weight", "segment_id"])
    assert tuple(params.features.shape) == (6, 2) and "features" in params
    np.testing.assert_allclose(params.features[:, 0].numpy(), cloud.extras["weight"], rtol=1e-6)
    with pytest.raises(CloudError, match=r"no extra column\(s\) \['nope'\]"):
        GaussianParams.from_cloud(cloud, features=["nope"])
    feats = torch.arange(12.0).reshape(6, 2)
    back = GaussianParams.from_cloud(cloud, features=feats).to_cloud()
    assert list(back.extras) == ["object_feature_0", "object_feature_1"]
    np.testing.assert_array_equal(back.extras["object_feature_1"], feats[:, 1].numpy())
    named = GaussianParams.from_cloud(cloud, features=feats).to_cloud(feature_names=["a", "b"])
    assert list(named.extras) == ["a", "b"]
    assert "features" not in GaussianParams.from_cloud(cloud).keys()


@pytest.mark.parametrize("name, bad", [
    ("means", torch.zeros(4, 2)), ("quats_wxyz", torch.zeros(4, 3)), ("log_scales", torch.zeros(5, 3)),
    ("opacity_logits", torch.zeros(4, 1)), ("sh_dc", torch.zeros(4, 1, 3)), ("sh_rest", torch.zeros(4, 3)),
    ("features", torch.zeros(3, 2)),
])
def test_shapes_are_checked_with_the_offending_shape(name, bad):
    good = dict(means=torch.zeros(4, 3), quats_wxyz=torch.zeros(4, 4), log_scales=torch.zeros(4, 3),
                opacity_logits=torch.zeros(4), sh_dc=torch.zeros(4, 3), sh_rest=torch.zeros(4, 0, 3))
    good[name] = bad
    with pytest.raises(CloudError, match=re.escape(f"GaussianParams.{name} must have shape")) as err:
        GaussianParams(**good)
    assert str(err.value).endswith(f"got {list(bad.shape)}")


def test_sh_rest_must_be_an_sh_degree():
    with pytest.raises(CloudError, match="2 SH coefficients per channel is no SH degree"):
        GaussianParams(torch.zeros(4, 3), torch.zeros(4, 4), torch.zeros(4, 3), torch.zeros(4), torch.zeros(4, 3),
                       torch.zeros(4, 1, 3))


def test_mapping_for_the_strategy():
    params = GaussianParams.from_cloud(make_cloud(8), requires_grad=True)
    assert list(params) == list(PARAM_NAMES) and len(params) == 8
    assert params["log_scales"] is params.log_scales
    params["opacity_logits"] = torch.nn.Parameter(torch.ones(8))
    assert (params.opacity_logits == 1).all()
    with pytest.raises(KeyError, match="no tensor 'scales'"):
        params["scales"]
    with pytest.raises(KeyError, match="no field 'opacities'"):
        params["opacities"] = torch.zeros(8)
    detached = params.detach()
    assert not any(t.requires_grad for t in detached.values())
