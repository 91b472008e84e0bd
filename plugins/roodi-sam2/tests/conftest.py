"""Make ``roodi_sam2`` importable from a checkout even when the plugin is not installed."""

import sys
from pathlib import Path

try:
    import roodi_sam2  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
