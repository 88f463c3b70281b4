//! Credentials (docs/network.md, "Security"): one private file per machine, public cards
//! exchanged between machines, no secret ever copied.
//!
//! A credentials file (mode 0600, read by bass only, never given to Zenoh) holds this
//! machine's identity name, a 32-byte secret seed, and the public cards it trusts:
//!
//! ```text
//! bass-bridge-credentials 2
//! identity robot
//! seed <64 hex digits>
//! trust ws1 <signing key, 64 hex> <key-agreement key, 64 hex>
//! ```
//!
//! From the seed come an Ed25519 signing key (serve signs its chunks, states, clock and
//! control replies; a mirror signs its control requests) and an X25519 key-agreement key.
//! The public card (`robot.pub`, one line `bass-bridge-identity 2 NAME SIGN DH`) is what
//! other machines trust. The Zenoh user/password of each ordered pair of machines is
//! derived from the two machines' keys (X25519, then HKDF-SHA256 over both names), so only
//! those two machines can compute it: a machine that trusts robot holds nothing with which
//! it could log in, or sign, as robot. The dictionary Zenoh checks is made from the trusted
//! cards at start, in memory ([`Credentials::zenoh_dictionary`]): no comment, blank or
//! header line of any file ever reaches Zenoh's parser.

use std::io::{Read, Write};
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ed25519_dalek::{Signer, SigningKey, VerifyingKey};

use crate::usage::UsageError;

/// Options of `bass-bridge credentials`.
#[derive(clap::Args, Debug)]
pub struct CredentialsOpts {
    /// The credentials file to create (with --user) or to add trusted identities to; its
    /// public card is written next to it (`robot.cred` → `robot.pub`).
    pub file: PathBuf,
    /// Create FILE for this machine's identity NAME, with fresh keys.
    #[arg(long, value_name = "NAME")]
    pub user: Option<String>,
    /// Trust another machine's public card (its `.pub` file; repeatable). A card of a name
    /// already trusted with other keys replaces it (a rotated identity), and says so.
    #[arg(long, value_name = "OTHER.pub")]
    pub trust: Vec<PathBuf>,
    /// Stop trusting the identity NAME (repeatable).
    #[arg(long, value_name = "NAME")]
    pub forget: Vec<String>,
    /// Write FILE's public card again (it is written whenever FILE is created or changed).
    #[arg(long)]
    pub export: bool,
}

/// Largest credentials file or public card read (a file over this is refused by name).
pub const MAX_FILE: u64 = 1 << 20;
/// Most identities one file trusts.
pub const MAX_TRUSTED: usize = 1024;

const FILE_MAGIC: &str = "bass-bridge-credentials 2";
const CARD_MAGIC: &str = "bass-bridge-identity 2";
/// Domain separation of every signature bass-bridge makes.
const SIGNATURE_CONTEXT: &[u8] = b"bass-bridge signature v2\0";

/// Another machine's public identity: its name and its two public keys.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Identity name (the Zenoh user name).
    pub name: String,
    /// Ed25519 public key.
    pub sign: [u8; 32],
    /// X25519 public key.
    pub dh: [u8; 32],
}

/// A loaded credentials file.
#[derive(Clone)]
pub struct Credentials {
    /// This machine's identity name.
    pub user: String,
    seed: [u8; 32],
    /// The identities trusted, in file order.
    pub trusted: Vec<Identity>,
}

impl std::fmt::Debug for Credentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Credentials").field("user", &self.user).field("trusted", &self.trusted).finish()
    }
}

