"""The MEX gateway and the Bass class in GNU Octave (built with mkoctfile --mex)."""

import os
import pty
import re
import select
import shutil
import subprocess
import time

import numpy as np
import pytest

from conftest import ROOT, TARGET, broker_available
from test_basc_seed import SEED_EXAMPLE_1

pytestmark = pytest.mark.skipif(shutil.which("octave") is None, reason="GNU Octave is not installed")

PROMPT = rb"octave:\d+> "
MEXDIR = os.path.join(TARGET, "clients", "matlab")


@pytest.fixture(scope="module")
def mexdir(clients_env):
    subprocess.run([os.path.join(ROOT, "matlab", "build_octave.sh"), MEXDIR], check=True, env=clients_env)
    return MEXDIR


def octave(env, code, timeout=120, cwd=None):
    p = subprocess.run(["octave", "--no-gui", "--norc", "-q", "--path", MEXDIR, "--path",
                        os.path.join(ROOT, "tests", "clients", "octave"), "--eval", code],
                       env=env, capture_output=True, text=True, timeout=timeout, cwd=cwd)
    return p.returncode, p.stdout, p.stderr


def test_mex_gateway_unit_assertions(mexdir, clients_env, tmp_path):
    env = dict(clients_env, BASS_RUNTIME_DIR=str(tmp_path))
    rc, out, err = octave(env, "test_mex")
    assert rc == 0, out + err
    assert "test_mex: all assertions passed" in out


def test_octave_replays_the_seed_session_example_1(mexdir, clients_env, live_port):
    """Acquire (through the broker when it runs), then GetBlocks(1, 88200, 0) from the Bass class."""
    acquire = ""
    if broker_available() and os.environ.get("BASS_CLIENTS_SOURCE") != "sim_writer":
        acquire = ("bass.Acquire('-a', 'sim:pattern', 44100, 2205, 20); pause(0.3); s = bass.Status(); "
                   "assert(strcmp(s.state, 'capturing') && s.sampleRate == 44100 && s.nFramesPerChunk == 2205);")
    code = f"bass = Bass('{live_port}'); {acquire} pause(0.3); bass.GetBlocks(1, 88200, 0);"
    outs = []
    for _ in range(5):  # a run whose periods saw other than 5 chunks is retried (see test_basc_seed)
        rc, out, err = octave(clients_env, code)
        assert rc == 0, out + err
        lines = [l for l in out.splitlines() if l.startswith(("Requested", "!!Lost", "A new block"))]
        got = [int(m.group(1)) for m in map(re.compile(r"got +(\d+)\.").search, lines) if m]
        assert sum(got) == 88200 and lines[-1] == "A new block is ready to be processed."
        assert all(g % 2205 == 0 or g == 88200 - sum(got[:-1]) for g in got)
        if "\n".join(lines) + "\n" == SEED_EXAMPLE_1:
            print(out)
            return
        outs.append(out)
    pytest.fail("no Octave run printed the seed's example 1 exactly:\n" + "\n---\n".join(outs))


def test_getblocks_without_an_output_prints_the_seed_lines_only(mexdir, clients_env, live_port):
    """The seed's `bass.GetBlocks(1, 4410, 0)`, without a semicolon: the BASC lines and no
    `ans =` with the block's 4410 x 2 samples; with an output the block comes back."""
    code = (f"bass = Bass('{live_port}');\nbass.GetBlocks(1, 4410, 0)\n"
            "b = bass.GetBlocks(1, 2205, 0); disp(size(b)); disp(class(b));")
    rc, out, err = octave(clients_env, code)
    assert rc == 0, out + err
    assert "ans" not in out and len(out.splitlines()) < 10, out
    assert "A new block is ready to be processed." in out
    assert re.search(r"2205\s+2\s+int32", out), out


