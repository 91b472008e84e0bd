"""The first render on a machine compiles the kernels (half a minute): the command line says so, once."""

from __future__ import annotations

import importlib.util
import sys

import numpy as np

from roodi_toolkit import progress
from roodi_toolkit.io.ply import write_ply
from roodi_toolkit.render import cores, fast

from .test_render_cli import ball_cloud

SOURCE = '''
import numba

@numba.njit(cache=True)
def twice(x):
    return 2 * x
'''


def _load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[name]
    return module


def test_uncompiled_until_compiled_here_or_in_the_cache_on_disk(tmp_path):
    path = tmp_path / "jitted.py"
    path.write_text(SOURCE)
    first = _load(path, "roodi_first_compile_a")
    assert cores.uncompiled(first.twice) == ["twice"]
    assert first.twice(3) == 6
    assert cores.uncompiled(first.twice) == []  # compiled in this process
    again = _load(path, "roodi_first_compile_b")  # a fresh dispatcher: numba's index on disk has it
    assert not again.twice.overloads and cores.uncompiled(again.twice) == []
    path.write_text(SOURCE.replace("2 * x", "3 * x"))  # another source: the cache no longer counts
    changed = _load(path, "roodi_first_compile_c")
    assert cores.uncompiled(changed.twice) == ["twice"]
    assert cores.uncompiled(changed.twice, again.twice) == ["twice"]


def test_not_cached_functions_tell_nothing():
    import numba

    @numba.njit
    def plain(x):
        return x

    assert cores.uncompiled(plain) == []


def test_the_notice_is_told_once_and_only_when_compiling(monkeypatch):
    told = []
    means = np.zeros((4, 3), np.float32)
    quats = np.tile(np.float32([1, 0, 0, 0]), (4, 1))
    args = (means, quats, np.zeros((4, 3), np.float32), np.zeros(4, np.float32), np.zeros((4, 3), np.float32), 0,
            fast.make_view(np.eye(4), np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]]), 8, 8))
    monkeypatch.setattr(fast, "uncompiled", lambda *d: ["composite_forward"])
    progress.tell_first_compile(told.append)
    fast.project(*args)
    fast.project(*args)
    assert len(told) == 1 and "compiling the renderer's kernels" in told[0]
    monkeypatch.setattr(fast, "uncompiled", lambda *d: [])
    progress.tell_first_compile(told.append)
    fast.project(*args)  # nothing compiled: nothing told, and the notice dropped
    monkeypatch.setattr(fast, "uncompiled", lambda *d: ["composite_forward"])
    fast.project(*args)
    assert len(told) == 1
    progress.tell_first_compile(told.append)
    progress.tell_first_compile(None)  # None tells nobody
    fast.project(*args)
    assert len(told) == 1


def test_the_command_line_says_so_on_stderr_unless_quiet(tmp_path, run_cli, monkeypatch):
    ply = tmp_path / "ball.ply"
    write_ply(ball_cloud(), ply)
    monkeypatch.setattr(fast, "uncompiled", lambda *d: ["composite_forward"])
    res = run_cli("render", ply, tmp_path / "a", "--orbit", "2", "--size", "16x16")
    assert res.exit_code == 0, res.stderr
    assert res.stderr.count("compiling the renderer's kernels for this machine") == 1
    res = run_cli("render", ply, tmp_path / "b", "--orbit", "1", "--size", "16x16", "-q")
    assert res.exit_code == 0 and "compiling" not in res.stderr
    res = run_cli("render", ply, tmp_path / "c", "--orbit", "1", "--size", "16x16", "--renderer", "torch")
    assert res.exit_code == 0 and "compiling" not in res.stderr
    assert progress.take_first_compile() is None  # a command's notice ends with it
