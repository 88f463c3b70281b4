//! docs/c-api.md must state the facts of include/bass.h (the contract for C, C++, MEX and
//! Python): every result code of the header is in the docs' table with its number, the table
//! has no other rows, every `BASS_*` / `bass_*` name the docs mention exists in the header,
//! and the C examples use no made-up constants.
//!
//! docs/port-format.md's header and chunk-entry tables must give every field of
//! `format::Header` / `format::ChunkEntry` with the offset and size `offset_of!` finds, and
//! docs/network.md's wire diagram must be the `Header` of bridge/src/wire.rs (read as text,
//! with its own diagram and offset asserts) with the flags it defines.

use bass_test_support::client as common;

use std::collections::{BTreeMap, BTreeSet};

use bassclient::bass_result;
use common::read_repo_file as read;

/// Identifiers (ASCII letters, digits, `_`, not starting with a digit) in `text`.
fn identifiers(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| w.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_'))
}

/// Rows `| value | `NAME` | ... |` of the docs' result table.
fn docs_results(docs: &str) -> BTreeMap<String, u32> {
    docs.lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let value = cells.get(1)?.parse::<u32>().ok()?;
            let name = cells.get(2)?.trim_matches('`');
            (name == "BASS_OK" || name.starts_with("BASS_ERR_")).then(|| (name.to_string(), value))
        })
        .collect()
}

#[test]
fn every_result_code_in_the_docs_has_the_headers_name_and_value() {
    let docs = read("docs/c-api.md");
    let want: BTreeMap<String, u32> = bass_result::all()
        .iter()
        .map(|&r| (r.name().to_str().expect("ASCII").to_owned(), r as u32))
        .collect();
    assert_eq!(docs_results(&docs), want, "docs/c-api.md's result table differs from the library's codes");
}

/// matlab/README.md names every error identifier the MEX gateway raises.
#[test]
fn the_matlab_readme_names_every_error_identifier() {
    let readme = read("matlab/README.md");
    let missing: Vec<&str> = bass_result::all()
        .iter()
        .map(|r| r.mex_id())
        .filter(|&id| id != "bass:ok" && !readme.contains(&format!("`{id}`")))
        .collect();
    assert!(missing.is_empty(), "matlab/README.md does not name {missing:?}");
}

#[test]
fn every_name_the_docs_mention_exists_in_the_header() {
    let header = read("include/bass.h");
    let declared: BTreeSet<&str> = identifiers(&header).collect();
    let docs = read("docs/c-api.md");
    let unknown: BTreeSet<&str> = identifiers(&docs)
        .filter(|w| (w.starts_with("BASS_") || w.starts_with("bass_")) && w.len() > 5)
        .filter(|w| !declared.contains(w))
        .collect();
    assert!(unknown.is_empty(), "docs/c-api.md names what include/bass.h does not declare: {unknown:?}");
}

#[test]
fn the_c_examples_use_only_declared_constants() {
    let header = read("include/bass.h");
    let declared: BTreeSet<&str> = identifiers(&header).collect();
    let docs = read("docs/c-api.md");
    let mut in_code = false;
    let mut unknown = BTreeSet::new();
    for line in docs.lines() {
        if line.starts_with("```") {
            in_code = line.trim() == "```c";
            continue;
        }
        if in_code {
            // ALL-CAPS words in C are macros or enum constants: the header's, or C's own.
            let caps = identifiers(line).filter(|w| {
                w.len() > 1 && w.chars().all(|c| c.is_ascii_uppercase() || c == '_' || c.is_ascii_digit())
            });
            unknown.extend(caps.filter(|w| !declared.contains(w) && !["NULL", "EOF"].contains(w)));
        }
    }
    assert!(unknown.is_empty(), "the C examples of docs/c-api.md use undeclared constants: {unknown:?}");
}

// ---- docs/port-format.md's header and chunk-entry tables against format.rs ----

use std::mem::{offset_of, size_of};

use bassport::format::{
    chunk_flags, ChunkEntry, ChunkExt, Header, CHUNK_ENTRY_SIZE, CHUNK_EXT_SIZE, HEADER_SIZE,
};

/// The size of the field a projection `|h| &h.field` reaches (`size_of_val` needs a value).
fn field_size<S, T>(_: fn(&S) -> &T) -> usize {
    size_of::<T>()
}

/// `(name, offset, size)` of struct fields, from `offset_of!` and the fields' types.
macro_rules! fields {
    ($ty:ty: $($f:ident),* $(,)?) => {
        vec![$((stringify!($f), offset_of!($ty, $f), field_size::<$ty, _>(|s| &s.$f))),*]
    };
}

