//! Who may control a broker through `serve --allow-control`, and the signed request that
//! says who asks: the policy serve checks every request against (a trusted, allowed
//! identity's signature on the request, fresh, not replayed), and the mirror's signing side.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result};

use crate::credentials::Credentials;
use crate::usage::UsageError;

/// How far a signed request's time may be from serve's (CLOCK_REALTIME, both sides).
pub const FRESHNESS: Duration = Duration::from_secs(60);
/// Requests remembered against replay (their nonces, for [`FRESHNESS`] on either side).
const MAX_NONCES: usize = 4096;

/// `--allow-control NAMES` as given: names, and credentials to check them with.
pub fn check_allowed(names: &[String], have_credentials: bool) -> Result<()> {
    if names.iter().all(|n| n.is_empty()) {
        return Err(UsageError(
            "--allow-control needs the identities allowed, comma-separated (e.g. --allow-control \
             ws1,ws2): names of public cards that --credentials trusts"
                .into(),
        )
        .into());
    }
    if !have_credentials {
        return Err(UsageError(
            "--allow-control needs --credentials: a request is authorized by the identity whose key \
             signs it (docs/network.md, \"Remote control\")"
                .into(),
        )
        .into());
    }
    for n in names {
        crate::credentials::check_user(n).context("--allow-control")?;
    }
    Ok(())
}

/// Every `--allow-control` name is a trusted identity.
pub fn check_trusted(names: &[String], cred: &Credentials) -> Result<()> {
    for n in names {
        if cred.trusted(n).is_none() {
            return Err(UsageError(format!(
                "--allow-control {n}: the credentials trust no such identity (they trust: {})",
                cred.trusted_names()
            ))
            .into());
        }
    }
    Ok(())
}

/// Who may control, checked with what.
pub struct Policy {
    /// The identities allowed.
    pub allowed: Vec<String>,
    /// Serve's credentials (the allowed identities' public keys).
    pub credentials: Arc<Credentials>,
    /// The control key expression (signatures are bound to it).
    pub key: String,
}

/// A signed request's attachment: `user_len u8, user, realtime_ns u64 LE, nonce [16],
/// signature [64]`; the signature covers the time, the nonce, the user and the request, on
/// the control key.
pub(super) struct Signed {
    pub(super) user: String,
    pub(super) time_ns: u64,
    pub(super) nonce: [u8; 16],
    pub(super) signature: [u8; 64],
}

pub(super) fn signed_part(time_ns: u64, nonce: &[u8; 16], user: &str, request: &[u8]) -> Vec<u8> {
    let mut m = Vec::with_capacity(8 + 16 + user.len() + 1 + request.len());
    m.extend_from_slice(&time_ns.to_le_bytes());
    m.extend_from_slice(nonce);
    m.extend_from_slice(user.as_bytes());
    m.push(0);
    m.extend_from_slice(request);
    m
}

impl Signed {
    pub(super) fn encode(&self) -> Vec<u8> {
        let mut b = vec![self.user.len() as u8];
        b.extend_from_slice(self.user.as_bytes());
        b.extend_from_slice(&self.time_ns.to_le_bytes());
        b.extend_from_slice(&self.nonce);
        b.extend_from_slice(&self.signature);
        b
    }

    pub(super) fn decode(b: &[u8]) -> Option<Signed> {
        let (&n, rest) = b.split_first()?;
        let n = usize::from(n);
        if rest.len() != n + 8 + 16 + 64 {
            return None;
        }
        let user = std::str::from_utf8(&rest[..n]).ok()?.to_owned();
        crate::credentials::check_user(&user).ok()?;
        let time_ns = u64::from_le_bytes(rest[n..n + 8].try_into().ok()?);
        let nonce = rest[n + 8..n + 24].try_into().ok()?;
        let signature = rest[n + 24..].try_into().ok()?;
        Some(Signed { user, time_ns, nonce, signature })
    }
}

/// Nonces of recent requests, against replay.
#[derive(Default)]
pub(super) struct Seen(std::collections::HashMap<[u8; 16], u64>);

impl Seen {
    /// Whether `nonce` is new (then remembered); false for a replay or when full.
    fn fresh(&mut self, nonce: [u8; 16], now: u64) -> bool {
        let keep = 2 * FRESHNESS.as_nanos() as u64;
        self.0.retain(|_, t| now.saturating_sub(*t) <= keep);
        if self.0.len() >= MAX_NONCES || self.0.contains_key(&nonce) {
            return false;
        }
        self.0.insert(nonce, now);
        true
    }
}

impl Policy {
    /// The identity a request comes from, or why it is refused.
    pub(super) fn authorize(
        &self,
        request: &[u8],
        attachment: Option<&[u8]>,
        seen: &Mutex<Seen>,
    ) -> Result<(String, [u8; 16]), String> {
        let Some(a) = attachment.and_then(Signed::decode) else {
            return Err("an unsigned request (a mirror without --credentials, or not bass-bridge)".into());
        };
        let Some(id) = self.credentials.trusted(&a.user) else {
            return Err(format!("{:?} is not an identity this serve trusts", a.user));
        };
        if !id.verify(&self.key, &signed_part(a.time_ns, &a.nonce, &a.user, request), &a.signature) {
            return Err(format!("a request that claims to be {:?} with a signature that is not its", a.user));
        }
        if !self.allowed.contains(&a.user) {
            return Err(format!(
                "{:?} is not allowed to control this broker (--allow-control {})",
                a.user,
                self.allowed.join(",")
            ));
        }
        let now = bassport::sys::realtime_ns();
        if now.abs_diff(a.time_ns) > FRESHNESS.as_nanos() as u64 {
            return Err(format!(
                "a request from {:?} signed {:.0} s away from this machine's clock (more than {} s: a replay, or clocks apart)",
                a.user,
                (a.time_ns as f64 - now as f64) / 1e9,
                FRESHNESS.as_secs()
            ));
        }
        if !seen.lock().unwrap_or_else(|e| e.into_inner()).fresh(a.nonce, now) {
            return Err(format!("a replayed request of {:?} (its nonce was seen)", a.user));
        }
        Ok((a.user, a.nonce))
    }
}

/// The mirror's side of signed control: its credentials (to sign requests) and the source
/// identity whose signature a reply must carry.
pub struct Signer {
    /// The mirror's credentials.
    pub credentials: Arc<Credentials>,
    /// The source's identity.
    pub source: String,
}

pub(super) fn random_nonce() -> [u8; 16] {
    let mut n = [0u8; 16];
    let read =
        std::fs::File::open("/dev/urandom").and_then(|mut f| std::io::Read::read_exact(&mut f, &mut n));
    if read.is_err() {
        // A nonce need only be unique, not secret.
        n[..8].copy_from_slice(&bassport::sys::monotonic_ns().to_le_bytes());
        n[8..].copy_from_slice(&crate::net::instance_id().to_le_bytes());
    }
    n
}
