//! Credentials files for Zenoh's user/password authentication (docs/network.md, "Security").
//!
//! A credentials file is text, one identity per line, `user:password` (Zenoh's own dictionary
//! format, so the file is also the dictionary Zenoh checks): the **first** line is the
//! identity this machine presents when it connects; every line, the first included, is an
//! identity it accepts from peers that connect to it. Blank lines and `#` comments are
//! ignored. The file must not be readable by group or others (mode 0600), as ssh keys.
//!
//! `bass-bridge credentials FILE --user NAME` creates a file with a fresh random password;
//! `bass-bridge credentials FILE --trust OTHER` adds OTHER's own identity (its first line)
//! to FILE's accepted ones.

use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::net::UsageError;

/// Options of `bass-bridge credentials`.
#[derive(clap::Args, Debug)]
pub struct CredentialsOpts {
    /// The credentials file to create (with --user) or to add trusted identities to.
    pub file: PathBuf,
    /// Create FILE for this machine's identity NAME, with a fresh random password.
    #[arg(long, value_name = "NAME")]
    pub user: Option<String>,
    /// Accept the identity of another machine's credentials file (its first line; repeatable).
    #[arg(long, value_name = "OTHER_FILE")]
    pub trust: Vec<PathBuf>,
}

/// A loaded credentials file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Credentials {
    /// The identity presented.
    pub user: String,
    /// Its password.
    pub password: String,
    /// Every identity accepted (user names), the first one included.
    pub accepted: Vec<String>,
}

/// Shortest password accepted in a credentials file.
pub const MIN_PASSWORD: usize = 16;

fn check_user(user: &str) -> Result<()> {
    let ok = !user.is_empty()
        && user.len() <= 64
        && user.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-@".contains(&b));
    if !ok {
        return Err(
            UsageError(format!("user name {user:?}: use 1 to 64 characters of A-Z a-z 0-9 . _ - @")).into()
        );
    }
    Ok(())
}

/// Parses a credentials file's text; errors name the line.
pub fn parse(text: &str, what: &str) -> Result<Credentials> {
    let mut ids: Vec<(String, String)> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let Some((user, password)) = line.split_once(':') else {
            return Err(UsageError(format!("{what} line {}: not `user:password`", n + 1)).into());
        };
        check_user(user).with_context(|| format!("{what} line {}", n + 1))?;
        if password.len() < MIN_PASSWORD || password.chars().any(|c| c.is_whitespace() || c.is_control()) {
            return Err(UsageError(format!(
                "{what} line {}: the password of {user:?} must be at least {MIN_PASSWORD} characters \
                 without spaces (make one with `bass-bridge credentials FILE --user NAME`)",
                n + 1
            ))
            .into());
        }
        ids.push((user.to_owned(), password.to_owned()));
    }
    let Some((user, password)) = ids.first().cloned() else {
        return Err(UsageError(format!("{what} holds no `user:password` line")).into());
    };
    Ok(Credentials { user, password, accepted: ids.into_iter().map(|(u, _)| u).collect() })
}

impl Credentials {
    /// Loads and checks a credentials file: mode 0600 or stricter, well formed.
    pub fn load(path: &Path) -> Result<Credentials> {
        let what = format!("credentials file {}", path.display());
        let meta = std::fs::metadata(path).map_err(|e| UsageError(format!("{what}: {e}")))?;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(UsageError(format!(
                "{what} is readable by others (mode {mode:04o}): chmod 600 {}",
                path.display()
            ))
            .into());
        }
        let text = std::fs::read_to_string(path).map_err(|e| UsageError(format!("{what}: {e}")))?;
        parse(&text, &what)
    }
}