def test_ctrl_c_during_wait_returns_to_the_octave_prompt(mexdir, clients_env, live_port):
    """Interactive Octave on a pseudo-terminal: Ctrl-C during an endless Wait gives the prompt back,
    and the session still works."""
    pid, fd = pty.fork()
    if pid == 0:
        os.environ.update(clients_env)
        os.execvp("octave", ["octave", "--no-gui", "--norc", "-q", "--no-history", "--path", MEXDIR])
    buf = b""

    def read_until(pattern, timeout):
        nonlocal buf
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if re.search(pattern, buf):
                return True
            r, _, _ = select.select([fd], [], [], 0.1)
            if r:
                try:
                    buf += os.read(fd, 4096)
                except OSError:
                    break
        return bool(re.search(pattern, buf))

    try:
        assert read_until(PROMPT, 30), buf
        os.write(fd, f"h = bass_mex('Open', '{live_port}'); disp(['WAIT' 'ING']); bass_mex('Wait', h, uint64(2)^60)\n".encode())
        assert read_until(rb"WAITING", 10), buf  # printed by the command, not its echo
        time.sleep(0.5)
        buf = b""
        os.write(fd, b"\x03")  # Ctrl-C
        assert read_until(PROMPT, 10), f"no prompt after Ctrl-C: {buf!r}"
        os.write(fd, b"disp(6 * 7); x = bass_mex('Info', h); disp(upper(x.state))\n")
        assert read_until(rb"42\s+CAPTURING", 10), buf
        os.write(fd, b"exit\n")
        _, status = os.waitpid(pid, 0)
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
        pid = 0
    finally:
        if pid:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
        os.close(fd)


def test_octave_control_plane_and_pattern_reads_through_a_broker(mexdir, clients_env, broker):
    code = f"""
    b = Bass('{broker}');
    d = b.ListDevices();
    assert(any(strcmp(d(:, 1), 'sim:pattern')));
    epoch = b.Acquire('sim:pattern', 48000, 480, 10);
    assert(isa(epoch, 'uint64') && epoch >= 1);
    lfi = b.Wait(uint64(960), 5);
    [l, r, nfr, n, loss] = b.getAudioData(960, uint64(1));
    f = (1:960).';
    assert(n == 960 && loss == 0 && nfr == 961);
    assert(isequal(l, int32(f * 64)) && isequal(r, int32(f * 64 + 1)));
    s = b.Status();
    assert(strcmp(s.state, 'capturing') && s.sampleRate == 48000 && s.epoch == epoch);
    assert(isempty(s.replica));  % a bassd is no mirror's replica
    b.Stop();
    try
      b.Wait(uint64(2)^40, 5);
      error('test:fail', 'no error');
    catch e
      assert(strcmp(e.identifier, 'bass:stopped'), e.identifier);
    end
    try
      b.Acquire('no-such-device-xyz', 44100, 2205, 20);
      error('test:fail', 'no error');
    catch e
      assert(strcmp(e.identifier, 'bass:broker'), e.identifier);
    end
    disp('control plane ok');
    """
    rc, out, err = octave(clients_env, code)
    assert rc == 0, out + err
    assert "control plane ok" in out


def test_mex_acquires_several_devices_with_a_channel_count_each(mexdir, clients_env, broker):
    """Acquire with a cell array of devices (master first) and one channel count per device:
    the port has their sum, Status.devices gives each one's first channel and count; a count
    list of the wrong length, a bad count and an empty device list are bass:badArgument; the
    Bass class does the same with Acquire's fifth argument, and Devices() gives the rows."""
    code = f"""
    bass_mex('Acquire', {{'sim:field', 'sim:field?ppm=87&ch=2'}}, 48000, 480, 100, [2 1], '{broker}');
    s = bass_mex('Status', '{broker}');
    assert(s.channels == 3, sprintf('%d channels', s.channels));
    assert(numel(s.devices) == 2);
    m = s.devices{{1}}; f = s.devices{{2}};
    assert(strcmp(m.role, 'master') && m.firstChannel == 0 && m.channels == 2);
    assert(strcmp(f.role, 'follower') && f.firstChannel == 2 && f.channels == 1);
    assert(strcmp(f.name, 'sim:field?ppm=87&ch=2'), f.name);
    h = bass_mex('Open', '{broker}');
    info = bass_mex('Info', h);
    assert(info.channels == 3);
    bass_mex('Close', h);
    expect_error('bass:badArgument', @() bass_mex('Acquire', {{'sim:field', 'sim:field'}}, 48000, 480, 100, [2 1 1], '{broker}'));
    expect_error('bass:badArgument', @() bass_mex('Acquire', {{'sim:field', 'sim:field'}}, 48000, 480, 100, [2 1.5], '{broker}'));
    expect_error('bass:badArgument', @() bass_mex('Acquire', {{}}, 48000, 480, 100, 2, '{broker}'));
    expect_error('bass:badArgument', @() bass_mex('Acquire', {{'sim:field', 42}}, 48000, 480, 100, 2, '{broker}'));
    % one count for every device still works
    bass_mex('Acquire', {{'sim:field', 'sim:field?ppm=-143'}}, 48000, 480, 100, 2, '{broker}');
    s = bass_mex('Status', '{broker}');
    assert(s.channels == 4 && s.devices{{2}}.firstChannel == 2 && s.devices{{2}}.channels == 2);
    % the Bass class: a device list and a count per device, and its Devices()
    b = Bass('{broker}');
    b.Acquire({{'sim:field', 'sim:field?ppm=87&ch=2'}}, 48000, 480, 100, [2 1]);
    d = b.Devices();
    assert(numel(d) == 2 && d{{2}}.channels == 1 && strcmp(d{{2}}.role, 'follower'));
    assert(isfield(d{{2}}, 'xruns') && isfield(d{{2}}, 'ratioPpm') && isfield(d{{2}}, 'locks'));
    expect_error('bass:badArgument', @() b.Acquire('sim:field', 48000, 480, 100, 2, 7));
    clear b;
    bass_mex('Stop', '{broker}');
    disp('several devices ok');
    """
    rc, out, err = octave(clients_env, code)
    assert rc == 0, out + err
    assert "several devices ok" in out


