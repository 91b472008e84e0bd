"""Say where scripts/bootstrap.sh gets PyTorch from, and how: the CPU build on a machine without CUDA.

Usage: python scripts/torch_source.py VERSION

Prints one line saying which source and why, then the ``pip install`` arguments, one per line:

- an NVIDIA GPU answers ``nvidia-smi -L``: ``torch==VERSION`` from the package index as configured (its CUDA build);
- no GPU and PyTorch's CPU index reachable (``$ROODI_TORCH_INDEX``, default https://download.pytorch.org/whl/cpu;
  a ``file://`` index counts when its ``torch/`` folder is there): ``--index-url INDEX torch==VERSION``, the CPU
  build (about 200 MB instead of the CUDA build's several GB of ``nvidia-*`` wheels);
- no GPU and the CPU index unreachable (offline, or a machine with its own mirror): ``torch==VERSION`` from what the
  machine's pip offers; bootstrap.sh then says which build came.

Runs with any Python 3 and only the standard library; installs nothing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request

CPU_INDEX = "https://download.pytorch.org/whl/cpu"


def has_cuda_gpu() -> bool:
    """Return whether ``nvidia-smi -L`` lists a GPU (the driver is there and sees one)."""
    smi = shutil.which("nvidia-smi")
    if smi is None:
        return False
    try:
        out = subprocess.run([smi, "-L"], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return out.returncode == 0 and "GPU" in out.stdout


def index_reachable(index: str, timeout: float = 10.0) -> bool:
    """Return whether the index answers for ``torch`` (an http(s) page, or a ``file://`` folder holding it)."""
    url = index.rstrip("/") + "/torch/"
    if url.startswith("file:"):
        return os.path.isdir(urllib.request.url2pathname(urllib.parse.urlparse(url).path))
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            return 200 <= response.status < 400
    except (OSError, ValueError):
        return False


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: torch_source.py VERSION", file=sys.stderr)
        return 2
    pin = f"torch=={argv[0]}"
    index = os.environ.get("ROODI_TORCH_INDEX", CPU_INDEX)
    if has_cuda_gpu():
        print(f"an NVIDIA GPU is here (nvidia-smi): {pin} from the package index as configured (its CUDA build)")
        print(pin)
    elif index_reachable(index):
        print(f"no CUDA GPU here: {pin} CPU build from PyTorch's CPU index {index}")
        print("--index-url")
        print(index)
        print(pin)
    else:
        print(f"no CUDA GPU here, and PyTorch's CPU index {index} cannot be reached: {pin} from what this machine's "
              "pip offers")
        print(pin)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