/// A fresh random password: 32 hexadecimal digits from the kernel's random source.
fn random_password() -> Result<String> {
    let mut b = [0u8; 16];
    std::io::Read::read_exact(&mut std::fs::File::open("/dev/urandom")?, &mut b)
        .context("read /dev/urandom")?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// `bass-bridge credentials`: creates a file (`--user`) and/or adds trusted identities.
pub fn run(o: CredentialsOpts) -> Result<()> {
    if o.user.is_none() && o.trust.is_empty() {
        return Err(UsageError("give --user NAME (create) or --trust OTHER_FILE (add)".into()).into());
    }
    if let Some(user) = &o.user {
        check_user(user)?;
        // O_EXCL: never overwrite (nor follow a symlink to) an existing file; 0600 from birth.
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&o.file)
            .map_err(|e| UsageError(format!("create {}: {e}", o.file.display())))?;
        writeln!(f, "# bass-bridge credentials: first line = this machine; all lines = accepted")?;
        writeln!(f, "{user}:{}", random_password()?)?;
        eprintln!("created {} for identity {user:?}", o.file.display());
    }
    let mine = Credentials::load(&o.file)?;
    let mut add = String::new();
    let mut known = mine.accepted.clone();
    for other in &o.trust {
        let c = Credentials::load(other)?;
        if known.contains(&c.user) {
            if c.user == mine.user {
                bail!(UsageError(format!("{} is this file's own identity {:?}", other.display(), c.user)));
            }
            eprintln!("{} already accepts {:?}", o.file.display(), c.user);
            continue;
        }
        add.push_str(&format!("{}:{}\n", c.user, c.password));
        known.push(c.user.clone());
        eprintln!("{} now accepts {:?}", o.file.display(), c.user);
    }
    if !add.is_empty() {
        std::fs::OpenOptions::new()
            .append(true)
            .open(&o.file)
            .and_then(|mut f| f.write_all(add.as_bytes()))
            .with_context(|| format!("append to {}", o.file.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_line_is_the_identity_and_every_line_is_accepted() {
        let c = parse("# lab\n\nrobot:0123456789abcdef0123\nws1:fedcba9876543210fedc\n", "t").unwrap();
        assert_eq!(c.user, "robot");
        assert_eq!(c.password, "0123456789abcdef0123");
        assert_eq!(c.accepted, vec!["robot", "ws1"]);
    }

    #[test]
    fn bad_lines_are_named() {
        let e = parse("robot:short\n", "f").unwrap_err().to_string();
        assert!(e.contains("f line 1") && e.contains("at least 16"), "{e}");
        let e = parse("robot 0123456789abcdef\n", "f").unwrap_err().to_string();
        assert!(e.contains("line 1: not `user:password`"), "{e}");
        let e = parse("\n# nothing\n", "f").unwrap_err().to_string();
        assert!(e.contains("no `user:password` line"), "{e}");
        let e = format!("{:#}", parse("ro\x1bbot:0123456789abcdef0123\n", "f").unwrap_err());
        assert!(e.contains("user name \"ro\\u{1b}bot\""), "{e}");
    }

    #[test]
    fn create_trust_and_load_round_trip_with_private_modes() {
        let d = tempfile::tempdir().unwrap();
        let (robot, ws) = (d.path().join("robot.cred"), d.path().join("ws.cred"));
        let mk = |file: &Path, user: Option<&str>, trust: Vec<PathBuf>| {
            run(CredentialsOpts { file: file.to_owned(), user: user.map(str::to_owned), trust })
        };
        mk(&robot, Some("robot"), vec![]).unwrap();
        mk(&ws, Some("ws1"), vec![robot.clone()]).unwrap();
        mk(&robot, None, vec![ws.clone()]).unwrap();
        let (r, w) = (Credentials::load(&robot).unwrap(), Credentials::load(&ws).unwrap());
        assert_eq!((r.user.as_str(), r.accepted.clone()), ("robot", vec!["robot".to_string(), "ws1".into()]));
        assert_eq!((w.user.as_str(), w.accepted.clone()), ("ws1", vec!["ws1".to_string(), "robot".into()]));
        assert_eq!(r.password.len(), 32);
        assert_eq!(std::fs::metadata(&robot).unwrap().permissions().mode() & 0o777, 0o600);
        // Never overwritten.
        assert!(mk(&robot, Some("robot"), vec![]).is_err());
        // A file others can read is refused, naming the mode.
        std::fs::set_permissions(&ws, std::fs::Permissions::from_mode(0o644)).unwrap();
        let e = Credentials::load(&ws).unwrap_err().to_string();
        assert!(e.contains("mode 0644") && e.contains("chmod 600"), "{e}");
    }
}
