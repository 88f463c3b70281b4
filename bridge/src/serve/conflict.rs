//! One name, one source (issue 20 item 6): `serve` watches the liveliness tokens under
//! `NS/<broker>/alive/**` and the state messages on `NS/<broker>/state`, and reports every
//! other live `serve` instance of its name as an error — in its log (rate-limited) and in the
//! state it publishes ([`crate::net::SourceState::conflict`]). It keeps serving: which
//! source a mirror follows is the mirror's decision.
//!
//! Everything here comes from the network: instance and Zenoh ids are escaped and cut before
//! they are kept or logged, and at most [`MAX_OTHERS`] other instances are remembered.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Other instances remembered at most (a peer declaring many tokens cannot grow memory).
pub const MAX_OTHERS: usize = 16;

/// How often one other instance is logged while it stays (its first sight is logged at once).
pub const LOG_EVERY: Duration = Duration::from_secs(30);

/// Longest instance or Zenoh id kept, in characters.
const MAX_ID: usize = 40;

/// The leaf of a token of an older `serve` (key `NS/<broker>/alive`, no instance id).
pub const OLDER: &str = "(an older serve without an instance id)";

/// One other instance.
#[derive(Debug)]
struct Other {
    zid: Option<String>,
    alive: bool,
    logged: Option<Instant>,
}

/// The other instances seen serving our name.
#[derive(Debug)]
pub struct Conflicts {
    own: String,
    own_zid: String,
    others: BTreeMap<String, Other>,
}

/// `s` from the network, escaped and cut to [`MAX_ID`] characters.
fn id(s: &str) -> String {
    let e = crate::text::escape(s);
    if e.chars().count() > MAX_ID {
        let mut cut: String = e.chars().take(MAX_ID).collect();
        cut.push_str("...");
        cut
    } else {
        e
    }
}

/// The instance id in a liveliness key `alive_key/<instance>` (`alive_key` itself: an older
/// serve); None for a key outside `alive_key` or deeper below it.
pub fn instance_of_key<'k>(key: &'k str, alive_key: &str) -> Option<&'k str> {
    let rest = key.strip_prefix(alive_key)?;
    if rest.is_empty() {
        return Some(OLDER);
    }
    let leaf = rest.strip_prefix('/')?;
    (!leaf.is_empty() && !leaf.contains('/')).then_some(leaf)
}

impl Conflicts {
    /// For the instance `own` (16 hex digits) with Zenoh id `own_zid`.
    pub fn new(own: &str, own_zid: &str) -> Conflicts {
        Conflicts { own: own.to_owned(), own_zid: own_zid.to_owned(), others: BTreeMap::new() }
    }

    /// A liveliness token appeared (`alive`) or went away for instance `instance`. Returns the
    /// error line to log now, if any.
    pub fn on_token(&mut self, instance: &str, alive: bool, now: Instant) -> Option<String> {
        if instance == self.own {
            return None;
        }
        let key = id(instance);
        if !alive {
            if let Some(o) = self.others.get_mut(&key) {
                o.alive = false;
            }
            return None;
        }
        if !self.others.contains_key(&key) {
            self.make_room();
            self.others.insert(key.clone(), Other { zid: None, alive: true, logged: None });
        }
        let o = self.others.get_mut(&key)?;
        o.alive = true;
        self.log_if_due(&key, now)
    }

    /// A state message of instance `instance` from Zenoh id `zid`: learns the other's Zenoh
    /// id. Returns the error line to log now (the first time the id is learnt), if any.
    pub fn on_state(&mut self, instance: &str, zid: &str, now: Instant) -> Option<String> {
        if instance.is_empty() || instance == self.own {
            return None;
        }
        let key = id(instance);
        let o = self.others.get_mut(&key)?;
        if zid.is_empty() || o.zid.is_some() {
            return None;
        }
        o.zid = Some(id(zid));
        // What the first line could not say yet: said once, now.
        o.logged = None;
        self.log_if_due(&key, now)
    }

    /// The reminders due now (every [`LOG_EVERY`] per other instance that stays).
    pub fn reminders(&mut self, now: Instant) -> Vec<String> {
        let keys: Vec<String> = self.others.iter().filter(|(_, o)| o.alive).map(|(k, _)| k.clone()).collect();
        keys.iter().filter_map(|k| self.log_if_due(k, now)).collect()
    }

    /// What the published state says while another instance is alive (None: no conflict).
    pub fn describe(&self) -> Option<String> {
        let live: Vec<String> = self
            .others
            .iter()
            .filter(|(_, o)| o.alive)
            .map(|(k, o)| match &o.zid {
                Some(z) => format!("instance {k} (Zenoh id {z})"),
                None => format!("instance {k}"),
            })
            .collect();
        (!live.is_empty()).then(|| {
            format!(
                "another serve publishes this name: {}; this one is instance {} (Zenoh id {})",
                live.join(", "),
                self.own,
                self.own_zid
            )
        })
    }