/// Public field names, in order, of `pub struct NAME { ... }` in Rust source `src`.
fn pub_fields(src: &str, name: &str) -> Vec<String> {
    let start = src.find(&format!("pub struct {name} {{")).unwrap_or_else(|| panic!("no struct {name}"));
    let body = &src[start..start + src[start..].find("\n}").expect("struct end")];
    body.lines()
        .filter_map(|l| l.trim().strip_prefix("pub ")?.split_once(':').map(|(n, _)| n.trim().to_string()))
        .filter(|n| !n.contains(' '))
        .collect()
}

/// Rows `| offset | type | field ... |` of the Markdown table after `heading` in `docs`:
/// (field: the cell's first word, offset, size from the type: u32, u64 or `N B`).
fn docs_table(docs: &str, heading: &str) -> Vec<(String, usize, usize)> {
    let start = docs.find(heading).unwrap_or_else(|| panic!("docs: no section {heading}"));
    let rest = &docs[start + heading.len()..];
    let section = &rest[..rest.find("\n#").unwrap_or(rest.len())];
    section
        .lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let offset = cells.get(1)?.parse::<usize>().ok()?;
            let size = match *cells.get(2)? {
                "u64" => 8,
                "u32" => 4,
                t => t.strip_suffix(" B")?.parse().ok()?,
            };
            let name = cells.get(3)?.split_whitespace().next()?.trim_matches('`');
            Some((name.to_string(), offset, size))
        })
        .collect()
}

fn owned(v: Vec<(&str, usize, usize)>) -> Vec<(String, usize, usize)> {
    v.into_iter().map(|(n, o, s)| (n.to_string(), o, s)).collect()
}

#[test]
fn the_docs_header_table_has_every_field_of_format_rs_at_its_offset_and_size() {
    let layout = fields![Header: magic, version_major, version_minor, header_size, channels, sample_format,
        sample_rate, frames_per_chunk, chunks_on_port, chunk_table_offset, samples_offset, total_size, epoch,
        writer_pid, state, writer_start_time, created_realtime_ns, error_code, futex, restart_grace_ms, writer_pid_ns, ext_table_offset, last_frame_index,
        write_intent, heartbeat_mono_ns, xruns, gap_frames, chunks_published, rate_estimate_mhz,
        started_mono_ns, lost_upstream_frames, message, device];
    // The list above is complete: a field added to format.rs fails here until it is listed.
    let names: Vec<&str> = layout.iter().map(|f| f.0).collect();
    assert_eq!(names, pub_fields(&read("port/src/format.rs"), "Header"));
    let docs = docs_table(&read("docs/port-format.md"), "### Header");
    assert_eq!(docs, owned(layout), "docs/port-format.md's header table differs from format.rs");
    let (_, offset, size) = docs.last().unwrap();
    assert!(offset + size <= HEADER_SIZE);
}

#[test]
fn the_docs_chunk_entry_table_has_every_field_of_format_rs_at_its_offset_and_size() {
    let layout = fields![ChunkEntry: first_frame, mono_ns, realtime_ns, flags, frames];
    let names: Vec<&str> = layout.iter().map(|f| f.0).collect();
    assert_eq!(names, pub_fields(&read("port/src/format.rs"), "ChunkEntry"));
    let docs = read("docs/port-format.md");
    assert!(docs.contains(&format!("### Chunk table entry ({CHUNK_ENTRY_SIZE} bytes)")));
    assert_eq!(docs_table(&docs, "### Chunk table entry"), owned(layout));
}

#[test]
fn the_docs_chunk_extension_table_has_every_field_of_format_rs_at_its_offset_and_size() {
    let layout = fields![ChunkExt: first_frame, bound_ns, missing_channels, unaligned_channels];
    let names: Vec<&str> = layout.iter().map(|f| f.0).collect();
    assert_eq!(names, pub_fields(&read("port/src/format.rs"), "ChunkExt"));
    let docs = read("docs/port-format.md");
    assert!(docs.contains(&format!("### Chunk extension table entry ({CHUNK_EXT_SIZE} bytes)")));
    assert_eq!(docs_table(&docs, "### Chunk extension table entry"), owned(layout));
}

// ---- docs/network.md's wire diagram against bridge/src/wire.rs (read as text: building
// bridge/ takes Zenoh; its own compile-time asserts tie the struct to its offsets) ----

/// Rows `offset size name` of the first ``` block after `after` (lines starting with two
/// numbers); `(name, offset, size)`, size None when not a number (the samples).
fn diagram_rows(text: &str, after: &str) -> Vec<(String, usize, Option<usize>)> {
    let start = text.find(after).unwrap_or_else(|| panic!("no {after:?}"));
    let block = &text[start..];
    let open = block.find("```").expect("a diagram block");
    let block = &block[open + 3..];
    let block = &block[..block.find("```").expect("block end")];
    block
        .lines()
        .filter_map(|l| {
            let mut w = l.trim_start_matches("//!").split_whitespace();
            let offset = w.next()?.parse().ok()?;
            let size = w.next()?;
            let name = w.next()?.trim_end_matches(|c: char| !(c.is_ascii_alphanumeric() || c == '_'));
            // A continuation line of a description ("4 TIME_ESTIMATED | ...") is no field.
            let field = name.starts_with(|c: char| c.is_ascii_lowercase()) && !name.contains('|');
            field.then(|| (name.to_string(), offset, size.parse().ok()))
        })
        .collect()
}

