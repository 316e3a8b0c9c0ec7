import os
from pathlib import Path

import pytest

# Bad logging calls raise instead of warning (shared/rerun-notes.md).
os.environ.setdefault("RERUN_STRICT", "1")

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED.is_dir():
        pytest.skip("../shared/data is not beside the project")
    return SHARED


@pytest.fixture(scope="session")
def sample_session_path() -> Path:
    return ROOT / "sample_data" / "session.mat"
