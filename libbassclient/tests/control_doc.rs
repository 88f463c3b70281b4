//! docs/control-protocol.md stays exact: every ```json example in it is decoded by the real
//! codec (as a request or as a reply, as its `"request"`/`"reply"` field says), encoded
//! again, and compared with the example as JSON values — a field renamed, added or dropped
//! in the code and not in the doc (or the other way round) fails here.

use bassport::control::wire;

fn doc_examples() -> Vec<(usize, String)> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/control-protocol.md");
    let text = std::fs::read_to_string(path).expect("docs/control-protocol.md");
    let mut out = Vec::new();
    let mut block: Option<(usize, String)> = None;
    for (n, line) in text.lines().enumerate() {
        let fence = line.trim_start();
        match &mut block {
            None if fence == "```json" => block = Some((n + 1, String::new())),
            Some(_) if fence.starts_with("```") => out.extend(block.take()),
            Some((_, body)) => {
                body.push_str(line);
                body.push('\n');
            }
            None => {}
        }
    }
    assert!(block.is_none(), "unterminated ```json block in the doc");
    out
}

#[test]
fn every_documented_message_round_trips_through_the_codec() {
    let examples = doc_examples();
    assert!(examples.len() >= 12, "expected the doc's examples, found {}", examples.len());
    let (mut requests, mut replies) = (0, 0);
    for (line, body) in &examples {
        let written: serde_json::Value =
            serde_json::from_str(body).unwrap_or_else(|e| panic!("doc line {line}: not JSON: {e}"));
        let again = if written.get("request").is_some() {
            requests += 1;
            let r = wire::decode_request(body.as_bytes()).unwrap_or_else(|e| panic!("doc line {line}: {e}"));
            wire::encode_request(&r)
        } else {
            replies += 1;
            let r = wire::decode_reply(body.as_bytes()).unwrap_or_else(|e| panic!("doc line {line}: {e}"));
            wire::encode_reply(&r)
        };
        let again: serde_json::Value = serde_json::from_slice(&again).unwrap();
        assert_eq!(again, written, "doc line {line}: the codec writes this message differently");
    }
    assert!(requests >= 5 && replies >= 6, "{requests} requests, {replies} replies");
    // Every request and every kind of reply is shown at least once.
    for kind in [
        r#""request": "open-port""#,
        r#""reply": "port-fd""#,
        r#""reply": "port-file""#,
        r#""request": "acquire""#,
        r#""reply": "acquired""#,
    ] {
        assert!(examples.iter().any(|(_, b)| b.contains(kind)), "no example of {kind} in the doc");
    }
}

#[test]
fn the_documented_version_is_the_codec_s() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/control-protocol.md"))
        .expect("docs/control-protocol.md");
    assert!(text.starts_with(&format!("# The bass control protocol (version {})", &wire::PROTOCOL[13..])));
    assert_eq!(wire::PROTOCOL, "bass-control/2");
}
