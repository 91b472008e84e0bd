import pytest

from roodi_toolkit.errors import OutputError, RoodiError
from roodi_toolkit.io.files import atomic_path, check_output, prepare_output_dir, read_json, write_json


def test_atomic_path_replaces_only_on_success(tmp_path):
    dest = tmp_path / "out.txt"
    dest.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(dest) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert dest.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
    with atomic_path(dest) as tmp:
        tmp.write_text("new")
    assert dest.read_text() == "new"


def test_check_output_policy(tmp_path):
    src = tmp_path / "in.ply"
    src.write_text("x")
    with pytest.raises(OutputError, match="same file as the input"):
        check_output(src, overwrite=True, inputs=[src])
    with pytest.raises(OutputError, match="--overwrite"):
        check_output(src, overwrite=False)
    assert check_output(src, overwrite=True) == src
    with pytest.raises(OutputError, match="does not exist"):
        check_output(tmp_path / "nope" / "o.ply", overwrite=False)
    with pytest.raises(OutputError, match="is a folder"):
        check_output(tmp_path, overwrite=True)


def test_output_dir_policy(tmp_path):
    out = tmp_path / "o"
    prepare_output_dir(out, overwrite=False)
    (out / "f").write_text("x")
    with pytest.raises(OutputError, match="not empty"):
        prepare_output_dir(out, overwrite=False)
    prepare_output_dir(out, overwrite=True)


def test_json_roundtrip_and_errors(tmp_path):
    import numpy as np

    p = write_json({"a": np.float32(1.5), "b": np.arange(3)}, tmp_path / "a.json")
    assert read_json(p) == {"a": 1.5, "b": [0, 1, 2]}
    (tmp_path / "bad.json").write_text("{oops")
    with pytest.raises(RoodiError, match="malformed"):
        read_json(tmp_path / "bad.json")
    with pytest.raises(RoodiError, match="not found"):
        read_json(tmp_path / "none.json")


def test_figures_leave_the_matplotlib_backend_alone(tmp_path):
    import matplotlib

    from roodi_toolkit.io.files import save_figure
    from roodi_toolkit.viz.figures import new_figure

    before = matplotlib.get_backend()
    fig, (a, b) = new_figure(1, 2, figsize=(4, 2))
    a.plot([0, 1], [1, 0])
    path = save_figure(fig, tmp_path / "f.png")
    assert path.stat().st_size > 1000 and matplotlib.get_backend() == before


def test_outputs_follow_the_umask_not_mkstemps_0600(tmp_path):
    import os

    from roodi_toolkit.io.files import write_json

    old = os.umask(0o022)
    try:
        write_json({"a": 1}, tmp_path / "a.json")
        assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o644
        os.umask(0o077)
        write_json({"a": 1}, tmp_path / "b.json")
        assert (tmp_path / "b.json").stat().st_mode & 0o777 == 0o600
    finally:
        os.umask(old)


def test_a_signal_during_the_removal_of_a_temporary_file_waits_for_it(tmp_path, monkeypatch):
    """Ctrl-C unwinds a write, and a second signal (the batch's SIGTERM to its workers) comes as the temporary file
    is being removed: the removal finishes first, then the signal's handler raises (a nested writer's temporary file
    was left behind in a batch stopped by Ctrl-C, 1 run in many)."""
    import os
    import signal
    from pathlib import Path

    from roodi_toolkit import signals

    class Stopped(Exception):
        pass

    def stop(signum, frame):
        raise Stopped

    real_unlink = Path.unlink

    def unlink(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGUSR1)  # its handler runs at the next bytecode, before the file is gone
        return real_unlink(self, *args, **kwargs)

    previous = signal.signal(signal.SIGUSR1, signals.deferrable(stop))
    try:
        monkeypatch.setattr(Path, "unlink", unlink)
        with pytest.raises(Stopped):
            with atomic_path(tmp_path / "out.ply") as tmp:
                tmp.write_bytes(b"ply")
                raise KeyboardInterrupt
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert list(tmp_path.iterdir()) == []