/// Checks an identity name: also a Zenoh user name and a key-expression chunk, so none of
/// `: * $ # / ?` nor spaces.
pub fn check_user(user: &str) -> Result<()> {
    let ok = !user.is_empty()
        && user.len() <= 64
        && user.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-@".contains(&b));
    if !ok {
        return Err(UsageError(format!(
            "identity name {}: use 1 to 64 characters of A-Z a-z 0-9 . _ - @",
            crate::text::escape(&format!("{user:?}"))
        ))
        .into());
    }
    Ok(())
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn unhex32(s: &str) -> Option<[u8; 32]> {
    if s.len() != 64 || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

impl Identity {
    /// The card's one line.
    pub fn card(&self) -> String {
        format!("{CARD_MAGIC} {} {} {}\n", self.name, hex(&self.sign), hex(&self.dh))
    }

    fn parse_keys(name: &str, sign: &str, dh: &str, what: &str) -> Result<Identity> {
        check_user(name).with_context(|| what.to_owned())?;
        let (Some(sign), Some(dh)) = (unhex32(sign), unhex32(dh)) else {
            return Err(
                UsageError(format!("{what}: the keys of {name:?} are not two 64-digit hex keys")).into()
            );
        };
        VerifyingKey::from_bytes(&sign).map_err(|_| {
            UsageError(format!("{what}: the signing key of {name:?} is not a valid Ed25519 key"))
        })?;
        Ok(Identity { name: name.to_owned(), sign, dh })
    }

    /// Parses a public card (`bass-bridge-identity 2 NAME SIGN DH`).
    pub fn parse_card(text: &str, what: &str) -> Result<Identity> {
        if text.lines().map(str::trim).find(|l| !l.is_empty() && !l.starts_with('#')) == Some(FILE_MAGIC) {
            return Err(UsageError(format!(
                "{what} is a private credentials file: it holds that machine's secret seed, never \
                 copy it. Trust its public card instead (the .pub file next to it)"
            ))
            .into());
        }
        let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#'));
        let first = lines.next().unwrap_or_default();
        let fields: Vec<&str> = first.split_ascii_whitespace().collect();
        match fields[..] {
            ["bass-bridge-identity", "2", name, sign, dh] if lines.next().is_none() => {
                Identity::parse_keys(name, sign, dh, what)
            }
            _ if first.contains(':') => Err(UsageError(format!(
                "{what} is an old shared-password credentials file (version 1): its lines were \
                 secrets. Make new credentials on each machine (`bass-bridge credentials FILE \
                 --user NAME`) and exchange their .pub cards"
            ))
            .into()),
            _ => Err(UsageError(format!(
                "{what} is not a bass-bridge public card (one line `{CARD_MAGIC} NAME KEY KEY`)"
            ))
            .into()),
        }
    }

    /// Whether `signature` (64 bytes) is this identity's over `key` and `payload`.
    pub fn verify(&self, key: &str, payload: &[u8], signature: &[u8]) -> bool {
        let (Ok(vk), Ok(sig)) = (VerifyingKey::from_bytes(&self.sign), <[u8; 64]>::try_from(signature))
        else {
            return false;
        };
        vk.verify_strict(&signed_message(key, payload), &ed25519_dalek::Signature::from_bytes(&sig)).is_ok()
    }
}

/// What is signed: a context, the key expression the message is sent on, the payload. The
/// key binds a message to its broker and purpose (a signed state cannot pass as a chunk).
fn signed_message(key: &str, payload: &[u8]) -> Vec<u8> {
    let mut m = Vec::with_capacity(SIGNATURE_CONTEXT.len() + key.len() + 1 + payload.len());
    m.extend_from_slice(SIGNATURE_CONTEXT);
    m.extend_from_slice(key.as_bytes());
    m.push(0);
    m.extend_from_slice(payload);
    m
}

/// Parses a credentials file's text; errors name the line, never its content.
pub fn parse(text: &str, what: &str) -> Result<Credentials> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| {
        let l = l.trim();
        !l.is_empty() && !l.starts_with('#')
    });
    match lines.next() {
        Some((_, l)) if l.trim() == FILE_MAGIC => {}
        Some((_, l)) if l.contains(':') => {
            return Err(UsageError(format!(
                "{what} is an old shared-password credentials file (version 1), whose lines were \
                 copied between machines: any machine that trusted it could log in as this one. \
                 Make new credentials on each machine (`bass-bridge credentials FILE --user NAME`) \
                 and exchange their public .pub cards (docs/network.md, \"Security\")"
            ))
            .into())
        }
        _ => {
            return Err(UsageError(format!(
                "{what}: not a bass-bridge credentials file (no `{FILE_MAGIC}` line)"
            ))
            .into())
        }
    }
    let (mut user, mut seed, mut trusted) = (None, None, Vec::<Identity>::new());
    for (n, line) in lines {
        let at = format!("{what} line {}", n + 1);
        let f: Vec<&str> = line.split_ascii_whitespace().collect();
        match f[..] {
            ["identity", name] if user.is_none() => {
                check_user(name).with_context(|| at.clone())?;
                user = Some(name.to_owned());
            }
            ["seed", s] if seed.is_none() => {
                seed = Some(
                    unhex32(s).ok_or_else(|| UsageError(format!("{at}: the seed is not 64 hex digits")))?,
                )
            }
            ["trust", name, sign, dh] => {
                let id = Identity::parse_keys(name, sign, dh, &at)?;
                if trusted.iter().any(|t| t.name == id.name) {
                    return Err(UsageError(format!("{at}: {name:?} is trusted twice")).into());
                }
                if trusted.len() >= MAX_TRUSTED {
                    return Err(
                        UsageError(format!("{at}: more than {MAX_TRUSTED} trusted identities")).into()
                    );
                }
                trusted.push(id);
            }
            _ => {
                return Err(UsageError(format!(
                    "{at}: not `identity NAME`, `seed HEX` or `trust NAME KEY KEY`"
                ))
                .into())
            }
        }
    }
    let (Some(user), Some(seed)) = (user, seed) else {
        return Err(UsageError(format!("{what}: no `identity` or no `seed` line")).into());
    };
    if trusted.iter().any(|t| t.name == user) {
        return Err(UsageError(format!("{what}: trusts its own identity {user:?}")).into());
    }
    Ok(Credentials { user, seed, trusted })
}

