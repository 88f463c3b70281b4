#!/usr/bin/env python3
"""The docs test (make test-docs): the documentation's commands and snippets run as written.

Usage: run_docs.py --bin DIR --mexdir DIR [DOC[:KINDS[:broker]] ...]   (tests/docs/run.sh)

With no DOC, the documents of DOCS; a DOC of DOCS named alone runs as DOCS says; any other
document runs the KINDS given (comma-separated: sh,python,octave), with the runner's broker if
`:broker` follows (tests/docs/selftest/ uses this to check that the runner fails what it must).

Each document of DOCS gets a private runtime directory (BASS_RUNTIME_DIR) and a working
directory, with DIR first on PATH (so `bassd` and `bass` are the built ones, as after `make
install`), the source tree's Python package and DIR's libbassclient. Its fenced blocks run in
the document's order, each kind as a reader would run it:

* ```sh: a block with `$ ` prompts is a transcript: each `$` line is a command and the lines
  after it are what the documentation says it prints; a block without prompts is a script,
  every line a command (a trailing backslash continues it). Each command runs with bash in
  the working directory and must exit 0; what it starts in the background (`bassd &`) lives
  until the document's end.
* ```python: a script of its own (python3), which must exit 0.
* ```octave (or ```matlab): `>> ` lines are typed into one interactive Octave per document, on
  a pseudo-terminal (the MEX gateway and Bass.m on its path); the other lines are the
  session's output. A command must give the prompt back without an `error:` line. A command
  whose shown output has a `^C` line is interrupted with Ctrl-C once the first line shown
  for it has appeared (or after half a second): it must still be running then, and must give
  the prompt back with no error but one that says it was interrupted.

Every command's output is bounded (MAX_LINES lines): a snippet that floods the screen (an
Octave statement without its semicolon printing 88200 x 2 numbers) fails. Every command has a
time limit.

Markers, an HTML comment on the line before a block (blank lines between are allowed):

* `<!-- docs-test: skip (WHY) -->`: the block is not run (it needs a sound card, a second
  computer, rebuilds the tree, ...); the runner prints it and WHY.
* `<!-- docs-test: output -->`: what the block prints must be what the documentation shows
  (whitespace collapsed, so the text may wrap). In a transcript (```sh with `$ `, or
  ```octave), each command's output (stdout for the shell) is compared with the lines shown
  after it; commands shown without output, and Octave commands interrupted with `^C`, are not
  compared. A ```python block's stdout is compared with the ```text block that follows it.

A document marked `broker` gets a plain `bassd` (broker "default") started by the runner
before its blocks: the one its set-up step starts (a step the document's reader runs once,
marked skip since it builds the tree).
"""

import argparse
import ctypes
import os
import pty
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

# (document, block kinds it runs, whether the runner starts its broker "default")
DOCS = [
    ("README.md", {"sh"}, False),
    ("docs/tutorial.md", {"sh", "python", "octave"}, True),
    ("docs/clients.md", {"python"}, True),
]
KINDS = {"sh": "sh", "bash": "sh", "console": "sh", "shell": "sh", "python": "python",
         "octave": "octave", "matlab": "octave"}
MARKER = re.compile(r"^\s*<!--\s*docs-test:\s*(skip|output)\b\s*(.*?)\s*-->\s*$")
FENCE = re.compile(r"^(\s*)```(\S*)\s*$")
MAX_LINES = 200
COMMAND_TIMEOUT = 120
OCTAVE_PROMPT = "docs-test-octave> "


class Block:
    def __init__(self, doc, line, kind, lines, marker):
        self.doc, self.line, self.kind, self.lines, self.marker = doc, line, kind, lines, marker
        self.lang = kind  # the fence's language, as written
        self.expected = None  # a python block marked output: the lines of the text block after it

    def where(self):
        return f"{self.doc}:{self.line} ({self.kind})"


def blocks(doc, text):
    """The fenced blocks of a document, with the marker before each (or None)."""
    out, marker, lines = [], None, text.splitlines()
    i = 0
    while i < len(lines):
        m = MARKER.match(lines[i])
        f = FENCE.match(lines[i])
        if m:
            marker = (m.group(1), m.group(2).strip("() "))
        elif f and f.group(2):
            indent, lang, start = f.group(1), f.group(2).lower(), i + 1
            body = []
            i += 1
            while i < len(lines) and not re.match(r"^\s*```\s*$", lines[i]):
                body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i].lstrip())
                i += 1
            out.append(Block(doc, start, lang, body, marker))
            marker = None
        elif lines[i].strip():
            marker = None
        i += 1
    for b, after in zip(out, out[1:] + [None]):
        if b.marker and b.marker[0] == "output" and KINDS.get(b.lang) == "python":
            if after is None or after.lang != "text":
                raise Failure(f"{b.where()}: marked output, but no ```text block of its output follows")
            b.expected = after.lines
    return out


