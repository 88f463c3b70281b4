//! The TRANSIENT_LOCAL ("latched") topic's history, answered at a bounded rate.
//!
//! rmw_zenoh's TRANSIENT_LOCAL subscribers are zenoh-ext advanced subscribers with history
//! and late-publisher detection: on start they query `<key>/@adv/**?_max=<depth>`, and for
//! every publisher token `<key>/@adv/pub/<zid>/<eid>/_` they see appear they query that key
//! (`_max`, and `_sn=a..b` when they recover a gap). zenoh-ext's own cache answers every such
//! query; a peer that floods them made serve spend 40 % of a core answering. [`Latched`] is
//! that cache for depth 1 (the last message, its attachment and sequence number, so a
//! subscriber that also got it live delivers it once), behind a token bucket: at most
//! [`BURST`] answers at once and [`RATE`] a second after that.
//!
//! Refusing a query still costs nearly what answering does (Zenoh decodes, routes and ends
//! each), so when the bucket runs dry the queryable and the publisher's detection token
//! `<key>/@adv/pub/<zid>/<eid>/_` (declared here, not by zenoh-ext) are withdrawn until the
//! bucket is full again ([`BURST`] / [`RATE`] s): a querying peer, or the router between, then
//! sends serve no more queries at all. When they return, every advanced subscriber sees the
//! publisher "join" and queries once more, so one that started during a flood still gets the
//! latched message. Withdrawals are counted and logged.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use zenoh::sample::SourceInfo;
use zenoh::Wait;

/// Answers at once (a ROS launch starting many subscribers of the topic together).
pub const BURST: u32 = 64;

/// Answers a second once the burst is spent.
pub const RATE: u32 = 32;

/// A token bucket: `capacity` tokens, refilled at `per_sec`, one taken per answer.
#[derive(Debug)]
pub struct Bucket {
    capacity: f64,
    per_sec: f64,
    tokens: f64,
    at: Instant,
}

impl Bucket {
    /// A full bucket.
    pub fn new(capacity: u32, per_sec: u32, now: Instant) -> Bucket {
        Bucket {
            capacity: f64::from(capacity),
            per_sec: f64::from(per_sec),
            tokens: f64::from(capacity),
            at: now,
        }
    }

