"""SAM2 segmenter plugin for roodi-toolkit: registers ``sam2`` under ``roodi_toolkit.segmenters``."""

from .segmenter import SAM2Segmenter, frame_order

__all__ = ["SAM2Segmenter", "frame_order"]