def joined(lines):
    """Lines with trailing-backslash continuations joined."""
    out, cur = [], ""
    for line in lines:
        if line.rstrip().endswith("\\"):
            cur += line.rstrip()[:-1] + " "
            continue
        out.append(cur + line)
        cur = ""
    if cur:
        out.append(cur)
    return out


def collapse(text):
    return " ".join(text.split())


def too_long(text):
    n = len(text.splitlines())
    return f"printed {n} lines (more than {MAX_LINES}: a missing semicolon?)" if n > MAX_LINES else None


class Failure(Exception):
    pass


class Session:
    """One document's run: its directories, environment, background processes, Octave."""

    def __init__(self, doc, args):
        self.doc, self.args = doc, args
        self.tmp = tempfile.mkdtemp(prefix="bass-docs-test-")
        self.rt = os.path.join(self.tmp, "rt")
        self.work = os.path.join(self.tmp, "work")
        os.mkdir(self.rt, 0o700)
        os.mkdir(self.work)
        env = dict(os.environ)
        env["PATH"] = args.bin + os.pathsep + env.get("PATH", "")
        env["BASS_RUNTIME_DIR"] = self.rt
        env["BASS_LIB"] = os.path.join(args.bin, "libbassclient.so")
        env["PYTHONPATH"] = os.path.join(ROOT, "python") + os.pathsep + env.get("PYTHONPATH", "")
        env.pop("BASS_BROKER_UID", None)
        self.env = env
        self.groups = []  # process groups started for this document (each command's bash)
        self.octave = None
        self.count = 0

    def show(self, cmd, out):
        if self.args.verbose:
            print(f"  $ {cmd}\n" + "".join(f"  | {l}\n" for l in out.splitlines()), end="")

    def log(self, name):
        self.count += 1
        return os.path.join(self.tmp, f"{self.count:03d}-{name}")

    # --- processes -------------------------------------------------------------------------
    def spawn(self, argv, out, err):
        p = subprocess.Popen(argv, cwd=self.work, env=self.env, stdin=subprocess.DEVNULL,
                             stdout=out, stderr=err, start_new_session=True)
        self.groups.append(p.pid)
        return p

    def start_broker(self):
        with open(self.log("bassd.log"), "w") as log:
            self.spawn(["bassd"], log, log)
        sock = os.path.join(self.rt, "bass-default.sock")
        deadline = time.monotonic() + 30
        while not os.path.exists(sock):
            if time.monotonic() > deadline:
                raise Failure(f"{self.doc}: the runner's bassd did not create {sock}")
            time.sleep(0.02)

    def close(self):
        if self.octave:
            self.octave.close()
        for g in self.groups:
            try:
                os.killpg(g, signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + 10
        while self.groups and time.monotonic() < deadline:
            reap()
            self.groups = [g for g in self.groups if alive(g)]
            time.sleep(0.02)
        for g in self.groups:
            os.killpg(g, signal.SIGKILL)
        reap()
        shutil.rmtree(self.tmp, ignore_errors=True)

    # --- blocks ----------------------------------------------------------------------------
    def run(self, b):
        if b.kind == "sh":
            return self.run_sh(b)
        if b.kind == "python":
            return self.run_python(b)
        return self.run_octave(b)

    def command(self, cmd, b):
        out, err = self.log("stdout"), self.log("stderr")
        with open(out, "w") as o, open(err, "w") as e:
            p = self.spawn(["bash", "-c", "set -o pipefail\n" + cmd], o, e)
            try:
                rc = p.wait(timeout=COMMAND_TIMEOUT)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
                rc = f"timeout after {COMMAND_TIMEOUT} s"
        stdout, stderr = open(out).read(), open(err).read()
        self.show(cmd, stdout + stderr)
        if rc != 0:
            raise Failure(f"{b.where()}: `{cmd}` exited {rc}:\n{stdout}{stderr}")
        if too_long(stdout):
            raise Failure(f"{b.where()}: `{cmd}` {too_long(stdout)}")
        return stdout

    def run_sh(self, b):
        lines = joined(b.lines)
        if any(l.startswith("$ ") for l in lines):
            steps, cur = [], None
            for l in lines:
                if l.startswith("$ "):
                    cur = [l[2:], []]
                    steps.append(cur)
                elif cur is not None:
                    cur[1].append(l)
        else:
            steps = [[l, []] for l in lines if l.strip() and not l.lstrip().startswith("#")]
        for cmd, shown in steps:
            stdout = self.command(cmd, b)
            if b.marker and b.marker[0] == "output" and any(s.strip() for s in shown):
                if collapse(stdout) != collapse("\n".join(shown)):
                    raise Failure(f"{b.where()}: `{cmd}` printed\n{stdout}\nbut the documentation shows\n"
                                  + "\n".join(shown))
        return f"{len(steps)} command(s)"

    def run_python(self, b):
        path = os.path.join(self.tmp, f"snippet-{b.line}.py")
        with open(path, "w") as f:
            f.write("\n".join(b.lines) + "\n")
        stdout = self.command(f"exec {sys.executable} {path}", b)
        if b.expected is not None and collapse(stdout) != collapse("\n".join(b.expected)):
            raise Failure(f"{b.where()}: the snippet printed\n{stdout}\nbut the documentation shows\n"
                          + "\n".join(b.expected))
        return f"{len(b.lines)} line(s)" + (", output as shown" if b.expected is not None else "")

    def run_octave(self, b):
        if self.octave is None:
            self.octave = Octave(self)
        steps, cur = [], None
        for l in b.lines:
            if l.startswith(">> "):
                cur = [l[3:], []]
                steps.append(cur)
            elif cur is not None:
                cur[1].append(l)
        for cmd, shown in steps:
            interrupt = any(s.startswith("^C") for s in shown)
            first = next((s.strip() for s in shown if s.strip() and s.strip() != ">>"
                          and not s.startswith("^C") and not s.lstrip().startswith(("...", "("))), None)
            try:
                out = self.octave.run(cmd, interrupt, first)
            except Failure as e:
                raise Failure(f"{b.where()}: {e}") from None
            self.show(cmd, out)
            # An interrupted command may say it was interrupted; no other error is allowed.
            errors = [l for l in out.splitlines() if re.match(r"^(\^C)?error: ", l)
                      and not (interrupt and "interrupted" in l)]
            if errors:
                raise Failure(f"{b.where()}: `{cmd}` failed in Octave:\n{out}")
            if too_long(out):
                raise Failure(f"{b.where()}: `{cmd}` {too_long(out)}")
            shown = [s for s in shown if s.strip() != ">>"]
            if b.marker and b.marker[0] == "output" and not interrupt and any(s.strip() for s in shown):
                if collapse(out) != collapse("\n".join(shown)):
                    raise Failure(f"{b.where()}: `{cmd}` printed\n{out}\nbut the documentation shows\n"
                                  + "\n".join(shown))
        return f"{len(steps)} command(s)"


class Octave:
    """An interactive Octave on a pseudo-terminal, its prompt set to OCTAVE_PROMPT."""

    def __init__(self, session):
        self.session = session
        argv = ["octave", "--no-gui", "--norc", "--quiet", "--no-history", "--no-line-editing",
                "--path", session.args.mexdir]
        self.pid, self.fd = pty.fork()
        if self.pid == 0:
            os.chdir(session.work)
            os.execvpe(argv[0], argv, session.env)
        session.groups.append(self.pid)  # pty.fork makes the child a session leader
        self.buf = ""
        self.syncs = 0
        if not self.read_until(re.compile(r"(>>|octave:\d+>) $"), 60):
            raise Failure(f"Octave did not start: {self.buf}")
        self.run(f"PS1('{OCTAVE_PROMPT}'); more off; page_screen_output(false);", False, None)

    def read_until(self, pattern, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pattern.search(self.buf):
                return True
            r, _, _ = select.select([self.fd], [], [], 0.05)
            if r:
                try:
                    self.buf += os.read(self.fd, 65536).decode(errors="replace").replace("\r", "")
                except OSError:
                    break
        return bool(pattern.search(self.buf))

    def run(self, cmd, interrupt, first):
        """Types cmd; returns what it printed. With interrupt, Ctrl-C once `first` (or half a
        second) has passed: the command must still be running then."""
        self.buf = ""
        os.write(self.fd, (cmd + "\n").encode())
        prompt = re.compile(re.escape(OCTAVE_PROMPT) + r"$")
        if interrupt:
            if first is None or not self.read_until(re.compile(re.escape(first)), 30):
                self.read_until(prompt, 0.5)  # nothing to wait for: let the command start
            if prompt.search(self.buf):
                raise Failure(f"`{cmd}` ended before the Ctrl-C the documentation shows:\n{self.buf}")
            os.write(self.fd, b"\x03")
        if not self.read_until(prompt, 10 if interrupt else COMMAND_TIMEOUT):
            raise Failure(f"Octave gave no prompt back after `{cmd}`:\n{self.buf[-4000:]}")
        # A sync command, so that nothing the command prints late (after an interrupt, a second
        # prompt) is taken for the next command's output.
        self.syncs += 1
        sync = f"disp('docs-test-sync-{self.syncs}')"
        head = len(self.buf)
        os.write(self.fd, (sync + "\n").encode())
        done = re.compile(r"^docs-test-sync-%d\n" % self.syncs + re.escape(OCTAVE_PROMPT) + "$", re.M)
        if not self.read_until(done, 10):
            raise Failure(f"Octave did not answer after `{cmd}`:\n{self.buf[-4000:]}")
        late = self.buf[head:self.buf.rindex(sync)]
        out = (self.buf[:head] + late).replace(OCTAVE_PROMPT, "")
        if out.startswith(cmd):  # the terminal's echo of the command
            out = out[len(cmd):].lstrip("\n")
        return out

    def close(self):
        try:
            os.write(self.fd, b"exit\n")
        except OSError:
            pass
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if os.waitpid(self.pid, os.WNOHANG) != (0, 0):
                break
            self.read_until(re.compile("$^"), 0.05)
        os.close(self.fd)


def alive(pgid):
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def reap():
    """Reaps every finished child (orphans come to this process: it is their subreaper)."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def selected(names):
    """The (document, kinds, broker) to run for the command line's DOC arguments."""
    if not names:
        return DOCS
    known = {d[0]: d for d in DOCS}
    out = []
    for n in names:
        doc, _, rest = n.partition(":")
        if doc in known and not rest:
            out.append(known[doc])
            continue
        kinds, _, broker = rest.partition(":")
        kinds = set(kinds.split(",")) if kinds else {"sh", "python", "octave"}
        out.append((doc, kinds, broker == "broker"))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True, help="directory of bassd, bass and libbassclient.so")
    ap.add_argument("--mexdir", required=True, help="directory of bass_mex.mex and Bass.m")
    ap.add_argument("--no-octave", action="store_true", help="Octave is not installed: skip its blocks")
    ap.add_argument("-v", "--verbose", action="store_true", help="print every command's output")
    ap.add_argument("docs", nargs="*", help="DOC[:KINDS[:broker]] to run (default: all of DOCS)")
    args = ap.parse_args()
    args.bin, args.mexdir = os.path.abspath(args.bin), os.path.abspath(args.mexdir)
    # Orphans (`bassd &` of a command whose bash has exited) come back here to be reaped.
    ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER
    failed = skipped = passed = 0
    for doc, kinds, broker in selected(args.docs):
        try:
            bs = blocks(doc, open(os.path.join(ROOT, doc)).read())
        except Failure as e:
            failed += 1
            print(f"FAIL {e}")
            continue
        bs = [b for b in bs if KINDS.get(b.kind) in kinds]
        for b in bs:
            b.kind = KINDS[b.kind]
        s = Session(doc, args)
        try:
            if broker:
                s.start_broker()
            for b in bs:
                if b.marker and b.marker[0] == "skip":
                    skipped += 1
                    print(f"skip {b.where()}: {b.marker[1]}")
                    continue
                if b.kind == "octave" and args.no_octave:
                    skipped += 1
                    print(f"skip {b.where()}: Octave is not installed")
                    continue
                t0 = time.monotonic()
                try:
                    what = s.run(b)
                except Failure as e:
                    failed += 1
                    print(f"FAIL {e}")
                    break  # the blocks after it build on it
                passed += 1
                print(f"ok   {b.where()}: {what} in {time.monotonic() - t0:.1f} s")
        except Failure as e:
            failed += 1
            print(f"FAIL {e}")
        finally:
            s.close()
    print(f"test-docs: {passed} blocks ran, {skipped} skipped (marked), {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
