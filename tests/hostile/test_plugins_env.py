"""Hostile plugins and hostile environment variables.

A plugin that exits (``sys.exit``, ``os._exit``), raises ``KeyboardInterrupt`` or anything else, or blocks while
importing is reported by name; ``plugins`` goes on to list the rest, and a command that does not name it never
imports it. Malformed ``ROODI_PLUGINS``, ``ROODI_THREADS`` and ``ROODI_PLUGIN_TIMEOUT`` give one line naming the
variable, or are ignored where they do not matter.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from .conftest import expect_failure

PLUGIN_BODIES = {
    "sys_exit": "import sys\nsys.exit(3)\n",
    "sys_exit_zero": "raise SystemExit(0)\n",
    "os_exit": "import os\nos._exit(7)\n",
    "keyboard": "raise KeyboardInterrupt\n",
    "blocks": "import time\ntime.sleep(20)\n",
    "raises": "raise RuntimeError('boom at import')\n",
    "recursion": "def f():\n    return f()\nf()\n",
    "syntax": "def (:\n",
    "missing_attr": "X = 1\n",
    "base_exception": "class Weird(BaseException):\n    pass\nraise Weird('odd')\n",
}


@pytest.fixture
def plugin_dir(tmp_path: Path, monkeypatch, request) -> SimpleNamespace:
    """A folder on sys.path holding one module per hostile body, named uniquely per test (a blocked import keeps
    its module lock, so no two tests may share a module)."""
    folder = tmp_path / "plugins"
    folder.mkdir()
    tag = abs(hash(request.node.nodeid)) % 10 ** 8
    for kind, body in PLUGIN_BODIES.items():
        (folder / f"hostile_{kind}_{tag}.py").write_text(body)
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv("ROODI_PLUGIN_TIMEOUT", "1")
    return SimpleNamespace(path=folder, tag=tag)


@pytest.mark.parametrize("kind", list(PLUGIN_BODIES))
def test_plugins_lists_a_hostile_plugin_and_the_rest(kind: str, plugin_dir: SimpleNamespace, run_cli, monkeypatch) -> None:
    module = f"hostile_{kind}_{plugin_dir.tag}"
    monkeypatch.setenv("ROODI_PLUGINS", "inpainters:evil=" + module + ":Evil")
    res = run_cli("plugins", "--json")
    assert res.exit_code == 0, res.stderr
    rows = {r["name"]: r for r in json.loads(res.stdout)}
    assert rows["evil"]["status"] == "error" and rows["evil"]["error"]
    assert rows["torch"]["status"] == "ok"  # the built-ins are still listed and load


@pytest.mark.parametrize("kind", list(PLUGIN_BODIES))
def test_naming_a_hostile_plugin_fails_by_name(kind: str, plugin_dir: SimpleNamespace, run_cli, monkeypatch, world,
                                               tmp_path: Path) -> None:
    module = f"hostile_{kind}_{plugin_dir.tag}"
    monkeypatch.setenv("ROODI_PLUGINS", "renderers:evil=" + module + ":Evil")
    res = run_cli("render", world.ply, tmp_path / "r", "--renderer", "evil", "--orbit", "1", "--size", "8x8", "-q")
    expect_failure(res, 1, "'evil'")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("kind", ["blocks", "os_exit", "keyboard"])
def test_a_hostile_plugin_not_named_is_never_imported(kind: str, plugin_dir: SimpleNamespace, run_cli, monkeypatch, world,
                                                      tmp_path: Path) -> None:
    module = f"hostile_{kind}_{plugin_dir.tag}"
    monkeypatch.setenv("ROODI_PLUGINS", "renderers:evil=" + module + ":Evil")
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q")
    assert res.exit_code == 0, res.stderr
    import sys

    assert module not in sys.modules


MALFORMED = ["garbage", "inpainters", "inpainters:x", "inpainters:x=", "inpainters:x=mod", "inpainters:=m:a",
             "shaders:x=m:a", ":x=m:a", ";;;", "inpainters:x=m:a;bad item", "renderers:numba=nowhere_zz:R"]


@pytest.mark.parametrize("value", MALFORMED)
def test_malformed_roodi_plugins_does_not_break_render(value: str, run_cli, monkeypatch, world,
                                                       tmp_path: Path) -> None:
    monkeypatch.setenv("ROODI_PLUGINS", value)
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q")
    if value.startswith("renderers:numba="):  # it stands in for the default built-in, as documented, and fails by name
        expect_failure(res, 1, "'numba'")
    else:
        assert res.exit_code == 0, res.stderr
    res = run_cli("plugins")
    assert res.exit_code == 0, res.stderr


@pytest.mark.parametrize("value", ["abc", "-1", "0", "nan", "inf", ""])
def test_bad_plugin_timeout_is_named(value: str, run_cli, monkeypatch, world, tmp_path: Path) -> None:
    monkeypatch.setenv("ROODI_PLUGIN_TIMEOUT", value)
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q")
    expect_failure(res, 1, "ROODI_PLUGIN_TIMEOUT")


@pytest.mark.parametrize("value", ["0", "-2", "x", "100000", "1e3", " "])
def test_bad_roodi_threads_is_named(value: str, run_cli, monkeypatch, world, tmp_path: Path) -> None:
    monkeypatch.setenv("ROODI_THREADS", value)
    res = run_cli("render", world.ply, tmp_path / "r", "--orbit", "1", "--size", "8x8", "-q")
    expect_failure(res, 1, "ROODI_THREADS")
    assert not (tmp_path / "r").exists()


def test_threads_is_ignored_by_commands_without_torch(run_cli, monkeypatch, world) -> None:
    monkeypatch.setenv("ROODI_THREADS", "100000")
    assert run_cli("info", world.ply).exit_code == 0


@pytest.mark.parametrize("how", ["env", "option"])
@pytest.mark.parametrize("kind", ["garbage file", "missing file", "folder", "empty file"])
def test_lpips_weights_named_by_the_user_must_load(kind: str, how: str, run_cli, monkeypatch, world,
                                                   tmp_path: Path) -> None:
    weights = tmp_path / "w.pth"
    if kind == "garbage file":
        weights.write_bytes(b"not a checkpoint" * 10)
    elif kind == "folder":
        weights.mkdir()
    elif kind == "empty file":
        weights.write_bytes(b"")
    monkeypatch.delenv("ROODI_LPIPS_WEIGHTS", raising=False)
    extra = ["--lpips-weights", weights] if how == "option" else []
    if how == "env":
        monkeypatch.setenv("ROODI_LPIPS_WEIGHTS", str(weights))
    res = run_cli("evaluate", world.ply, world.gen, "--object", "1", "--json", tmp_path / "s.json", "-q", *extra)
    expect_failure(res, 1, "w.pth")  # not scored silently without LPIPS
    assert not (tmp_path / "s.json").exists()