def test_mex_edge_cases_timeouts_ranges_and_handles_across_unloads(mexdir, clients_env, tmp_path):
    """tests/clients/octave/test_mex_edges.m: fractional/zero/negative/NaN/Inf Wait timeouts,
    bass:badArgument for every out-of-range or non-numeric argument, handles unique across
    `clear bass_mex` / `clear functions` with nothing leaked, a Bass object kept across them."""
    env = dict(clients_env, BASS_RUNTIME_DIR=str(tmp_path))
    rc, out, err = octave(env, "test_mex_edges", timeout=60)
    assert rc == 0, out + err
    assert "test_mex_edges: all assertions passed" in out


def test_every_read_path_reports_a_broker_restart_and_a_dead_broker(mexdir, clients_env, tmp_path):
    """A Bass object and raw handles opened before a broker restart: getAudioData (and the raw
    GetAudioData/GetAudioDataMulti) raise bass:restarted once the new broker acquires, instead of
    returning n = 0 forever; the Bass object then reads the new port; after a SIGKILL of the
    broker they raise bass:writerGone."""
    if not broker_available():
        pytest.skip("bassd or the control plane is not built")
    env = dict(clients_env, BASS_RUNTIME_DIR=str(tmp_path))
    bassd = os.path.join(TARGET, "release", "bassd")
    pidfiles = [tmp_path / "bassd1.pid", tmp_path / "bassd2.pid"]
    # The brokers are started from Octave's shell (orphans, reaped by init: a killed one is gone,
    # not a zombie that `kill -0` still finds).
    code = f"""
    function pid = start(pidfile)
      system(sprintf('{bassd} --name rs >/dev/null 2>&1 & echo $! > %s', pidfile));
      pid = str2double(fileread(pidfile));
    end
    function up()
      for k = 1:200
        try
          bass_mex('Status', 'rs'); return;
        catch
          pause(0.05);
        end
      end
      error('test:fail', 'broker rs did not come up');
    end
    function gone(pid)
      system(sprintf('kill -%s %d; while kill -0 %d 2>/dev/null; do sleep 0.05; done', 'TERM', pid, pid));
    end
    first = start('{pidfiles[0]}');
    up();
    bass_mex('Acquire', 'sim:pattern', 48000, 480, 10, 2, 'rs');
    b = Bass('rs');
    b.Wait(uint64(960), 10);
    [l, r, nfr, n] = b.getAudioData(960, uint64(1));
    assert(n == 960 && nfr == 961);
    raw = bass_mex('Open', 'rs');
    gone(first);
    second = start('{pidfiles[1]}');
    up();
    bass_mex('Acquire', 'sim:pattern', 48000, 480, 10, 2, 'rs');
    expect_error('bass:restarted', @() b.getAudioData(960, uint64(2)^40));
    expect_error('bass:restarted', @() bass_mex('GetAudioData', raw, 960, uint64(2)^40));
    expect_error('bass:restarted', @() bass_mex('GetAudioDataMulti', raw, 960, uint64(2)^40));
    % the Bass object reads the new acquisition from frame 1
    b.Wait(uint64(480), 10);
    [l, r, nfr, n] = b.getAudioData(480, uint64(1));
    assert(n == 480 && isequal(l, int32((1:480).' * 64)));
    raw2 = bass_mex('Open', 'rs');
    system(sprintf('kill -KILL %d', second));
    pause(0.5);
    expect_error('bass:writerGone', @() b.getAudioData(480, uint64(2)^40));
    expect_error('bass:writerGone', @() bass_mex('GetAudioData', raw2, 480, uint64(2)^40));
    expect_error('bass:writerGone', @() bass_mex('GetAudioDataMulti', raw2, 480, uint64(2)^40));
    disp('restart ok');
    """
    script = tmp_path / "restart_paths.m"
    script.write_text("1;\n" + code)
    try:
        rc, out, err = octave(env, f"source('{script}')", timeout=90)
    finally:
        for f in pidfiles:
            try:
                os.kill(int(f.read_text()), 9)
            except (OSError, ValueError):
                pass
    assert rc == 0, out + err
    assert "restart ok" in out