/// `(name, offset, size)` of wire.rs's `repr(C)` Header from its field types, laid out as C
/// does (each field at the next multiple of its alignment).
fn wire_struct(src: &str) -> Vec<(String, usize, Option<usize>)> {
    let start = src.find("pub struct Header {").expect("wire.rs declares Header");
    let body = &src[start..start + src[start..].find("\n}").unwrap()];
    let mut at: usize = 0;
    let mut out = Vec::new();
    for line in body.lines().skip(1) {
        let Some((name, ty)) = line.trim().strip_prefix("pub ").and_then(|l| l.split_once(':')) else {
            continue;
        };
        let ty = ty.trim().trim_end_matches(',');
        let (size, align) = match ty {
            "u16" => (2, 2),
            "u32" => (4, 4),
            "u64" => (8, 8),
            t if t.starts_with("[u8;") => (t[4..t.len() - 1].trim().parse().unwrap(), 1),
            t => panic!("wire.rs Header: unexpected field type {t}"),
        };
        at = at.next_multiple_of(align);
        out.push((name.trim().to_string(), at, Some(size)));
        at += size;
    }
    out
}

#[test]
fn the_docs_wire_diagram_is_wire_rs_header() {
    let src = read("bridge/src/wire.rs");
    let fields = wire_struct(&src);
    assert!(fields.len() >= 16, "parsed {} wire header fields", fields.len());
    // wire.rs's own compile-time asserts say the same offsets.
    for (name, offset, _) in &fields[1..] {
        let assert = format!("assert!(offset_of!(Header, {name}) == {offset});");
        assert!(src.contains(&assert), "bridge/src/wire.rs lacks `{assert}`");
    }
    let (_, last, Some(size)) = fields.last().cloned().unwrap() else { unreachable!() };
    let header_len = last + size;
    assert!(src.contains(&format!("pub const HEADER_LEN: usize = {header_len};")));
    let mut want = fields.clone();
    want.push(("samples".into(), header_len, None));
    assert_eq!(diagram_rows(&src, "//! ```text"), want, "the diagram in wire.rs's doc comment");
    let docs = read("docs/network.md");
    assert_eq!(diagram_rows(&docs, "## The chunk message"), want, "docs/network.md's wire diagram");

    // The flags the docs' diagram names on its flags row are wire.rs's single-bit `flags`
    // constants (a number, or the port's `chunk_flags::NAME`).
    let port_flag = |name: &str| match name {
        "GAP" => Some(chunk_flags::GAP),
        "DISCONTINUITY" => Some(chunk_flags::DISCONTINUITY),
        "TIME_ESTIMATED" => Some(chunk_flags::TIME_ESTIMATED),
        "LATE" => Some(chunk_flags::LATE),
        _ => None,
    };
    let consts: BTreeMap<String, u32> = {
        let m = &src[src.find("pub mod flags {").expect("wire.rs has a flags module")..];
        m[..m.find("\n}").unwrap()]
            .lines()
            .filter_map(|l| {
                let (name, value) = l.trim().strip_prefix("pub const ")?.split_once(": u32 = ")?;
                let value = value.trim_end_matches(';');
                let value = match value.strip_prefix("chunk_flags::") {
                    Some(flag) => port_flag(flag)?,
                    None => value.parse().ok()?, // combinations (PORT, ALL) are not flags
                };
                Some((name.to_string(), value))
            })
            .collect()
    };
    let section = &docs[docs.find("## The chunk message").unwrap()..];
    let mut rows = section.lines().skip_while(|l| l.split_whitespace().nth(2) != Some("flags"));
    let mut text = rows.next().expect("a flags row").to_string();
    // ... and its continuation lines (indented past the columns, no offset of their own).
    text.extend(rows.take_while(|l| l.starts_with("        ")).map(|l| format!(" {l}")));
    let words: Vec<&str> =
        text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).filter(|w| !w.is_empty()).collect();
    let documented: BTreeMap<String, u32> = words
        .windows(2)
        .filter_map(|p| {
            let name = p[1];
            let named = name.len() > 2 && name.chars().all(|c| c.is_ascii_uppercase() || c == '_');
            Some((name.to_string(), p[0].parse().ok().filter(|_| named)?))
        })
        .collect();
    assert!(consts.len() >= 4, "parsed {consts:?} from wire.rs");
    assert_eq!(documented, consts, "docs/network.md's wire flags differ from bridge/src/wire.rs");
}
