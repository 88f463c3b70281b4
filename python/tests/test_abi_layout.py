"""The Python side's copies of the C ABI facts agree with include/bass.h and the library.

python/bass/_abi.py (structs, constants, function signatures) and _results.py are generated
by `make header` from the library's Rust sources, as bass.h is, and diffed in CI
(libbassclient/tests/header_in_sync.rs). What is checked here is what generation cannot
prove: a tiny C program, generated from the ctypes field lists and compiled against the
header with `cc`, prints the compiler's sizeof/offsetof/alignment of every mirrored struct and
field and the value of every constant; they must equal what ctypes computes. And the loaded
library exports every declared function and names the states and codes as the package does.
"""

import ctypes
import os
import re
import shutil
import subprocess

import bass
from bass import _abi, _lib

HERE = os.path.dirname(os.path.abspath(__file__))
INCLUDE = os.path.normpath(os.path.join(HERE, "..", "..", "include"))

# Every constant of the generated module.
MIRRORED_CONSTANTS = [n for n in vars(_abi) if n.startswith("BASS_")]


def mirrored_structs():
    """{C name: ctypes class}: every ctypes.Structure of _abi; its docstring starts with the
    C type's name (e.g. "bass_port_info.")."""
    out = {}
    for obj in vars(_abi).values():
        if isinstance(obj, type) and issubclass(obj, ctypes.Structure) and obj is not ctypes.Structure:
            name = re.match(r"\s*(bass_\w+)", obj.__doc__ or "")
            assert name, f"{obj.__name__}: the docstring must start with the C struct's name"
            out[name.group(1)] = obj
    assert out, "_abi.py defines no ctypes structs?"
    return out


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
        py[f"{const} value"] = getattr(_abi, const)
    assert py == c


def test_the_python_state_names_are_the_librarys():
    assert len(bass.STATE_NAMES) >= 6
    # The MEX gateway shows bass_state_str: the same names.
    for value, name in bass.STATE_NAMES.items():
        assert _lib.lib.bass_state_str(value).decode() == name
    assert _lib.lib.bass_state_str(max(bass.STATE_NAMES) + 1).decode() == "unknown"


def test_the_library_exports_every_declared_function():
    assert len(_abi.SIGNATURES) >= 30
    assert _lib.MISSING == []


def test_every_result_code_has_its_constant_in_the_python_package():
    for code, name in bass.RESULT_NAMES.items():
        assert getattr(bass, "BASS_" + ("OK" if code == 0 else "ERR_" + name)) == code
        assert _lib.lib.bass_result_name(code).decode() == ("BASS_OK" if code == 0 else "BASS_ERR_" + name)


def test_the_chunk_flags_are_the_headers():
    assert {"GAP", "LATE"} <= set(bass.CHUNK_FLAGS)
    for name, bit in bass.CHUNK_FLAGS.items():
        assert getattr(bass, "CHUNK_" + name) == bit == getattr(_abi, "BASS_CHUNK_" + name)
        assert bass.ChunkInfo(1, 1, 0, 0, bit).flag_names == (name,)


def test_every_result_code_has_a_library_text():
    codes = sorted(bass.RESULT_NAMES)
    assert codes == list(range(len(codes)))
    texts = [_lib.lib.bass_result_str(c).decode() for c in codes]
    assert "unknown result code" not in texts
    assert len(set(texts)) == len(texts)
    assert _lib.lib.bass_result_str(max(codes) + 1).decode() == "unknown result code"
