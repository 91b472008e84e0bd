"""scripts/torch_source.py: where bootstrap.sh gets PyTorch from (the CPU build on a machine without CUDA).

bootstrap.sh ran ``pip install torch==2.13.0``: the CPU build only because this machine's pip finds local CPU wheels;
on a user's machine that is the multi-GB CUDA build. The tests run the helper alone (it installs nothing)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HELPER = ROOT / "scripts" / "torch_source.py"


def source(tmp_path: Path, index: str, gpu: bool | None) -> list[str]:
    """Run the helper with ``index`` as the CPU index and a fake ``nvidia-smi`` (None: none on PATH)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    smi = bin_dir / "nvidia-smi"
    if gpu is not None:
        listing = "GPU 0: NVIDIA H100 (UUID: GPU-x)" if gpu else ""
        smi.write_text(f"#!/bin/sh\necho '{listing}'\nexit {0 if gpu else 9}\n")
        smi.chmod(0o755)
    elif smi.exists():
        smi.unlink()
    env = {**os.environ, "ROODI_TORCH_INDEX": index, "PATH": f"{bin_dir}{os.pathsep}/usr/bin:/bin"}
    out = subprocess.run([sys.executable, str(HELPER), "2.13.0"], env=env, capture_output=True, text=True,
                         timeout=60, check=True)
    return out.stdout.splitlines()


def test_no_gpu_and_a_reachable_cpu_index_gives_the_cpu_build(tmp_path):
    index = tmp_path / "cpu-index"
    (index / "torch").mkdir(parents=True)
    for gpu in (None, False):  # no nvidia-smi, or one that finds no GPU
        lines = source(tmp_path, index.as_uri(), gpu)
        assert lines[1:] == ["--index-url", index.as_uri(), "torch==2.13.0"]
        assert "CPU build from PyTorch's CPU index" in lines[0]


def test_no_gpu_and_no_cpu_index_takes_what_the_machine_offers_and_says_so(tmp_path):
    lines = source(tmp_path, "http://127.0.0.1:9/whl/cpu", None)  # nothing listens there
    assert lines[1:] == ["torch==2.13.0"]
    assert "cannot be reached" in lines[0] and "this machine's pip" in lines[0]
    lines = source(tmp_path, (tmp_path / "missing").as_uri(), None)
    assert lines[1:] == ["torch==2.13.0"]


def test_a_cuda_gpu_keeps_the_default_build(tmp_path):
    index = tmp_path / "cpu-index"
    (index / "torch").mkdir(parents=True)
    lines = source(tmp_path, index.as_uri(), True)
    assert lines[1:] == ["torch==2.13.0"] and "NVIDIA GPU" in lines[0]


def test_bootstrap_uses_the_helper_and_says_which_build_came():
    script = (ROOT / "scripts" / "bootstrap.sh").read_text()
    assert 'scripts/torch_source.py "$TORCH_VERSION"' in script and "the CPU build" in script
    if os.name == "posix":
        assert subprocess.run(["bash", "-n", str(ROOT / "scripts" / "bootstrap.sh")]).returncode == 0
    else:  # pragma: no cover
        pytest.skip("bash syntax check on POSIX only")
