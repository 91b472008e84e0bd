"""The one torch form of Gaussians: :class:`GaussianParams`, what renderers draw and optimizers train.

:class:`~roodi_toolkit.gaussians.GaussianCloud` is the numpy form (I/O, geometry); this is its torch twin with the
same honest field names and raw value spaces (``log_scales``: scale = exp, ``opacity_logits``: opacity = sigmoid,
``quats_wxyz`` not necessarily normalised). Conversion is explicit both ways (:meth:`GaussianParams.from_cloud`,
:meth:`GaussianParams.to_cloud`).

The container is also a mapping from those names to tensors (``params["log_scales"]``, ``params[name] = new``,
``params.items()``), which is all the MCMC strategy's parameter edits (:mod:`roodi_toolkit.pipeline.strategy`) and a
checkpoint need; ``features`` is a key only while it is set.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Iterator, Mapping, Optional, Sequence

import numpy as np
import torch
from torch import Tensor

from .errors import CloudError
from .gaussians import GaussianCloud, check_field_shapes, sh_degree_from_coeffs

PARAM_NAMES = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest")
"""The fields every :class:`GaussianParams` has; ``features`` is optional."""


@dataclass(eq=False)
class GaussianParams:
    """N Gaussians as torch tensors in their raw value spaces (any of them may be a trainable Parameter).

    Attributes:
        means: centres. [N, 3]
        quats_wxyz: rotations, w first, not necessarily normalised. [N, 4]
        log_scales: log standard deviations. [N, 3]
        opacity_logits: pre-sigmoid opacities. [N]
        sh_dc: degree-0 SH coefficient per colour channel, as ``GaussianCloud.sh_dc``. [N, 3]
        sh_rest: higher SH coefficients, coefficient-major, K = (degree+1)^2. [N, K-1, 3]
        features: extra channels rendered with the same compositing weights (object features), or None. [N, F]

    Example:
        >>> cloud = GaussianCloud.from_activated(np.zeros((2, 3)), scales=np.full((2, 3), 0.1),
        ...                                      opacities=np.array([0.5, 0.9]), rgb=np.full((2, 3), 0.5))
        >>> p = GaussianParams.from_cloud(cloud, requires_grad=True, sh_degree=1)
        >>> len(p), tuple(p.sh_rest.shape), tuple(p.colors.shape), p.means.requires_grad
        (2, (2, 3, 3), (2, 4, 3), True)
        >>> list(p.keys())
        ['means', 'quats_wxyz', 'log_scales', 'opacity_logits', 'sh_dc', 'sh_rest']
        >>> np.array_equal(p.to_cloud().means, cloud.means)
        True
    """

    means: Tensor
    quats_wxyz: Tensor
    log_scales: Tensor
    opacity_logits: Tensor
    sh_dc: Tensor
    sh_rest: Tensor
    features: Optional[Tensor] = None

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check the shapes; raise CloudError naming the offending field and its shape."""
        if self.means.ndim != 2 or self.means.shape[1] != 3:
            raise CloudError(f"GaussianParams.means must have shape [N, 3], got {list(self.means.shape)}")
        n = self.means.shape[0]
        expected = {"quats_wxyz": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "sh_dc": (n, 3)}
        check_field_shapes(self, "GaussianParams", expected, n, rest_label=str(n))
        if self.features is not None and (self.features.ndim != 2 or self.features.shape[0] != n):
            raise CloudError(f"GaussianParams.features must have shape [{n}, F], got {list(self.features.shape)}")

    # ----------------------------------------------------------------------------------------------- conversion
    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, *, requires_grad: bool = False, sh_degree: Optional[int] = None,
                   features: Sequence[str] | Tensor | np.ndarray | None = None, dtype: torch.dtype = torch.float32,
                   device: str | torch.device = "cpu") -> "GaussianParams":
        """Return the cloud's raw arrays as (copied) tensors.

        Args:
            cloud: the Gaussians.
            requires_grad: make every tensor a ``torch.nn.Parameter`` (copies, so optimizers never write into the
                cloud's arrays).
            sh_degree: pad ``sh_rest`` with zeros (or cut it) to this degree; default the cloud's own.
            features: names of extra columns of the cloud to stack as feature channels, or the features themselves
                ``[N, F]``; default none.
            dtype: tensor dtype.
            device: tensor device.
        """
        t = lambda a: torch.tensor(np.asarray(a), dtype=dtype, device=device)  # noqa: E731  (copies)
        rest = cloud.sh_rest
        if sh_degree is not None:
            k = (int(sh_degree) + 1) ** 2 - 1
            rest = rest[:, :k] if rest.shape[1] >= k else np.concatenate(
                [rest, np.zeros((len(cloud), k - rest.shape[1], 3), dtype=rest.dtype)], axis=1)
        feats = None
        if isinstance(features, (Tensor, np.ndarray)):
            feats = features.detach().to(dtype=dtype, device=device).clone() if isinstance(features, Tensor) \
                else t(features)
        elif features:
            missing = [name for name in features if name not in cloud.extras]
            if missing:
                raise CloudError(f"the cloud has no extra column(s) {missing}; it has {list(cloud.extras) or 'none'}")
            feats = t(np.stack([cloud.extras[name].astype(np.float64) for name in features], axis=1))
        params = cls(t(cloud.means), t(cloud.quats_wxyz), t(cloud.log_scales), t(cloud.opacity_logits),
                     t(cloud.sh_dc), t(rest), feats)
        return params.requires_grad_() if requires_grad else params

    def to_cloud(self, *, feature_names: Optional[Sequence[str]] = None) -> GaussianCloud:
        """Return the Gaussians as a float32 GaussianCloud; features become extra columns named ``feature_names``
        (default ``object_feature_0`` ..., as the distillation writes them)."""
        a = lambda x: x.detach().cpu().numpy().astype(np.float32)  # noqa: E731
        extras = {}
        if self.features is not None:
            f = a(self.features)
            names = list(feature_names) if feature_names is not None else \
                [f"object_feature_{i}" for i in range(f.shape[1])]
            if len(names) != f.shape[1]:
                raise CloudError(f"{len(names)} feature names for {f.shape[1]} feature channels")
            extras = {name: np.ascontiguousarray(f[:, i]) for i, name in enumerate(names)}
        return GaussianCloud(a(self.means), a(self.quats_wxyz), a(self.log_scales), a(self.opacity_logits),
                             a(self.sh_dc), a(self.sh_rest), extras)

    # ----------------------------------------------------------------------------------------------- basics
    def __len__(self) -> int:
        return int(self.means.shape[0])

    def __repr__(self) -> str:
        feats = "" if self.features is None else f", features={self.features.shape[1]}"
        return f"GaussianParams(n={len(self)}, sh_degree={self.sh_degree}{feats})"

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_coeffs(self.sh_rest.shape[1] + 1)

    @property
    def colors(self) -> Tensor:
        """All SH coefficients, DC first, coefficient-major (what rasterizers take). [N, K, 3]"""
        return torch.cat([self.sh_dc[:, None, :], self.sh_rest], dim=1)

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    @property
    def device(self) -> torch.device:
        return self.means.device

    # ----------------------------------------------------------------------------------------------- mapping
    def keys(self) -> list[str]:
        """Return the names of the tensors held: :data:`PARAM_NAMES`, then ``features`` when set."""
        return list(PARAM_NAMES) + ([] if self.features is None else ["features"])

    def __iter__(self) -> Iterator[str]:
        return iter(self.keys())

    def __contains__(self, name: object) -> bool:
        return name in self.keys()

    def __getitem__(self, name: str) -> Tensor:
        if name not in self.keys():
            raise KeyError(f"GaussianParams has no tensor {name!r}; it has {self.keys()}")
        return getattr(self, name)

    def __setitem__(self, name: str, value: Tensor) -> None:
        """Replace one tensor (no shape check: the strategy replaces them one at a time when the count changes)."""
        if name not in PARAM_NAMES and name != "features":
            raise KeyError(f"GaussianParams has no field {name!r}; fields are {list(PARAM_NAMES) + ['features']}")
        setattr(self, name, value)

    def items(self) -> list[tuple[str, Tensor]]:
        return [(name, getattr(self, name)) for name in self.keys()]

    def values(self) -> list[Tensor]:
        return [getattr(self, name) for name in self.keys()]

    # ----------------------------------------------------------------------------------------------- optimisation
    def requires_grad_(self, requires_grad: bool = True) -> "GaussianParams":
        """Turn every tensor into a leaf ``torch.nn.Parameter`` (copies nothing); return self."""
        for name in self.keys():
            value = getattr(self, name)
            if not isinstance(value, torch.nn.Parameter):
                value = torch.nn.Parameter(value.detach().contiguous(), requires_grad=requires_grad)
            else:
                value.requires_grad_(requires_grad)
            setattr(self, name, value)
        return self

    def param_groups(self, lrs: Mapping[str, float]) -> list[dict]:
        """Return ``torch.optim`` parameter groups, one per name in ``lrs`` (unknown names are refused).

        Example:
            >>> p = GaussianParams.from_cloud(GaussianCloud.from_activated(np.zeros((1, 3)), scales=np.ones((1, 3)),
            ...     opacities=np.array([0.5]), rgb=np.zeros((1, 3))), requires_grad=True)
            >>> opt = torch.optim.Adam(p.param_groups({"means": 1e-3, "sh_dc": 1e-2}))
            >>> [g["name"] for g in opt.param_groups]
            ['means', 'sh_dc']
        """
        return [{"params": [self[name]], "lr": float(lr), "name": name} for name, lr in lrs.items()]

    def adam(self, config, means_scale: float, *, fused: bool = True) -> dict[str, torch.optim.Adam]:
        """Return one Adam per parameter of :data:`PARAM_NAMES`, as 3DGS trains them: each its own learning rate
        from ``config`` (``means_lr`` times ``means_scale``, the size of the scene or object, then ``quats_lr``,
        ``scales_lr``, ``opacities_lr``, ``sh0_lr``, ``shN_lr``) and ``eps`` 1e-15. ``fused``: one compiled pass per
        parameter instead of about ten tensor operations, the same update to float rounding (``fused=False`` is the
        reference that ``tests/pipeline/test_train_kernels.py`` and ``bench_train_step.py`` compare)."""
        lrs = {"means": config.means_lr * means_scale, "quats_wxyz": config.quats_lr, "log_scales": config.scales_lr,
               "opacity_logits": config.opacities_lr, "sh_dc": config.sh0_lr, "sh_rest": config.shN_lr}
        return {name: torch.optim.Adam([self[name]], lr=lrs[name], eps=1e-15, fused=fused) for name in PARAM_NAMES}

    def detach(self) -> "GaussianParams":
        """Return the same values without gradients (no copy)."""
        return GaussianParams(*(None if getattr(self, f.name) is None else getattr(self, f.name).detach()
                                for f in fields(self)))

    def with_features(self, features: Optional[Tensor]) -> "GaussianParams":
        """Return a container sharing these tensors with ``features`` ``[N, F]`` (or none) instead."""
        return GaussianParams(self.means, self.quats_wxyz, self.log_scales, self.opacity_logits, self.sh_dc,
                              self.sh_rest, features)
