"""Doctest namespace: examples in docstrings may use ``np`` without importing it. PyTorch runs on one thread, as
the CLI does by default (``$ROODI_THREADS`` changes both): two threads on a busy 2-core machine are ~10x slower."""

import os

import numpy as np
import pytest
import torch

torch.set_num_threads(int(os.environ.get("ROODI_THREADS", "1")))


@pytest.fixture(autouse=True)
def _doctest_namespace(doctest_namespace):
    doctest_namespace["np"] = np
