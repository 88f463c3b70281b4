"""Fixtures of the client tests: built binaries, a private runtime directory, a live port."""

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import pytest

# Ctrl-C tests send SIGINT to child processes. A run started in the background by a
# non-interactive shell (nohup, `cmd &`) inherits SIGINT ignored, and an ignored signal stays
# ignored across exec, so the children would never see it. Handled here, it is reset to the
# default in every child exec'd from this process, as in a terminal.
signal.signal(signal.SIGINT, signal.default_int_handler)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
TARGET = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
sys.path.insert(0, os.path.join(ROOT, "python"))


@pytest.fixture(scope="session")
def clients_env():
    """Environment for the client processes: CLIENTS_BIN (built by build.sh), a private
    BASS_RUNTIME_DIR."""
    rt = tempfile.mkdtemp(prefix="bass-clients-")
    env = dict(os.environ)
    env["BASS_RUNTIME_DIR"] = rt
    env.setdefault("CLIENTS_BIN", os.path.join(TARGET, "clients"))
    os.environ["BASS_RUNTIME_DIR"] = rt  # for the in-process Python client
    if not os.path.exists(os.path.join(env["CLIENTS_BIN"], "basc")):
        subprocess.run([os.path.join(ROOT, "tests", "clients", "build.sh")], check=True, env=env)
    yield env
    shutil.rmtree(rt, ignore_errors=True)


def broker_available():
    import bass

    return os.access(os.path.join(TARGET, "release", "bassd"), os.X_OK) and bass._lib.has("bass_acquire")


def wait_capturing(name, timeout=10.0):
    import bass

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with bass.Port(name) as p:
                i = p.info()
                if i["state_name"] == "capturing" and i["last_frame_index"] > 0:
                    return
        except bass.BassError:
            pass
        time.sleep(0.05)
    raise RuntimeError(f"port {name} did not start capturing")


@pytest.fixture(scope="session")
def live_port(clients_env):
    """A port receiving the pattern signal at 44100 Hz, 2205 frames per chunk, 20 chunks, paced
    in real time: from bassd's `sim:pattern` device if the broker is built, else sim_writer."""
    import bass

    name = "basc-seed"
    env = clients_env
    if broker_available() and os.environ.get("BASS_CLIENTS_SOURCE") != "sim_writer":
        proc = subprocess.Popen([os.path.join(TARGET, "release", "bassd"), "--name", name], env=env)
        deadline = time.monotonic() + 10
        while True:
            try:
                bass.acquire("sim:pattern", 44100, 2205, 20, 2, broker=name)
                break
            except bass.BassError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise
                time.sleep(0.05)
        source = "bassd sim:pattern"
    else:
        proc = subprocess.Popen([os.path.join(env["CLIENTS_BIN"], "sim_writer"), "--name", name], env=env)
        source = "examples-c/sim_writer"
    try:
        wait_capturing(name)
        print(f"\nlive port {name}: {source}")
        sys.stderr.write(f"[tests/clients] audio source: {source}\n")
        yield name
    finally:
        if source.startswith("bassd"):
            try:
                bass.stop(broker=name)
            except bass.BassError:
                pass
        proc.terminate()
        proc.wait(timeout=10)


@pytest.fixture
def broker(clients_env):
    """A private bassd (name "py") for tests that Acquire and Stop, terminated afterwards."""
    import bass

    if not broker_available():
        pytest.skip("bassd or the control plane is not built")
    p = subprocess.Popen([os.path.join(TARGET, "release", "bassd"), "--name", "py"], env=clients_env,
                         stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while True:
        try:
            bass.status(broker="py")
            break
        except bass.BassError as e:
            assert e.code == bass.BASS_ERR_NO_BROKER
            assert time.monotonic() < deadline and p.poll() is None
            time.sleep(0.05)
    yield "py"
    p.terminate()
    p.wait(timeout=10)
