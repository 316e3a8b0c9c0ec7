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


@pytest.fixture(scope="session")
def native_viewer() -> None:
    """The native viewer can render here, else skip naming the package (fail in CI)."""
    from viewer_env import need_native_viewer

    need_native_viewer()


@pytest.fixture(scope="session")
def chromium_path() -> str:
    """Chromium for the web viewer test, else skip naming the package (fail in CI)."""
    from viewer_env import need_chromium

    return need_chromium()


@pytest.fixture(autouse=True)
def _collected_before_hypothesis(request):
    """Hypothesis runs the garbage collector inside the test it drives: a file some earlier test
    left open inside a reference cycle would be freed there, and its ResourceWarning fail that
    test instead of the one that leaked it (CI once failed so on a DataFlash reader's file, since
    fixed). Collected before such a test, without that warning."""
    if getattr(request.function, "is_hypothesis_test", False):
        import gc
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ResourceWarning)
            gc.collect()
    yield
