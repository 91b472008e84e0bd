"""The short account of a prune that ``prune`` and ``inspect`` print: counts that add up, one short line each.

What was judged, what goes and why (one line per stage that removed anything), what a test flagged but stays and
why; the details (thresholds, timings, the long reasons) are in the report (``prune --report``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .outliers import PruneReport

STAGE_LABELS = {"nonfinite": "NaN/Inf", "min_opacity": "faint", "box": "outside box", "sphere": "outside sphere"}
"""Names the summary gives stages (others are shown as named)."""


def mode_line(report: "PruneReport") -> str:
    """Return the one-line reason for the mode, e.g. ``"object mode (auto): one connected piece holds 99.74% of the
    Gaussians (>= 98%)"``."""
    cfg = report.config
    if report.mode == "statistical":
        return (f"statistical mode: rule {cfg.get('rule', '?')}, alpha {cfg.get('alpha', float('nan')):g}, "
                f"K {cfg.get('k', '?')} ({cfg.get('distance', 'w2')} distances)")
    largest = report.statistics.get("largest_fraction")
    if cfg.get("mode") != "auto" or largest is None:
        return f"{report.mode} mode (--mode {report.mode})"
    limit = cfg.get("object_fraction", float("nan"))
    if report.mode == "object":
        return f"object mode (auto): one connected piece holds {largest:.2%} of the Gaussians (>= {limit:.0%})"
    return f"scene mode (auto): the largest connected piece holds {largest:.2%} of the Gaussians (< {limit:.0%})"


def summary_lines(report: "PruneReport", *, dry_run: bool = False) -> list[str]:
    """Return the summary: the mode, what was judged, one ``go`` line per stage that removed Gaussians, one ``stay``
    line per group a test flagged that stays (among the kept), and the report's notes.

    The ``go`` counts add up to what goes, and what goes and stays to what was judged (the real biker)::

        object mode (auto): one connected piece holds 100.00% of the Gaussians (>= 98%)
        judged 152,746 Gaussians: 51 go, 152,695 stay
          go    5  detached: pieces apart from the object, of at most 3 Gaussians
          go   46  oversized: 43 bigger than their spacing and neighbours, 3 round blobs of a colour no neighbour has
          stay 58  oversized, of a neighbour's colour (--blob-colour 0: they go)
    """
    n, kept = report.input_count, report.kept_count
    went = n - kept
    verb = ("would go", "would stay") if dry_run else ("go", "stay")
    lines = [mode_line(report), f"judged {n:,} Gaussians: {went:,} {verb[0]}, {kept:,} {verb[1]}"]
    width = max([len(f"{c:,}") for _, c in report.stages] + [len(f"{c:,}") for _, c, _ in report.stayed] + [1])
    for name, count in report.stages:
        if count:
            label = STAGE_LABELS.get(name, name)
            detail = report.details.get(name, "")
            lines.append(f"  go   {count:>{width},}  {label}" + (f": {detail}" if detail else ""))
    for name, count, why in report.stayed:
        if count:
            lines.append(f"  stay {count:>{width},}  {STAGE_LABELS.get(name, name)}, {why}")
    lines += [f"  note: {note}" for note in report.notes]
    return lines