    /// Takes a token if there is one at `now`.
    pub fn take(&mut self, now: Instant) -> bool {
        let dt = now.saturating_duration_since(self.at).as_secs_f64();
        self.tokens = (self.tokens + dt * self.per_sec).min(self.capacity);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// The last message put on the topic.
struct Last {
    payload: Vec<u8>,
    attachment: Vec<u8>,
    sn: u32,
}

/// What the queryable's callback shares with the publishing thread and the history thread.
struct Shared {
    key: String,
    source: zenoh::session::EntityGlobalId,
    last: Mutex<Option<Last>>,
    bucket: Mutex<Bucket>,
    /// Set when the bucket ran dry, until the history thread has withdrawn and re-declared.
    closing: AtomicBool,
    to_thread: Mutex<Sender<Event>>,
    answered: AtomicU64,
    withdrawn: AtomicU64,
}

/// What the history thread is told.
enum Event {
    /// The bucket ran dry: withdraw the queryable and the token for a while.
    Dry,
    /// The publisher is gone.
    Stop,
}

/// The history of one advanced publisher (declared without zenoh-ext's cache nor its detection
/// token): keep it as long as the publisher.
pub struct Latched {
    shared: Arc<Shared>,
    next_sn: u32,
}

/// How long the history stays withdrawn: until the bucket is full again.
const PAUSE: Duration = Duration::from_millis(1000 * BURST as u64 / RATE as u64);

impl Latched {
    /// Declares the queryable and detection token of `publisher` (on `key`) where zenoh-ext's
    /// cache and `publisher_detection` would, and the thread that withdraws them in a flood.
    pub fn declare(
        session: &zenoh::Session,
        key: &str,
        publisher: &zenoh_ext::AdvancedPublisher<'static>,
    ) -> Result<Latched> {
        let source = publisher.id();
        let at = format!("{key}/@adv/pub/{}/{}/_", source.zid(), source.eid());
        let (tx, rx) = channel();
        let shared = Arc::new(Shared {
            key: key.to_string(),
            source,
            last: Mutex::new(None),
            bucket: Mutex::new(Bucket::new(BURST, RATE, Instant::now())),
            closing: AtomicBool::new(false),
            to_thread: Mutex::new(tx),
            answered: AtomicU64::new(0),
            withdrawn: AtomicU64::new(0),
        });
        let history = declare_history(session, &at, &shared)?;
        let (session, s) = (session.clone(), shared.clone());
        std::thread::Builder::new()
            .name("bridge-ros2-hist".into())
            .spawn(move || history_thread(&session, &at, &s, rx, history))?;
        Ok(Latched { shared, next_sn: 0 })
    }

    /// Records the message just put (the advanced publisher numbers its puts from 0).
    pub fn record(&mut self, payload: &[u8], attachment: &[u8]) {
        let last = Last { payload: payload.to_vec(), attachment: attachment.to_vec(), sn: self.next_sn };
        *self.shared.last.lock().unwrap_or_else(|e| e.into_inner()) = Some(last);
        self.next_sn = self.next_sn.wrapping_add(1);
    }
}

impl Drop for Latched {
    fn drop(&mut self) {
        let _ = self.shared.to_thread.lock().unwrap_or_else(|e| e.into_inner()).send(Event::Stop);
    }
}

type History = (zenoh::query::Queryable<()>, zenoh::liveliness::LivelinessToken);

fn declare_history(session: &zenoh::Session, at: &str, shared: &Arc<Shared>) -> Result<History> {
    let s = shared.clone();
    let queryable = session
        .declare_queryable(at.to_string())
        .callback(move |q| s.answer(&q))
        .wait()
        .map_err(|e| anyhow!("declare the history queryable {at}: {e}"))?;
    let token =
        session.liveliness().declare_token(at.to_string()).wait().map_err(|e| anyhow!("token {at}: {e}"))?;
    Ok((queryable, token))
}

/// Holds the history's declarations; withdraws them for [`PAUSE`] each time the bucket runs dry.
fn history_thread(
    session: &zenoh::Session,
    at: &str,
    s: &Arc<Shared>,
    rx: Receiver<Event>,
    history: History,
) {
    let mut history = Some(history);
    loop {
        match rx.recv() {
            Ok(Event::Dry) => {}
            Ok(Event::Stop) | Err(_) => return,
        }
        drop(history.take());
        let n = s.withdrawn.fetch_add(1, Ordering::Relaxed) + 1;
        if n.is_power_of_two() {
            tracing::warn!(
                key = %s.key,
                withdrawn = n,
                answered = s.answered.load(Ordering::Relaxed),
                "ROS 2 history queries over {RATE}/s (burst {BURST}): history withdrawn for {} ms",
                PAUSE.as_millis()
            );
        }
        let until = Instant::now() + PAUSE;
        loop {
            match rx.recv_timeout(until.saturating_duration_since(Instant::now())) {
                Ok(Event::Dry) => {}
                Ok(Event::Stop) | Err(RecvTimeoutError::Disconnected) => return,
                Err(RecvTimeoutError::Timeout) => break,
            }
        }
        *s.bucket.lock().unwrap_or_else(|e| e.into_inner()) = Bucket::new(BURST, RATE, Instant::now());
        s.closing.store(false, Ordering::Release);
        match declare_history(session, at, s) {
            Ok(h) => history = Some(h),
            Err(e) => tracing::warn!("ROS 2 history of {}: {e:#}", s.key),
        }
    }
}

impl Shared {
    fn answer(&self, q: &zenoh::query::Query) {
        if !self.bucket.lock().unwrap_or_else(|e| e.into_inner()).take(Instant::now()) {
            if !self.closing.swap(true, Ordering::AcqRel) {
                let _ = self.to_thread.lock().unwrap_or_else(|e| e.into_inner()).send(Event::Dry);
            }
            return;
        }
        let last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        let Some(l) = last.as_ref() else { return };
        let p = q.parameters();
        if p.get("_max") == Some("0") || p.get("_sn").is_some_and(|r| !in_range(r, l.sn)) {
            return;
        }
        let r = q
            .reply(self.key.as_str(), l.payload.clone())
            .attachment(l.attachment.clone())
            .source_info(SourceInfo::new(self.source, l.sn))
            .wait();
        match r {
            Ok(()) => {
                self.answered.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::debug!(key = %self.key, "history reply: {e}"),
        }
    }
}

/// Whether `sn` is in zenoh-ext's `_sn` range text (`a..b`, `a..`, `..b`, `..`, `a`).
fn in_range(range: &str, sn: u32) -> bool {
    let bound = |s: Option<&str>| s.and_then(|s| s.parse::<u32>().ok());
    match range.split_once("..") {
        Some((a, b)) => bound(Some(a)).map_or(true, |a| sn >= a) && bound(Some(b)).map_or(true, |b| sn <= b),
        None => bound(Some(range)) == Some(sn),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn the_bucket_answers_a_burst_then_at_its_rate() {
        let t0 = Instant::now();
        let mut b = Bucket::new(BURST, RATE, t0);
        let burst = (0..1000).filter(|_| b.take(t0)).count();
        assert_eq!(burst, BURST as usize);
        // A flood of 10 000 queries over the next 10 s: RATE a second get an answer.
        let answered = (1..=10_000).filter(|i| b.take(t0 + Duration::from_millis(*i))).count();
        let want = 10 * RATE as usize;
        assert!((want - 1..=want).contains(&answered), "{answered} answers, want {want}");
        // Idle for a minute: a full burst again, never more.
        let t1 = t0 + Duration::from_secs(70);
        assert_eq!((0..1000).filter(|_| b.take(t1)).count(), BURST as usize);
    }

    #[test]
    fn sequence_ranges_read_as_zenoh_ext_writes_them() {
        assert!(in_range("..", 5) && in_range("3..", 5) && in_range("..5", 5) && in_range("5", 5));
        assert!(!in_range("6..", 5) && !in_range("..4", 5) && !in_range("4", 5) && in_range("2..9", 5));
    }
}
