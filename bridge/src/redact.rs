//! No secret in any output: every log line (ours and Zenoh's, at every level) and every error
//! message passes through [`redact`], which replaces each secret this process holds (the
//! credentials' seed, every derived Zenoh password, a password of a `--zenoh-config`) by
//! `<redacted>` before it is written.

use std::borrow::Cow;
use std::io::Write;
use std::sync::RwLock;

static SECRETS: RwLock<Vec<String>> = RwLock::new(Vec::new());

/// Adds secrets to redact from now on (strings shorter than 8 bytes are not secrets bass makes,
/// and would redact ordinary words).
pub fn add(secrets: impl IntoIterator<Item = String>) {
    let mut s = SECRETS.write().unwrap_or_else(|e| e.into_inner());
    for x in secrets {
        if x.len() >= 8 && !s.contains(&x) {
            s.push(x);
        }
    }
}

/// `text` with every known secret replaced by `<redacted>`.
pub fn redact(text: &str) -> Cow<'_, str> {
    let s = SECRETS.read().unwrap_or_else(|e| e.into_inner());
    if !s.iter().any(|x| text.contains(x.as_str())) {
        return Cow::Borrowed(text);
    }
    let mut out = text.to_owned();
    for x in s.iter() {
        out = out.replace(x.as_str(), "<redacted>");
    }
    Cow::Owned(out)
}

/// Standard error through [`redact`]: the writer of the log.
pub struct Stderr;

impl Write for Stderr {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let text = String::from_utf8_lossy(buf);
        std::io::stderr().write_all(redact(&text).as_bytes())?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Stderr {
    type Writer = Stderr;
    fn make_writer(&'a self) -> Stderr {
        Stderr
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn secrets_are_replaced_wherever_they_appear() {
        super::add(["0123456789abcdef".to_string(), "short".to_string()]);
        assert_eq!(super::redact("password: Some(\"0123456789abcdef\")"), "password: Some(\"<redacted>\")");
        assert_eq!(super::redact("short stays"), "short stays");
    }
}
