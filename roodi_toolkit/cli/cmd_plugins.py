"""``roodi-toolkit plugins``: every registered renderer, inpainter and segmenter, and whether it loads."""

from __future__ import annotations

import json

import click

from roodi_toolkit.plugins import check_all, short_group


@click.command(epilog="Example:\n\n\b\n  roodi-toolkit plugins\n"
               "  ROODI_PLUGINS='inpainters:mine=my_inpainter:Mine' roodi-toolkit plugins   # my_inpainter.py here\n"
               "  ROODI_PLUGINS='inpainters:mine=src/mine.py:Mine' roodi-toolkit plugins")
@click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON.")
def plugins(as_json: bool) -> None:
    """List plugins with their group, origin and status: installed (it can run here), needs CUDA, needs weights,
    needs a package (with what to do), or error (it does not load, with the error)."""
    statuses = check_all()
    rows = [{"group": short_group(s.spec.group), "name": s.spec.name, "origin": s.spec.origin,
             "target": s.spec.target, "status": s.state, "detail": s.detail, "error": s.error} for s in statuses]
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        click.echo("no plugins registered")
        return
    widths = [max(len(r[k]) for r in rows + [{"group": "group", "name": "name", "origin": "origin"}])
              for k in ("group", "name", "origin")]
    click.echo(f"{'group':<{widths[0]}}  {'name':<{widths[1]}}  {'origin':<{widths[2]}}  status")
    for r in rows:
        status = r["status"] + (f": {r['detail']}" if r["detail"] else "")
        click.echo(f"{r['group']:<{widths[0]}}  {r['name']:<{widths[1]}}  {r['origin']:<{widths[2]}}  {status}")
