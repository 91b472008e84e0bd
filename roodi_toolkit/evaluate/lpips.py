"""LPIPS, importable from here: the network lives in :mod:`roodi_toolkit.lpips`, below both the metrics that score with
it and the fine-tuning (:mod:`roodi_toolkit.pipeline.finetune`) that trains with it; its weight files are read and
written by :mod:`roodi_toolkit.io.lpips_weights` (not re-exported here: evaluation opens no file)."""

from ..lpips import CHANNELS, LPIPS, LPIPSInputError, LPIPSUnavailable  # noqa: F401

__all__ = ["CHANNELS", "LPIPS", "LPIPSInputError", "LPIPSUnavailable"]
