"""``roodi-toolkit batch extract``: every object of a scene as an item of a batch (the scene trained and distilled
once). Its own module: it imports the pipeline (torch), which ``batch prune``, ``convert`` and ``info`` never need."""

from __future__ import annotations

from typing import Any

import click

from roodi_toolkit.batch.items import Item
from roodi_toolkit.batch.runner import run_batch
from roodi_toolkit.cli.cmd_batch import report
from roodi_toolkit.cli.cmd_extract import extract_config_from_options, extract_options
from roodi_toolkit.cli.common import progress_factory, quiet_option
from roodi_toolkit.cli.settings import SettingsCommand
from roodi_toolkit.run.extract import prepare_scene


@click.command("extract", cls=SettingsCommand)
@click.argument("data_dir", type=str)
@click.argument("out", type=str)
@click.option("--object", "object_ids", multiple=True, required=True, metavar="ID|all",
              help="An object to extract (repeat), or 'all' for every object of the distillation.")
@click.option("--jobs", "-j", type=click.IntRange(1, 256), default=1, show_default=True,
              help="Worker processes on this machine (one object each at a time); with --ray local, its CPUs.")
@click.option("--ray", "ray_address", default=None, metavar="ADDRESS",
              help="Run the objects as Ray tasks on this cluster, or 'local' to start Ray here.")
@click.option("--results", default=None, help="The JSON-lines results file [OUT/results.jsonl].")
@click.option("--rerun", is_flag=True, help="Extract every object again, even those an earlier run finished; "
              "without it a scene, distillation or object made with other settings is not replaced.")
@extract_options
@quiet_option
def batch_extract(data_dir: str, out: str, object_ids: tuple[str, ...], jobs: int, ray_address: str | None,
                  results: str | None, rerun: bool, model_dir: str | None, distill_dir: str | None, quiet: bool,
                  **stage_options: Any) -> None:
    """Extract objects of DATA_DIR into OUT/object_<ID>/: the scene is trained and distilled once (or taken from
    --model and --distill), then every object is an item of the batch."""
    config = extract_config_from_options(**stage_options)
    progress = progress_factory(quiet)
    prepared = prepare_scene(data_dir, out, model_dir=model_dir, distill_dir=distill_dir, config=config,
                             progress=progress, replace_changed=rerun)
    ids = prepared.object_ids(object_ids)
    items = [Item(f"object_{i}", data_dir, str(prepared.out / f"object_{i}" / "object.ply"), {"object": i})
             for i in ids]
    results = results or str(prepared.out / "results.jsonl")
    settings = {"config": config, "out": str(prepared.out), "model_dir": model_dir, "distill_dir": distill_dir,
                "replace_changed": rerun}
    del prepared  # the workers load the scene themselves
    summary = run_batch("extract", items, results, settings=settings, jobs=jobs, ray=ray_address, rerun=rerun,
                        progress=progress)
    report("extract", summary, results)
