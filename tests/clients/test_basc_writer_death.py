"""basc in periodic mode reports a broker that was killed (the port still says "capturing")
and exits non-zero. Before the fix it printed "got 0" forever."""

import os
import signal
import subprocess
import threading
import time

import pytest

from conftest import TARGET, broker_available


def test_periodic_basc_reports_a_killed_broker(clients_env):
    if not broker_available():
        pytest.skip("bassd is not built")
    env, name = clients_env, "basc-death"
    bassd = subprocess.Popen([os.path.join(TARGET, "release", "bassd"), "--name", name, "--rt-priority", "0"],
                             env=env, stderr=subprocess.DEVNULL)
    bass = [os.path.join(TARGET, "release", "bass"), "--name", name]
    try:
        deadline = time.monotonic() + 20
        while subprocess.run(bass + ["status"], env=env, capture_output=True).returncode != 0:
            assert time.monotonic() < deadline and bassd.poll() is None, "bassd did not come up"
            time.sleep(0.05)
        subprocess.run(bass + ["acquire", "sim:pattern", "--rate", "8000", "--frames", "80", "--chunks", "50"],
                       env=env, check=True, capture_output=True)
        basc = subprocess.Popen([os.path.join(env["CLIENTS_BIN"], "basc"), "--port", name, "--period-ms", "20",
                                 "--check-pattern", "0", "80", "0"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        blocks = threading.Event()

        def read_stdout():
            for line in basc.stdout:
                if line.startswith("A new block"):
                    blocks.set()

        threading.Thread(target=read_stdout, daemon=True).start()
        assert blocks.wait(20), "basc read no block"
        bassd.send_signal(signal.SIGKILL)
        bassd.wait(10)
        try:
            rc = basc.wait(20)
        except subprocess.TimeoutExpired:
            basc.kill()
            basc.wait()
            pytest.fail("basc did not notice that the broker died")
        err = basc.stderr.read()
        assert rc == 4, err
        assert "is gone" in err and "restart bassd" in err, err
    finally:
        if bassd.poll() is None:
            bassd.kill()
            bassd.wait()
