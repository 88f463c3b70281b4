"""The Python side's copies of the C ABI facts agree with include/bass.h.

python/bass/_lib.py mirrors C structs with ctypes, and python/bass/__init__.py keeps the
result and state names. A tiny C program, generated from the ctypes field lists and compiled
against the header with `cc`, prints the compiler's sizeof/offsetof/alignment of every
mirrored struct and field and the values of the mirrored constants; they must equal what
ctypes computes. The field names and their order are read from the header, so a field added
on the C side (even one that fits in padding) is noticed too.
"""

import ctypes
import os
import re
import shutil
import subprocess

import bass
from bass import _lib

HERE = os.path.dirname(os.path.abspath(__file__))
INCLUDE = os.path.normpath(os.path.join(HERE, "..", "..", "include"))
HEADER = open(os.path.join(INCLUDE, "bass.h")).read()

# Constants _lib.py copies from the header.
MIRRORED_CONSTANTS = ["BASS_DEVICE_LEN", "BASS_MESSAGE_LEN", "BASS_SOURCE_STATE_LEN", "BASS_WAIT_FOREVER"]


def mirrored_structs():
    """{C name: ctypes class}: every ctypes.Structure of _lib; its docstring starts with the
    C type's name (e.g. "bass_port_info.")."""
    out = {}
    for obj in vars(_lib).values():
        if isinstance(obj, type) and issubclass(obj, ctypes.Structure) and obj is not ctypes.Structure:
            name = re.match(r"\s*(bass_\w+)", obj.__doc__ or "")
            assert name, f"{obj.__name__}: the docstring must start with the C struct's name"
            out[name.group(1)] = obj
    assert out, "_lib.py defines no ctypes structs?"
    return out


def header_struct_fields(name):
    """Field names, in order, of `typedef struct { ... } name;` in the header."""
    end = HEADER.index("} " + name + ";")
    body = HEADER[HEADER.rindex("{", 0, end) + 1:end]
    fields = []
    for line in body.splitlines():
        line = line.strip()
        if not line or line.startswith("//") or line.startswith("/*") or line.startswith("*"):
            continue
        m = re.match(r".*?(\w+)\s*(\[[^\]]*\])?\s*;$", line)
        assert m, f"{name}: cannot read the field line {line!r}"
        fields.append(m.group(1))
    return fields


def header_defines(prefix):
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"#define (" + prefix + r"\w+) (\d+)\b", HEADER)}


def compiled_layout(tmp_path, structs):
    """Runs a C program printing `key value` lines: sizeof/alignof of each struct, offsetof
    and sizeof of each field, and each mirrored constant."""
    cc = shutil.which(os.environ.get("CC", "cc"))
    assert cc, "a C compiler (cc) is needed to check the ctypes layouts"
    lines = ["#include <stdalign.h>", "#include <stddef.h>", "#include <stdio.h>", '#include "bass.h"',
             "int main(void) {"]
    for cname, cls in structs.items():
        lines.append(f'  printf("{cname} size %zu\\n", sizeof({cname}));')
        lines.append(f'  printf("{cname} align %zu\\n", alignof({cname}));')
        for field, _ in cls._fields_:
            lines.append(f'  printf("{cname}.{field} offset %zu\\n", offsetof({cname}, {field}));')
            lines.append(f'  printf("{cname}.{field} size %zu\\n", sizeof((({cname} *)0)->{field}));')
    for const in MIRRORED_CONSTANTS:
        lines.append(f'  printf("{const} value %llu\\n", (unsigned long long)({const}));')
    lines += ["  return 0;", "}"]
    src = tmp_path / "layout.c"
    src.write_text("\n".join(lines) + "\n")
    exe = tmp_path / "layout"
    subprocess.run([cc, "-std=c11", "-Wall", "-Wextra", "-Werror", "-I", INCLUDE, str(src), "-o", str(exe)],
                   check=True, capture_output=True, text=True, timeout=120)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True, timeout=60).stdout
    return {k: int(v) for k, v in (line.rsplit(" ", 1) for line in out.splitlines())}


def test_every_ctypes_struct_has_the_headers_fields_in_order():
    for cname, cls in mirrored_structs().items():
        assert [f for f, _ in cls._fields_] == header_struct_fields(cname), cname


def test_ctypes_sizes_offsets_and_constants_match_the_compiler(tmp_path):
    structs = mirrored_structs()
    c = compiled_layout(tmp_path, structs)
    py = {}
    for cname, cls in structs.items():
        py[f"{cname} size"] = ctypes.sizeof(cls)
        py[f"{cname} align"] = ctypes.alignment(cls)
        for field, ftype in cls._fields_:
            py[f"{cname}.{field} offset"] = getattr(cls, field).offset
            py[f"{cname}.{field} size"] = ctypes.sizeof(ftype)
    for const in MIRRORED_CONSTANTS:
        py[f"{const} value"] = getattr(_lib, const)
    assert py == c


def test_the_python_state_names_are_the_headers():
    want = {v: k.removeprefix("BASS_STATE_").lower() for k, v in header_defines("BASS_STATE_").items()}
    assert len(want) >= 6
    assert bass.STATE_NAMES == want
    # ... and the library's (the MEX gateway shows bass_state_str).
    for value, name in want.items():
        assert _lib.lib.bass_state_str(value).decode() == name
    assert _lib.lib.bass_state_str(max(want) + 1).decode() == "unknown"


def test_every_declared_function_exists_in_the_header_with_as_many_parameters():
    for name, (_, args) in _lib._SIGNATURES.items():
        m = re.search(r"\b" + name + r"\(([^)]*)\);", HEADER)
        assert m, f"{name} is not declared in include/bass.h"
        params = [p for p in m.group(1).split(",") if p.strip() and p.strip() != "void"]
        assert len(params) == len(args), f"{name}: header has {len(params)} parameters, _lib.py {len(args)}"


def test_every_result_code_has_its_constant_in_the_python_package():
    for code, name in bass.RESULT_NAMES.items():
        assert getattr(bass, "BASS_" + ("OK" if code == 0 else "ERR_" + name)) == code
        assert _lib.lib.bass_result_name(code).decode() == ("BASS_OK" if code == 0 else "BASS_ERR_" + name)


def test_the_chunk_flags_are_the_headers():
    header = {k.removeprefix("BASS_CHUNK_"): v for k, v in header_defines("BASS_CHUNK_").items()}
    assert {"GAP", "LATE"} <= set(header)
    assert list(_lib.CHUNK_FLAGS.items()) == list(header.items())
    for name, bit in header.items():
        assert getattr(bass, "CHUNK_" + name) == bit
        assert bass.ChunkInfo(1, 1, 0, 0, bit).flag_names == (name,)


def test_every_result_code_has_a_library_text():
    codes = sorted(bass.RESULT_NAMES)
    assert codes == list(range(len(codes)))
    texts = [_lib.lib.bass_result_str(c).decode() for c in codes]
    assert "unknown result code" not in texts
    assert len(set(texts)) == len(texts)
    assert _lib.lib.bass_result_str(max(codes) + 1).decode() == "unknown result code"
