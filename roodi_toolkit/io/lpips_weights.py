"""LPIPS weight files on this machine: finding and reading them, and writing one file of a network's weights.

The network itself is :class:`roodi_toolkit.lpips.LPIPS`, built from state dicts; this module opens the files.
Weights never download. :func:`read_lpips` looks, in order, at:

1. ``path`` or ``$ROODI_LPIPS_WEIGHTS``: one file holding the network's state dict (``features.*`` and ``lins.*``),
   as :func:`write_lpips` writes it;
2. the upstream pair: the lpips package's ``weights/v0.1/alex.pth`` (``lin{i}.model.1.weight``) and torchvision's
   ``alexnet-owt-7be5be79.pth`` (``features.*``) from the torch hub cache (``$TORCH_HOME/hub/checkpoints``).

When neither is there it raises :class:`~roodi_toolkit.lpips.LPIPSUnavailable`, saying where it looked; callers
report LPIPS as unavailable rather than substituting another number.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import torch
from torch import Tensor

from ..errors import ConfigError, RoodiError
from ..lpips import LPIPS, LPIPSUnavailable
from .files import check_torch_archive, save_checkpoint

ENV_WEIGHTS = "ROODI_LPIPS_WEIGHTS"
ALEXNET_CHECKPOINT = "alexnet-owt-7be5be79.pth"

__all__ = ["ALEXNET_CHECKPOINT", "ENV_WEIGHTS", "lpips_for_loss", "read_lpips", "write_lpips"]


def read_lpips(path: str | os.PathLike | None = None) -> LPIPS:
    """Return LPIPS with weights found on this machine (see the module docstring), never downloading.

    Raises:
        LPIPSUnavailable: no usable local weights; the message lists where it looked.
    """
    looked = []
    combined = path or os.environ.get(ENV_WEIGHTS)
    if combined:
        p = Path(combined)
        if not p.is_file():
            raise LPIPSUnavailable(f"{p}: LPIPS weights file not found")
        return LPIPS.from_combined(_load(p), str(p))
    looked.append(f"${ENV_WEIGHTS} (unset)")
    lin_path = _lpips_package_weights()
    alex_path = Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_CHECKPOINT
    looked.append(f"lpips package weights ({lin_path or 'package not installed'})")
    looked.append(str(alex_path))
    if lin_path is not None and lin_path.is_file() and alex_path.is_file():
        return LPIPS.from_state_dicts(_load(lin_path), _load(alex_path))
    raise LPIPSUnavailable("no local LPIPS weights; looked at " + ", ".join(looked))


def lpips_for_loss(kind: str, path: str | os.PathLike | None = None) -> LPIPS | None:
    """Return the LPIPS network a perceptual loss of ``kind`` uses (fine-tuning's ``perceptual``, handed to
    :func:`roodi_toolkit.pipeline.perceptual.perceptual_loss`): None for ``"laplacian"``, and for ``"auto"`` when no
    local weights are usable; else read as :func:`read_lpips` reads it.

    Raises:
        ConfigError: ``kind="lpips"`` and no usable local weights (the message says where it looked).
    """
    if kind == "laplacian":
        return None
    try:
        return read_lpips(path)
    except LPIPSUnavailable as exc:
        if kind == "lpips":
            raise ConfigError(f"perceptual loss 'lpips' unavailable: {exc}") from None
    return None


def _lpips_package_weights() -> Path | None:
    spec = importlib.util.find_spec("lpips")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0]) / "weights" / "v0.1" / "alex.pth"


def _load(path: Path) -> dict[str, Tensor]:
    try:
        check_torch_archive(path, "LPIPS weights")  # a compressed entry would be inflated whole first
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is reported by name
        reason = str(exc) if isinstance(exc, RoodiError) else f"cannot read LPIPS weights ({type(exc).__name__})"
        raise LPIPSUnavailable(reason if reason.startswith(str(path)) else f"{path}: {reason}") from None
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise LPIPSUnavailable(f"{path}: not a state dict")
    return state


def write_lpips(net: LPIPS, path: str | os.PathLike) -> Path:
    """Write ``net``'s weights as one file that :func:`read_lpips` reads (e.g. after ``LPIPS.from_state_dicts``)."""
    return save_checkpoint({k: v for k, v in net.state_dict().items() if k not in ("shift", "scale")}, path)
