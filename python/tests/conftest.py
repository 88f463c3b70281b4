import os
import signal
import sys

import pytest

# Ctrl-C tests send SIGINT to child processes. A run started in the background by a
# non-interactive shell (nohup, `cmd &`) inherits SIGINT ignored, and an ignored signal stays
# ignored across exec, so the children would never see it. Handled here, it is reset to the
# default in every child exec'd from this process, as in a terminal.
signal.signal(signal.SIGINT, signal.default_int_handler)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


@pytest.fixture(autouse=True)
def runtime_dir(tmp_path, monkeypatch):
    """Every test gets its own port directory."""
    monkeypatch.setenv("BASS_RUNTIME_DIR", str(tmp_path))
    return tmp_path