/// Reads a file that must be a regular file of at most [`MAX_FILE`] bytes (a FIFO or a
/// device is refused by name without blocking); `private`: mode 0600 or stricter too.
pub fn read_checked(path: &Path, what: &str, private: bool) -> Result<String> {
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)
        .map_err(|e| UsageError(format!("{what}: {e}")))?;
    let meta = f.metadata().map_err(|e| UsageError(format!("{what}: {e}")))?;
    if !meta.is_file() {
        return Err(
            UsageError(format!("{what} is not a regular file (a FIFO, a device or a directory)")).into()
        );
    }
    if meta.len() > MAX_FILE {
        return Err(UsageError(format!(
            "{what} is {} bytes, more than the {MAX_FILE} a credentials file may be",
            meta.len()
        ))
        .into());
    }
    let mode = meta.mode() & 0o777;
    if private && mode & 0o077 != 0 {
        return Err(UsageError(format!(
            "{what} is readable by others (mode {mode:04o}): chmod 600 {}",
            path.display()
        ))
        .into());
    }
    let mut text = String::new();
    f.take(MAX_FILE + 1)
        .read_to_string(&mut text)
        .map_err(|e| UsageError(format!("{what}: {e} (not text?)")))?;
    if text.len() as u64 > MAX_FILE {
        return Err(UsageError(format!("{what} grew past {MAX_FILE} bytes while read")).into());
    }
    Ok(text)
}

/// Writes `text` to `path` whole or not at all: a new private temporary file beside it
/// (`O_EXCL`: never through a planted link), synced, then renamed over `path` (a link at
/// `path` is replaced, not followed). `create`: fail if `path` exists.
pub fn write_atomic(path: &Path, text: &str, mode: u32, create: bool) -> Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let base = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{base}.{}.tmp", std::process::id()));
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).mode(mode).open(&tmp)?;
        f.set_permissions(std::fs::Permissions::from_mode(mode))?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
        if create {
            // link(2) fails if `path` exists, whatever it is (a link included).
            std::fs::hard_link(&tmp, path)?;
            std::fs::remove_file(&tmp)
        } else {
            std::fs::rename(&tmp, path)
        }
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        UsageError(format!("write {}: {e}", path.display())).into()
    })
}

impl Credentials {
    /// Loads and checks a credentials file: a regular file, mode 0600 or stricter, at most
    /// [`MAX_FILE`] bytes, well formed.
    pub fn load(path: &Path) -> Result<Credentials> {
        let what = format!("credentials file {}", path.display());
        parse(&read_checked(path, &what, true)?, &what)
    }

    fn signing_key(&self) -> SigningKey {
        SigningKey::from_bytes(&self.derive(b"ed25519"))
    }

    fn dh_secret(&self) -> x25519_dalek::StaticSecret {
        x25519_dalek::StaticSecret::from(self.derive(b"x25519"))
    }

