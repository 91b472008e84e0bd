"""Where the tests find the repository, their own data and the shared real data, whichever folder of tests/ they are
in (a path counted up from a test file's own place changes when the file moves)."""

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEST_DATA = REPO / "tests" / "data"


def _shared_data() -> Path:
    """The shared real data: $ROODI_DATA, else ../shared/data from the repo root (a git worktree one folder further
    down, /work/wt/NAME, has it one level further up)."""
    if os.environ.get("ROODI_DATA"):
        return Path(os.environ["ROODI_DATA"])
    for cand in (REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data"):
        if cand.is_dir():
            return cand
    return REPO.parent / "shared" / "data"


SHARED_DATA = _shared_data()