    fn log_if_due(&mut self, key: &str, now: Instant) -> Option<String> {
        let (own, own_zid) = (&self.own, &self.own_zid);
        let o = self.others.get_mut(key)?;
        if !o.alive || o.logged.is_some_and(|t| now.saturating_duration_since(t) < LOG_EVERY) {
            return None;
        }
        o.logged = Some(now);
        let zid = o.zid.as_deref().unwrap_or("not known yet");
        Some(format!(
            "two sources with one name: another serve instance {key} (Zenoh id {zid}) publishes \
             this name; this is instance {own} (Zenoh id {own_zid}). A mirror follows only one \
             of them: give each source its own --name (or --namespace)"
        ))
    }

    /// Forgets gone instances first, then the oldest-logged, so a new one always fits.
    fn make_room(&mut self) {
        if self.others.len() < MAX_OTHERS {
            return;
        }
        let victim = self.others.iter().min_by_key(|(_, o)| (o.alive, o.logged)).map(|(k, _)| k.clone());
        if let Some(k) = victim {
            self.others.remove(&k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OWN: &str = "00000000000000aa";
    const OTHER: &str = "00000000000000bb";

    #[test]
    fn another_instance_is_an_error_naming_both_and_its_zenoh_id_once_known() {
        let t0 = Instant::now();
        let mut c = Conflicts::new(OWN, "zid-own");
        assert_eq!(c.on_token(OWN, true, t0), None, "our own token is no conflict");
        assert_eq!(c.describe(), None);
        let line = c.on_token(OTHER, true, t0).expect("the first sight is logged");
        assert!(line.contains(OWN) && line.contains(OTHER) && line.contains("not known yet"), "{line}");
        let line = c.on_state(OTHER, "zid-other", t0).expect("the learnt Zenoh id is said");
        assert!(line.contains("zid-other") && line.contains("zid-own"), "{line}");
        assert_eq!(c.on_state(OTHER, "zid-other", t0), None, "said once");
        assert_eq!(c.on_state(OWN, "zid-own", t0), None, "our own state");
        let d = c.describe().expect("a conflict is published");
        assert!(d.contains(OTHER) && d.contains("zid-other") && d.contains(OWN), "{d}");
        c.on_token(OTHER, false, t0);
        assert_eq!(c.describe(), None, "the other's token went away");
    }

    #[test]
    fn logs_are_rate_limited_per_instance_and_flapping_does_not_repeat_them() {
        let t0 = Instant::now();
        let mut c = Conflicts::new(OWN, "z");
        let mut lines = 0;
        for i in 0..1000u64 {
            let now = t0 + Duration::from_millis(i);
            lines += c.on_token(OTHER, i % 2 == 1, now).is_some() as u32;
            lines += c.reminders(now).len() as u32;
        }
        assert_eq!(lines, 1, "1000 token changes in 1 s: one line");
        // The loop ended with the other instance present: it is reminded of, once per LOG_EVERY.
        assert_eq!(
            c.reminders(t0 + LOG_EVERY + Duration::from_secs(1)).len(),
            1,
            "a reminder after LOG_EVERY"
        );
        assert_eq!(c.reminders(t0 + LOG_EVERY + Duration::from_secs(2)).len(), 0);
    }

    #[test]
    fn a_flood_of_tokens_keeps_memory_bounded_and_text_escaped() {
        let t0 = Instant::now();
        let mut c = Conflicts::new(OWN, "z");
        for i in 0..10_000 {
            c.on_token(&format!("{i:016x}\x1b[2J{}", "x".repeat(200)), true, t0);
        }
        assert!(c.others.len() <= MAX_OTHERS);
        let d = c.describe().unwrap();
        assert!(!d.contains('\x1b') && d.contains("\\x1b"), "{d}");
        assert!(d.len() < MAX_OTHERS * 200, "{} bytes", d.len());
    }

    #[test]
    fn instance_ids_come_from_the_token_keys_under_alive() {
        let a = "bass/src/alive";
        assert_eq!(instance_of_key("bass/src/alive/00000000000000bb", a), Some("00000000000000bb"));
        assert_eq!(instance_of_key("bass/src/alive", a), Some(OLDER));
        assert_eq!(instance_of_key("bass/src/alive/x/y", a), None);
        assert_eq!(instance_of_key("bass/src/alivex", a), None);
        assert_eq!(instance_of_key("bass/other/alive/1", a), None);
    }
}
