"""``roodi-toolkit batch``: prune, convert or describe a whole collection of splats, on a process pool or on Ray."""

from __future__ import annotations

import glob
from pathlib import Path
from typing import Any

import click

from roodi_toolkit.batch.items import collect_items, join_output
from roodi_toolkit.batch.outputs import is_url
from roodi_toolkit.batch.runner import run_batch
from roodi_toolkit.batch.tasks import check_items, settings_for
from roodi_toolkit.cli.common import progress_factory, quiet_option
from roodi_toolkit.cli.main import LazyGroup
from roodi_toolkit.cli.prune_options import (effective_mode, prune_config_from_options, prune_mode_options,
                                             prune_options)
from roodi_toolkit.errors import InputError
from roodi_toolkit.io.files import check_output_dir

EPILOG = """\b
SOURCE is a folder (every .ply, .compressed.ply, .spz, .splat, .ksplat, .sog and meta.json in it, recursively), a
quoted glob ("captures/**/*.ply"), or a manifest: a CSV with an 'input' column (optional 'output' and option
columns, e.g. 'k') or JSON lines {"input": ..., "output": ..., "options": {...}}.
OUT is a local folder or an fsspec URL (s3://bucket/prefix, gs://..., where the driver is installed).

\b
Examples:
  roodi-toolkit batch prune captures/ clean/ --jobs 2
  roodi-toolkit batch prune "captures/**/*.ply" clean/ --rule paper --k 32
  roodi-toolkit batch prune manifest.csv s3://my-bucket/clean --ray ray://head:10001
  roodi-toolkit batch convert captures/ web/ --to .spz --ray local
  roodi-toolkit batch info captures/ info/
  roodi-toolkit batch extract scenes/kitchen out/ --object all --jobs 2

Results go to OUT/results.jsonl (or --results: a new file or one a batch wrote), one line per item as it finishes;
a re-run skips the items whose output exists and whose input and settings are unchanged, so a killed batch resumes
where it stopped. A file already at an item's output is replaced only if an earlier run of the batch wrote it, or
with --overwrite.
"""

CONVERT_SUFFIXES = (".ply", ".compressed.ply", ".spz")


def _common(func: Any) -> Any:
    for option in reversed([
        click.argument("source", type=str),
        click.argument("out", type=str),
        click.option("--jobs", "-j", type=click.IntRange(1, 256), default=1, show_default=True,
                     help="Worker processes on this machine (one item each at a time); with --ray local, its CPUs."),
        click.option("--ray", "ray_address", default=None, metavar="ADDRESS",
                     help="Run as Ray tasks on this cluster (ray://host:10001, auto), or 'local' to start Ray here."),
        click.option("--results", default=None, help="The JSON-lines results file [OUT/results.jsonl]."),
        click.option("--rerun", is_flag=True, help="Run every item again, even those an earlier run finished."),
        click.option("--overwrite", is_flag=True,
                     help="Replace files at the items' outputs that this batch did not write (outputs an earlier run "
                          "of it wrote, as its results file records, are replaced without it)."),
        quiet_option,
    ]):
        func = option(func)
    return func


# extract runs the whole pipeline (torch): its module is imported only when it runs, so that prune, convert and info
# of splat files start as light as the single-file commands
@click.group(cls=LazyGroup, lazy={"extract": "roodi_toolkit.cli.cmd_batch_extract:batch_extract"}, epilog=EPILOG)
def batch() -> None:
    """Run prune, convert or info over many splat files, or extract every object of a scene: one item per worker,
    results as JSON lines."""


def _run(task: str, source: str, out: str, suffix: str | None, settings: dict[str, Any], jobs: int,
         ray_address: str | None, results: str | None, rerun: bool, overwrite: bool, quiet: bool) -> None:
    if not is_url(out):  # a folder (made if missing, added to if not), never a file nor inside the source
        check_output_dir(out, overwrite=True, inputs=[source])
    items = collect_items(source, out, suffix=suffix)
    check_items(task, items, settings, source)
    if results is None:
        results = join_output(out, "results.jsonl")
        if is_url(results):
            raise click.BadParameter("with a URL as OUT, give a local --results file", param_hint="--results")
    elif is_url(results):
        raise click.BadParameter("must be a local file", param_hint="--results")
    summary = run_batch(task, items, results, settings=settings, jobs=jobs, ray=ray_address, rerun=rerun,
                        overwrite=overwrite, inputs=[source] if not glob_pattern(source) else [],
                        progress=progress_factory(quiet))
    report(task, summary, results)


def glob_pattern(source: str) -> bool:
    """Whether SOURCE is a glob pattern rather than a folder or a file."""
    return not Path(source).exists() and glob.has_magic(source)


def report(task: str, summary: Any, results: str) -> None:
    """Echo the batch's outcome; raise (exit 1) if any item failed."""
    failed = [line for line in summary.lines if line["status"] == "failed"]
    for line in failed[:10]:
        click.echo(f"failed: {line['item']}: {line.get('error')}", err=True)
    if len(failed) > 10:
        click.echo(f"... and {len(failed) - 10} more failures (see {results})", err=True)
    click.echo(f"{task}: {summary.ok} done, {summary.skipped} unchanged and skipped, {summary.failed} failed of "
               f"{summary.total} items in {summary.seconds:.1f} s; results in {results}")
    if failed:
        raise InputError(f"{len(failed)} of {summary.total} items failed; their lines in {results} say why")


@batch.command("prune", epilog=EPILOG)
@_common
@prune_options
@prune_mode_options
def batch_prune(source: str, out: str, jobs: int, ray_address: str | None, results: str | None, rerun: bool,
                overwrite: bool, quiet: bool, mode: str, **prune_kw: Any) -> None:
    """Prune every splat of SOURCE into OUT (as PLY), with the prune command's options (per item from a manifest)."""
    config = prune_config_from_options(mode=effective_mode(mode), **prune_kw)
    _run("prune", source, out, ".ply", settings_for("prune", prune_config=config), jobs, ray_address, results, rerun,
         overwrite, quiet)


@batch.command("convert", epilog=EPILOG)
@_common
@click.option("--to", "suffix", type=click.Choice(CONVERT_SUFFIXES), required=True,
              help="Output format, by extension.")
def batch_convert(source: str, out: str, jobs: int, ray_address: str | None, results: str | None, rerun: bool,
                  overwrite: bool, quiet: bool, suffix: str) -> None:
    """Convert every splat of SOURCE into OUT in the format of --to."""
    _run("convert", source, out, suffix, {"to": suffix}, jobs, ray_address, results, rerun, overwrite, quiet)


@batch.command("info", epilog=EPILOG)
@_common
def batch_info(source: str, out: str, jobs: int, ray_address: str | None, results: str | None, rerun: bool,
               overwrite: bool, quiet: bool) -> None:
    """Describe every splat of SOURCE (count, SH degree, bounds, opacities, scales, bad rows) as OUT/<name>.json."""
    _run("info", source, out, ".json", {}, jobs, ray_address, results, rerun, overwrite, quiet)
