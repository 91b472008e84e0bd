"""LPIPS, importable from here as before: the network lives in :mod:`roodi_toolkit.lpips`, below both the metrics that
score with it and the fine-tuning (:mod:`roodi_toolkit.pipeline.finetune`) that trains with it."""

from ..lpips import (ALEXNET_CHECKPOINT, CHANNELS, ENV_WEIGHTS, LPIPS, LPIPSInputError, LPIPSUnavailable,  # noqa: F401
                     save_combined)

__all__ = ["ALEXNET_CHECKPOINT", "CHANNELS", "ENV_WEIGHTS", "LPIPS", "LPIPSInputError", "LPIPSUnavailable",
           "save_combined"]