    fn derive(&self, what: &[u8]) -> [u8; 32] {
        let mut out = [0u8; 32];
        hkdf::Hkdf::<sha2::Sha256>::new(Some(b"bass-bridge key v2"), &self.seed)
            .expand(what, &mut out)
            .expect("32 bytes is a valid HKDF-SHA256 output length");
        out
    }

    /// This machine's public card.
    pub fn identity(&self) -> Identity {
        Identity {
            name: self.user.clone(),
            sign: self.signing_key().verifying_key().to_bytes(),
            dh: x25519_dalek::PublicKey::from(&self.dh_secret()).to_bytes(),
        }
    }

    /// The trusted identity `name`.
    pub fn trusted(&self, name: &str) -> Option<&Identity> {
        self.trusted.iter().find(|t| t.name == name)
    }

    /// The trusted names, for messages.
    pub fn trusted_names(&self) -> String {
        if self.trusted.is_empty() {
            return "none".into();
        }
        self.trusted.iter().map(|t| t.name.as_str()).collect::<Vec<_>>().join(", ")
    }

    /// The Zenoh password `from` presents to `to`, where one of the two is this machine and
    /// the other a trusted identity (see [`Credentials::pair_secret`]).
    pub fn pair_password(&self, from: &str, to: &str) -> Option<String> {
        self.pair_secret(from, to, "zenoh usrpwd").map(|k| hex(&k))
    }

    /// A secret of the ordered pair (`from`, `to`) for `purpose`, where one of the two is this
    /// machine and the other a trusted identity: HKDF-SHA256 of their X25519 shared secret
    /// over the purpose and both names. Only these two machines can compute it.
    pub fn pair_secret(&self, from: &str, to: &str, purpose: &str) -> Option<[u8; 32]> {
        let other = match (from == self.user, to == self.user) {
            (true, false) => to,
            (false, true) => from,
            _ => return None,
        };
        let peer = self.trusted(other)?;
        let shared = self.dh_secret().diffie_hellman(&x25519_dalek::PublicKey::from(peer.dh));
        if !shared.was_contributory() {
            return None;
        }
        let mut info = Vec::new();
        for part in [purpose, from, to] {
            info.extend_from_slice(part.as_bytes());
            info.push(0);
        }
        let mut out = [0u8; 32];
        hkdf::Hkdf::<sha2::Sha256>::new(Some(b"bass-bridge pair v2"), shared.as_bytes())
            .expand(&info, &mut out)
            .ok()?;
        Some(out)
    }

    /// Zenoh's user/password dictionary: for each trusted identity, the password it presents
    /// to this machine. Only `user:password` lines of checked names and hex passwords.
    pub fn zenoh_dictionary(&self) -> String {
        let mut d = String::new();
        for t in &self.trusted {
            if let Some(p) = self.pair_password(&t.name, &self.user) {
                d.push_str(&format!("{}:{p}\n", t.name));
            }
        }
        d
    }

    /// Every secret string this machine's Zenoh configuration holds (for log redaction).
    pub fn secrets(&self) -> Vec<String> {
        let mut s = vec![hex(&self.seed)];
        for t in &self.trusted {
            s.extend(self.pair_password(&t.name, &self.user));
            s.extend(self.pair_password(&self.user, &t.name));
        }
        s
    }

    /// Signs `payload` sent on `key` (64 bytes).
    pub fn sign(&self, key: &str, payload: &[u8]) -> [u8; 64] {
        self.signing_key().sign(&signed_message(key, payload)).to_bytes()
    }

    /// A signer for many messages (the key is derived once).
    pub fn signer(&self) -> MessageSigner {
        MessageSigner { key: self.signing_key(), buf: Vec::new() }
    }

    fn text(&self) -> String {
        let mut t = format!(
            "# bass-bridge credentials of {0}: PRIVATE (mode 0600), never copy this file.\n\
             # Give other machines the public card {0}'s .pub file instead.\n\
             {FILE_MAGIC}\nidentity {0}\nseed {1}\n",
            self.user,
            hex(&self.seed)
        );
        for i in &self.trusted {
            t.push_str(&format!("trust {} {} {}\n", i.name, hex(&i.sign), hex(&i.dh)));
        }
        t
    }
}

/// Signs message after message with one derived key and one reused buffer.
pub struct MessageSigner {
    key: SigningKey,
    buf: Vec<u8>,
}

