"""The MEX gateway's copies of include/bass.h facts (matlab/bass_mex.c) agree with the header.

bass_mex.c keeps three tables a C compiler cannot check for completeness: the error
identifier of every result code (IDS), the Matlab field of every bass_port_info,
bass_broker_status and bass_chunk_info member (INFO_FIELDS, STATUS_FIELDS, CHUNK_FIELDS), and one logical per BASS_CHUNK_* flag
(CHUNK_FLAGS). Each is read from the source and compared with the header, so a code, a
member or a flag added to the header and not to the gateway fails here (no Octave needed).
The compiler checks the rest: every name in the tables must exist in bass.h.
"""

import os
import re

from conftest import ROOT

HEADER = open(os.path.join(ROOT, "include", "bass.h")).read()
MEX = "".join(open(os.path.join(ROOT, "matlab", f)).read() for f in ("bass_mex_tables.h", "bass_mex.c"))

# Matlab names that are not the C member in camelCase (the BASS documentation's vocabulary).
LEGACY_NAMES = {
    "frames_per_chunk": "nFramesPerChunk",
    "chunks_on_port": "nChunksOnPort",
    "frames_on_port": "nFramesOnPort",
}


def camel(snake):
    head, *rest = snake.lower().split("_")
    return head + "".join(w.capitalize() for w in rest)


def header_results():
    """[(name, value)] of the bass_result enum, in order."""
    end = HEADER.index("} bass_result;")
    body = HEADER[HEADER.rindex("{", 0, end) + 1:end]
    return [(m.group(1), int(m.group(2))) for m in re.finditer(r"^\s*(BASS_\w+) = (\d+),?$", body, re.M)]


def header_struct_fields(name):
    """Member names, in order, of `typedef struct { ... } name;`."""
    end = HEADER.index("} " + name + ";")
    body = HEADER[HEADER.rindex("{", 0, end) + 1:end]
    body = re.sub(r"//[^\n]*|/\*.*?\*/", "", body, flags=re.S)
    return [m.group(1) for m in re.finditer(r"(\w+)\s*(?:\[[^\]]*\])?\s*;", body)]


def header_defines(prefix):
    """[(name, value)] of `#define PREFIX... N`, in order."""
    return [(m.group(1), int(m.group(2))) for m in re.finditer(r"^#define (" + prefix + r"\w+) (\d+)\b", HEADER, re.M)]


def mex_table(name):
    """The initialiser text of `static const ... name[] = { ... };` in bass_mex.c."""
    m = re.search(r"\b" + name + r"\[\]\s*=\s*\{(.*?)\n\};", MEX, re.S)
    assert m, f"bass_mex.c has no table {name}"
    return m.group(1)


def mex_fields(table, ctype):
    """[(matlab name, C member)] of a FIELD(ctype, "name", member, kind) table."""
    rows = re.findall(r"FIELD\((\w+),\s*\"(\w+)\",\s*(\w+),\s*\w+\)", mex_table(table))
    assert rows, f"{table}: no FIELD rows"
    assert {t for t, _, _ in rows} == {ctype}, f"{table} maps members of {set(t for t, _, _ in rows)}"
    return [(matlab, member) for _, matlab, member in rows]


def test_every_result_code_has_its_own_error_id_in_the_headers_order():
    want = header_results()
    assert len(want) >= 25 and want[0] == ("BASS_OK", 0)
    assert [v for _, v in want] == list(range(len(want))), "the codes are 0..n-1 (an index into IDS)"
    rows = re.findall(r"\[(BASS_\w+)\]\s*=\s*\"([^\"]+)\"", mex_table("IDS"))
    assert [n for n, _ in rows] == [n for n, _ in want], "IDS must list every code of bass_result, in order"
    ids = [i for _, i in rows]
    assert len(set(ids)) == len(ids), f"two codes share an identifier: {ids}"
    assert all(re.fullmatch(r"bass:[a-z][A-Za-z]+", i) for i in ids), ids
    assert "bass:unknown" not in ids and "bass:usage" not in ids and "bass:badArgument" not in ids


def test_info_has_every_member_of_bass_port_info_in_order():
    want = header_struct_fields("bass_port_info")
    assert "lost_upstream_frames" in want and "started_mono_ns" in want, want
    got = mex_fields("INFO_FIELDS", "bass_port_info")
    assert [member for _, member in got] == want, "INFO_FIELDS must map every member of bass_port_info, in order"
    for matlab, member in got:
        assert matlab == LEGACY_NAMES.get(member, camel(member)), (member, matlab)


def test_status_has_every_member_of_bass_broker_status_in_order():
    want = header_struct_fields("bass_broker_status")
    got = mex_fields("STATUS_FIELDS", "bass_broker_status")
    assert [member for _, member in got] == want, "STATUS_FIELDS must map every member of bass_broker_status"
    for matlab, member in got:
        assert matlab == LEGACY_NAMES.get(member, camel(member)), (member, matlab)


def test_chunk_info_has_every_member_of_bass_chunk_info_and_every_chunk_flag():
    want = header_struct_fields("bass_chunk_info")
    got = mex_fields("CHUNK_FIELDS", "bass_chunk_info")
    assert [member for _, member in got] == want, "CHUNK_FIELDS must map every member of bass_chunk_info, in order"
    for matlab, member in got:
        assert matlab == camel(member), (member, matlab)
    flags = header_defines("BASS_CHUNK_")
    assert {"BASS_CHUNK_GAP", "BASS_CHUNK_LATE"} <= {n for n, _ in flags}, flags
    rows = re.findall(r"\{(BASS_CHUNK_\w+),\s*\"(\w+)\"\}", mex_table("CHUNK_FLAGS"))
    assert [n for n, _ in rows] == [n for n, _ in flags], "CHUNK_FLAGS must list every BASS_CHUNK_* flag, in order"
    for name, field in rows:
        assert field == camel(name.removeprefix("BASS_CHUNK_")), (name, field)
    assert not {f for _, f in rows} & {m for m, _ in got}, "a flag field would hide a member"


def test_the_readme_lists_every_error_identifier():
    readme = open(os.path.join(ROOT, "matlab", "README.md")).read()
    ids = re.findall(r"\"(bass:\w+)\"", mex_table("IDS"))
    missing = [i for i in ids if i != "bass:ok" and f"`{i}`" not in readme]
    assert not missing, f"matlab/README.md does not name {missing}"
