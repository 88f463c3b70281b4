import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


@pytest.fixture(autouse=True)
def runtime_dir(tmp_path, monkeypatch):
    """Every test gets its own port directory."""
    monkeypatch.setenv("BASS_RUNTIME_DIR", str(tmp_path))
    return tmp_path