impl MessageSigner {
    /// Signs `payload` sent on `key` (64 bytes).
    pub fn sign(&mut self, key: &str, payload: &[u8]) -> [u8; 64] {
        self.buf.clear();
        self.buf.extend_from_slice(SIGNATURE_CONTEXT);
        self.buf.extend_from_slice(key.as_bytes());
        self.buf.push(0);
        self.buf.extend_from_slice(payload);
        self.key.sign(&self.buf).to_bytes()
    }
}

/// HMAC-SHA256 of `parts` under `key` (a [`Credentials::pair_secret`]).
pub fn mac(key: &[u8; 32], parts: &[&[u8]]) -> [u8; 32] {
    use hmac::Mac;
    let mut m =
        <hmac::Hmac<sha2::Sha256> as Mac>::new_from_slice(key).expect("HMAC takes a key of any length");
    for p in parts {
        m.update(p);
    }
    m.finalize().into_bytes().into()
}

/// The public card's path beside a credentials file (`robot.cred` → `robot.pub`).
pub fn card_path(file: &Path) -> PathBuf {
    file.with_extension("pub")
}

fn random_seed() -> Result<[u8; 32]> {
    let mut b = [0u8; 32];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut b))
        .context("read /dev/urandom")?;
    Ok(b)
}

fn write_card(file: &Path, c: &Credentials) -> Result<()> {
    let card = card_path(file);
    write_atomic(&card, &c.identity().card(), 0o644, false)?;
    eprintln!(
        "public card of {:?}: {} (give it to the machines that should trust this one)",
        c.user,
        card.display()
    );
    Ok(())
}

/// `bass-bridge credentials`: creates a file (`--user`), trusts or forgets identities.
pub fn run(o: CredentialsOpts) -> Result<()> {
    if o.user.is_none() && o.trust.is_empty() && o.forget.is_empty() && !o.export {
        return Err(UsageError(
            "give --user NAME (create), --trust OTHER.pub, --forget NAME or --export".into(),
        )
        .into());
    }
    if card_path(&o.file) == o.file {
        return Err(UsageError(format!(
            "{}: a credentials file may not end in .pub (its card is written there)",
            o.file.display()
        ))
        .into());
    }
    if let Some(user) = &o.user {
        check_user(user)?;
        let c = Credentials { user: user.clone(), seed: random_seed()?, trusted: Vec::new() };
        write_atomic(&o.file, &c.text(), 0o600, true)?;
        eprintln!("created {} for identity {user:?}", o.file.display());
    }
    let mut mine = Credentials::load(&o.file)?;
    let before = mine.trusted.clone();
    for other in &o.trust {
        let what = format!("public card {}", other.display());
        let id = Identity::parse_card(&read_checked(other, &what, false)?, &what)?;
        if id.name == mine.user {
            return Err(UsageError(format!("{what} is this file's own identity {:?}", id.name)).into());
        }
        let full = mine.trusted.len() >= MAX_TRUSTED;
        match mine.trusted.iter_mut().find(|t| t.name == id.name) {
            Some(t) if *t == id => {
                eprintln!("{} already trusts {:?} with these keys", o.file.display(), id.name)
            }
            Some(t) => {
                *t = id.clone();
                eprintln!(
                    "{}: the keys of {:?} changed (a rotated identity): the new ones replace the old, \
                     which are no longer accepted",
                    o.file.display(),
                    id.name
                );
            }
            None if full => {
                return Err(UsageError(format!(
                    "{} trusts {MAX_TRUSTED} identities already",
                    o.file.display()
                ))
                .into())
            }
            None => {
                eprintln!("{} now trusts {:?}", o.file.display(), id.name);
                mine.trusted.push(id);
            }
        }
    }
    for name in &o.forget {
        let n = mine.trusted.len();
        mine.trusted.retain(|t| &t.name != name);
        if mine.trusted.len() == n {
            return Err(UsageError(format!("{} does not trust {name:?}", o.file.display())).into());
        }
        eprintln!("{} no longer trusts {name:?}", o.file.display());
    }
    if mine.trusted != before {
        write_atomic(&o.file, &mine.text(), 0o600, false)?;
    }
    if o.user.is_some() || o.export || mine.trusted != before {
        write_card(&o.file, &mine)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