def test_info_shows_every_header_state_by_its_name(mexdir, clients_env):
    """Info's state text is the header constant's name for every state a writer can set
    (before: BASS_STATE_STARTING showed as "unknown")."""
    import bass

    header = open(os.path.join(ROOT, "include", "bass.h")).read()
    states = {m.group(1).lower(): int(m.group(2))
              for m in re.finditer(r"#define BASS_STATE_(\w+) (\d+)\b", header)}
    settable = {k: v for k, v in states.items() if k != "superseded"}  # only a new acquisition
    assert "starting" in settable, states
    # The Python writer and Octave share clients_env's runtime directory.
    with bass.Writer("mex-states", frames_per_chunk=4, chunks_on_port=3) as w:
        for name, value in settable.items():
            w.set_state(value)
            rc, out, err = octave(clients_env, "h = bass_mex('Open', 'mex-states'); i = bass_mex('Info', h); "
                                       "printf('state=%s\\n', i.state); bass_mex('Close', h);")
            assert rc == 0, out + err
            assert f"state={name}\n" in out, (name, out, err)


def header_fields(struct):
    header = open(os.path.join(ROOT, "include", "bass.h")).read()
    end = header.index("} " + struct + ";")
    body = re.sub(r"//[^\n]*", "", header[header.rindex("{", 0, end) + 1:end])
    return re.findall(r"(\w+)\s*(?:\[[^\]]*\])?\s*;", body)


def test_octave_info_has_every_field_and_chunk_info_shows_late_gap_and_upstream_loss(mexdir, clients_env):
    """A replica-like port made by the Python writer (a start at frame 9, a LATE chunk, 8 frames
    lost upstream, a GAP chunk): Info has one field per bass_port_info member and shows
    lostUpstreamFrames; ChunkInfo gives the timestamps and one logical per flag."""
    import bass

    n_info, n_chunk = len(header_fields("bass_port_info")), len(header_fields("bass_chunk_info"))
    n_flags = len(re.findall(r"#define BASS_CHUNK_\w+ \d+", open(os.path.join(ROOT, "include", "bass.h")).read()))
    with bass.Writer("mex-flags", sample_rate=8000, frames_per_chunk=4, chunks_on_port=8) as w:
        w.start_at(9)
        w.publish(np.zeros((4, 2), dtype=np.int32), flags=bass.CHUNK_LATE, mono_ns=5_000_000_123,
                  realtime_ns=2**62 + 7)
        w.publish_lost(8)
        w.publish_gap(flags=bass.CHUNK_DISCONTINUITY)
        code = f"""
        h = bass_mex('Open', 'mex-flags');
        i = bass_mex('Info', h);
        assert(numel(fieldnames(i)) == {n_info});
        assert(i.lostUpstreamFrames == 8 && isa(i.lostUpstreamFrames, 'uint64'));
        assert(i.gapFrames == 12 && i.lastFrameIndex == 24 && strcmp(i.state, 'capturing'));
        assert(i.startedMonoNs > 0 && i.heartbeatMonoNs >= i.startedMonoNs && isa(i.heartbeatMonoNs, 'uint64'));
        c = bass_mex('ChunkInfo', h, 10);
        assert(numel(fieldnames(c)) == {n_chunk} + {n_flags} + 3);
        assert(isnan(c.boundNs) && c.missingChannels == 0 && isa(c.unalignedChannels, 'uint64'));
        assert(c.firstFrame == 9 && c.frames == 4 && c.late && ~c.gap && ~c.discontinuity && ~c.timeEstimated);
        assert(c.monoNs == uint64(5000000123) && c.realtimeNs == uint64(2)^62 + 7 && isa(c.realtimeNs, 'uint64'));
        c = bass_mex('ChunkInfo', h, uint64(20));
        assert(c.firstFrame == 17 && c.gap && ~c.late && c.flags == {bass.CHUNK_GAP});
        c = bass_mex('ChunkInfo', h, 24);
        assert(c.gap && c.discontinuity && c.flags == {bass.CHUNK_GAP | bass.CHUNK_DISCONTINUITY});
        expect_error('bass:lost', @() bass_mex('ChunkInfo', h, 8));
        expect_error('bass:notYet', @() bass_mex('ChunkInfo', h, 25));
        expect_error('bass:badArgument', @() bass_mex('ChunkInfo', h, -1));
        expect_error('bass:usage', @() bass_mex('ChunkInfo', h));
        bass_mex('Close', h);
        disp('chunk info ok');
        """
        rc, out, err = octave(clients_env, code)
    assert rc == 0, out + err
    assert "chunk info ok" in out


