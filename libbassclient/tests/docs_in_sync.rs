//! docs/c-api.md must state the facts of include/bass.h (the contract for C, C++, MEX and
//! Python): every result code of the header is in the docs' table with its number, the table
//! has no other rows, every `BASS_*` / `bass_*` name the docs mention exists in the header,
//! and the C examples use no made-up constants.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

fn read(rel: &str) -> String {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Identifiers (ASCII letters, digits, `_`, not starting with a digit) in `text`.
fn identifiers(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .filter(|w| w.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_'))
}

/// `NAME = value` members of the header's `bass_result` enum.
fn header_results(header: &str) -> BTreeMap<String, u32> {
    // `typedef enum { ... } bass_result;`: the body before the typedef's name.
    let end = header.find("} bass_result;").expect("the header declares bass_result");
    let body = &header[header[..end].rfind('{').expect("enum body") + 1..end];
    body.lines()
        .map(str::trim)
        .filter(|l| l.starts_with("BASS_"))
        .map(|l| {
            let (name, value) = l.trim_end_matches(',').split_once('=').expect("explicit values");
            (name.trim().to_string(), value.trim().parse().expect("numeric value"))
        })
        .collect()
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
    let header = read("include/bass.h");
    let docs = read("docs/c-api.md");
    let want = header_results(&header);
    assert!(want.len() > 20, "parsed only {} result codes from the header", want.len());
    assert_eq!(docs_results(&docs), want, "docs/c-api.md's result table differs from include/bass.h");
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
