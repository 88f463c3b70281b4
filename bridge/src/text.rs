//! Text that came from the network, made safe to show: every control character (C0, DEL,
//! C1: ESC, BEL, CR, LF, ...) becomes a visible escape, and the length is bounded. Whatever
//! a peer sends, it cannot move a terminal's cursor, clear its screen, set its title or forge
//! log lines once it went through [`escape`] — on its way to a log, the status file or a
//! replica port's message (which `bass status` and `bass blocks` print).

/// Longest text kept, in characters (the rest is cut and marked with `...`): room for a
/// local error chain (which may quote network text, so goes through here too), and a bound
/// on what a peer can make us log or store.
pub const MAX_CHARS: usize = 1024;

/// `s` with control characters escaped (`\x1b`, `\n`, `\r`, `\t`, `\u{9b}` for C1, `\\` for
/// a backslash, so an escape cannot be forged either), cut to [`MAX_CHARS`] characters.
///
/// ```
/// assert_eq!(bass_bridge::text::escape("a\x1b[2Jb\u{7}"), "a\\x1b[2Jb\\x07");
/// ```
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len().min(MAX_CHARS * 4));
    for (n, c) in s.chars().enumerate() {
        if n == MAX_CHARS {
            out.push_str("...");
            break;
        }
        match c {
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 || c as u32 == 0x7f => out.push_str(&format!("\\x{:02x}", c as u32)),
            // C1 controls (U+0080..U+009F: CSI is U+009B), and the characters that reorder or
            // hide text (bidirectional overrides, zero-width joiners): named, not shown.
            c if c.is_control() || is_invisible_format(c) => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
            c => out.push(c),
        }
    }
    out
}

/// Whether [`escape`] would change more than backslashes in `s`: a control or invisible
/// formatting character, or more than [`MAX_CHARS`] characters.
pub fn needs_escape(s: &str) -> bool {
    s.chars().any(|c| c.is_control() || is_invisible_format(c)) || s.chars().nth(MAX_CHARS).is_some()
}

/// [`escape`] for bytes that may not be UTF-8 (invalid sequences become U+FFFD first).
pub fn escape_bytes(b: &[u8]) -> String {
    escape(&String::from_utf8_lossy(&b[..b.len().min(MAX_CHARS * 4)]))
}

fn is_invisible_format(c: char) -> bool {
    matches!(c as u32, 0x200b..=0x200f | 0x202a..=0x202e | 0x2066..=0x2069 | 0xfeff)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_become_visible_escapes() {
        assert_eq!(escape("\x1b]0;title\x07\x1b[2J"), "\\x1b]0;title\\x07\\x1b[2J");
        assert_eq!(escape("a\r\nb\tc\x7f"), "a\\r\\nb\\tc\\x7f");
        assert_eq!(escape("\u{9b}31m"), "\\u{9b}31m", "C1 CSI");
        assert_eq!(escape("\u{202e}evil"), "\\u{202e}evil", "a bidi override");
        assert_eq!(escape("ok: école, 48 kHz"), "ok: école, 48 kHz", "printable text is kept");
        assert_eq!(escape("\\x1b"), "\\\\x1b", "a literal backslash cannot forge an escape");
        assert_eq!(escape_bytes(b"\xff\x1b"), "\u{fffd}\\x1b");
        for s in [escape("\x1b\x07\r\n\x7f\u{85}\u{9b}"), escape_bytes(&[0x1b, 0x9b, 0xc2, 0x9b])] {
            assert!(!s.chars().any(|c| c.is_control()), "{s:?}");
        }
    }

    #[test]
    fn the_length_is_bounded() {
        let long = "\x1b".repeat(10_000);
        let e = escape(&long);
        assert_eq!(e, format!("{}...", "\\x1b".repeat(MAX_CHARS)));
        assert!(escape_bytes(&vec![b'a'; 1 << 20]).len() <= MAX_CHARS + 3);
    }
}
