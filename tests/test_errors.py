"""Tests of the error kinds and of how the CLI reports each one."""

from __future__ import annotations

import errno

import pytest

from roodi_toolkit import write_ply
from roodi_toolkit.errors import (CloudError, ConfigError, DatasetError, EnvironmentProblemError, InputError,
                                  OutputError, PlyError, PluginError, RoodiError, UnsupportedFormatError,
                                  missing_library_problem, os_error_problem)
from roodi_toolkit.io.files import atomic_path, prepare_output_dir

from .conftest import make_cloud


def test_kinds_form_one_tree():
    for cls in (PlyError, CloudError, DatasetError, ConfigError, OutputError, UnsupportedFormatError):
        assert issubclass(cls, InputError)
    for cls in (InputError, PluginError, EnvironmentProblemError):
        assert issubclass(cls, RoodiError)
    assert not issubclass(PluginError, InputError) and not issubclass(EnvironmentProblemError, InputError)


@pytest.mark.parametrize("code, words", [(errno.ENOSPC, "disk is full"), (errno.EROFS, "read-only"),
                                         (errno.EACCES, "permission denied")])
def test_os_errors_of_the_machine_are_named(code, words):
    message = os_error_problem(OSError(code, "strerror"), "out/x.ply")
    assert message.startswith("out/x.ply: ") and words in message and "; " in message


def test_other_os_errors_are_not_environment_problems():
    assert os_error_problem(FileNotFoundError(errno.ENOENT, "No such file")) is None


def test_missing_system_library_names_the_debian_package():
    exc = ImportError("libGL.so.1: cannot open shared object file: No such file or directory")
    message = missing_library_problem(exc)
    assert "libGL.so.1" in message and "apt-get install libgl1" in message
    assert missing_library_problem(ImportError("No module named 'foo'")) is None


def test_atomic_path_turns_a_full_disk_into_an_environment_problem(tmp_path):
    dest = tmp_path / "out.bin"
    with pytest.raises(EnvironmentProblemError, match="disk is full"):
        with atomic_path(dest):
            raise OSError(errno.ENOSPC, "No space left on device")
    assert not dest.exists() and not list(tmp_path.iterdir())


def test_output_folder_in_a_read_only_place(tmp_path, monkeypatch):
    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr("pathlib.Path.mkdir", refuse)
    with pytest.raises(EnvironmentProblemError, match="read-only"):
        prepare_output_dir(tmp_path / "new", overwrite=False)


def test_cli_reports_a_full_disk_as_an_environment_problem(tmp_path, run_cli, monkeypatch):
    src = tmp_path / "in.ply"
    write_ply(make_cloud(50, seed=1), src)

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("roodi_toolkit.io.splat.write_ply", full)  # the name write_cloud calls
    res = run_cli("prune", src, tmp_path / "out.ply")
    assert res.exit_code == 1
    assert "environment problem" in res.stderr and "disk is full" in res.stderr
    assert "unexpected" not in res.stderr


def test_cli_reports_a_missing_system_library(tmp_path, run_cli, monkeypatch):
    src = tmp_path / "in.ply"
    write_ply(make_cloud(20, seed=2), src)

    def no_lib(*args, **kwargs):
        raise ImportError("libgomp.so.1: cannot open shared object file: No such file or directory")

    monkeypatch.setattr("roodi_toolkit.io.splat.read_ply", no_lib)  # the name read_cloud calls
    res = run_cli("info", src)
    assert res.exit_code == 1
    assert "environment problem" in res.stderr and "apt-get install libgomp1" in res.stderr
    assert "unexpected" not in res.stderr


def test_input_errors_still_exit_1(tmp_path, run_cli):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply")
    res = run_cli("info", bad)
    assert res.exit_code == 1 and res.stderr.startswith("error: ")
    assert "environment problem" not in res.stderr and "unexpected" not in res.stderr


def test_an_unsupported_ply_variant_is_both_a_ply_error_and_an_unsupported_format(tmp_path):
    from roodi_toolkit import read_ply

    path = tmp_path / "odd.ply"
    path.write_bytes(b"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nproperty float x\nend_header\n")
    with pytest.raises(UnsupportedFormatError, match="unsupported format") as info:
        read_ply(path)
    assert isinstance(info.value, PlyError)