def test_octave_sees_the_gap_chunks_of_a_device_overrun(mexdir, clients_env, broker):
    """sim:xrun at 8000 Hz, 100-frame chunks: frames 4001..4400 are GAP chunks, 4401 starts the
    DISCONTINUITY chunk; Info counts the overrun."""
    code = f"""
    b = Bass('{broker}');
    b.Acquire('sim:xrun', 8000, 100, 200);
    b.Wait(uint64(4600), 10);
    h = bass_mex('Open', '{broker}');
    before = bass_mex('ChunkInfo', h, 4000);
    assert(before.firstFrame == 3901 && ~before.gap && ~before.discontinuity);
    for f = [4001 4200 4400]
      c = bass_mex('ChunkInfo', h, f);
      assert(c.gap && c.timeEstimated && c.frames == 100);
    end
    after = b.ChunkInfo(4401);  % the Bass class
    assert(after.firstFrame == 4401 && after.discontinuity && ~after.gap);
    assert(after.monoNs - before.monoNs == uint64(5 * 12500000));
    i = b.PortInfo();
    assert(i.xruns >= 1 && i.gapFrames >= 407 && i.lostUpstreamFrames == 0);
    bass_mex('Close', h);
    b.Stop();
    disp('xrun ok');
    """
    rc, out, err = octave(clients_env, code)
    assert rc == 0, out + err
    assert "xrun ok" in out


def test_octave_names_the_never_ready_and_wrong_owner_errors(mexdir, clients_env, tmp_path):
    """The two result codes the gateway once reported as bass:unknown: a port file whose header
    never became valid (bass:neverReady) and, when this test may chown, one owned by a user the
    reader does not trust (bass:wrongOwner)."""
    import bass

    os.chmod(tmp_path, 0o700)  # only its owner can create files here: a foreign owner is wrong
    env = dict(clients_env, BASS_RUNTIME_DIR=str(tmp_path))
    stale = tmp_path / "bass-stale.port"
    stale.write_bytes(bytes(8192))
    foreign = None
    if os.geteuid() == 0:
        foreign = tmp_path / "bass-foreign.port"
        foreign.write_bytes(bytes(8192))
        os.chown(foreign, 65534, 65534)
    elif os.environ.get("BASS_TESTS_NO_SKIP", "0") != "0":
        pytest.fail("BASS_TESTS_NO_SKIP: the wrong-owner case needs root (chown)")
    # Wait (for the condition) until the stale file is past the library's 2 s grace.
    deadline = time.monotonic() + 30
    while True:
        rc, out, err = octave(env, "try; bass_mex('Open', 'stale'); catch e; disp(e.identifier); end")
        if "bass:neverReady" in out or time.monotonic() > deadline:
            break
        assert "bass:notReady" in out, out + err
        time.sleep(0.2)
    code = "expect_error('bass:neverReady', @() bass_mex('Open', 'stale'));"
    if foreign:
        code += " expect_error('bass:wrongOwner', @() bass_mex('Open', 'foreign'));"
    rc, out, err = octave(env, code + " disp('ids ok');")
    assert rc == 0, out + err
    assert "ids ok" in out
