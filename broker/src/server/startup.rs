//! The configured acquisition (`bassd --acquire DEVICE`, bassd.conf's BASSD_ARGS): started
//! when the broker starts, and tried again while its device is missing or fails to open — a
//! USB array that enumerates after bassd, a jackd started later, a card name mistyped in
//! the configuration. Each failure is logged once per attempt with its reason; meanwhile
//! Status (and the systemd STATUS line) says what the broker waits for and when it tries next:
//!
//! ```text
//!  start ─ open hw:2,0 ✗ ─ 0.5 s ─ ✗ ─ 1 s ─ ✗ ─ 2 s ─ ✗ ─ 4 s ─ ✗ ─ 8 s ─ ✗ ─ 10 s ─ ✓ capturing
//!          Status: idle, "waiting for device "hw:2,0": …; next try in 4.0 s (attempt 3)"
//! ```
//!
//! An Acquire or a Stop from a client takes over: the retries end (the operator chose).

use bassport::control::{AcquireRequest, ErrorKind, Reply, Status};
use bassport::format::State;
use bassport::sys::monotonic_ns;

use super::Broker;

/// The wait before the second try; doubled after each failure up to [`MAX_BACKOFF_NS`].
pub const FIRST_BACKOFF_NS: u64 = 500_000_000;
/// The longest wait between two tries.
pub const MAX_BACKOFF_NS: u64 = 10_000_000_000;

/// The configured acquisition while it has not started.
#[derive(Debug)]
pub(super) struct Startup {
    request: AcquireRequest,
    /// Tries made so far.
    attempt: u32,
    /// CLOCK_MONOTONIC of the next try (when not in flight).
    next_ns: u64,
    /// Why the last try failed.
    last_error: Option<String>,
    /// A try's device open is under way.
    in_flight: bool,
}

/// The wait after the `attempt`-th failed try: 0.5 s, 1 s, 2 s, ... at most 10 s.
pub fn backoff_ns(attempt: u32) -> u64 {
    FIRST_BACKOFF_NS.saturating_mul(1u64 << attempt.saturating_sub(1).min(20)).min(MAX_BACKOFF_NS)
}

impl Broker {
    /// Starts the configured acquisition, and keeps it to try again until it runs.
    pub(super) fn start_configured(&mut self, request: &AcquireRequest) {
        self.startup = Some(Startup {
            request: request.clone(),
            attempt: 0,
            next_ns: 0,
            last_error: None,
            in_flight: false,
        });
        self.try_configured();
    }

    fn try_configured(&mut self) {
        let Some(s) = self.startup.as_mut() else { return };
        s.attempt += 1;
        s.in_flight = true;
        let request = s.request.clone();
        self.last_open_failure = None;
        match self.acquire(&request, self.own_uid, None) {
            // A request refused as such (bad numbers, the device policy) is refused again
            // every time: said once and kept in Status, not tried again.
            Some(Reply::Error { kind: ErrorKind::InvalidArgument | ErrorKind::Permission, message }) => {
                tracing::error!("the configured acquisition of {:?} is refused: {message}", request.device);
                if let Some(s) = self.startup.as_mut() {
                    (s.in_flight, s.next_ns) = (false, u64::MAX);
                    s.last_error = Some(format!("refused: {message}"));
                }
            }
            Some(Reply::Error { message, .. }) => self.configured_failed(message),
            _ => {}
        }
    }

    fn configured_failed(&mut self, message: String) {
        let Some(s) = self.startup.as_mut() else { return };
        let wait = backoff_ns(s.attempt);
        s.next_ns = monotonic_ns().saturating_add(wait);
        s.in_flight = false;
        tracing::warn!(
            attempt = s.attempt,
            "the configured acquisition of {:?} did not start: {message}; next try in {:.1} s",
            s.request.device,
            wait as f64 / 1e9
        );
        s.last_error = Some(message);
    }

    /// Every turn of the control loop: a finished try is judged, a due one made.
    pub(super) fn tick_configured(&mut self, now: u64) {
        let Some(s) = &self.startup else { return };
        if self.opening.is_some() {
            return;
        }
        if s.in_flight {
            if self.current.as_ref().is_some_and(|a| a.running()) {
                if s.attempt > 1 {
                    tracing::info!(
                        attempts = s.attempt,
                        "the configured acquisition of {:?} started",
                        s.request.device
                    );
                }
                self.startup = None;
                return;
            }
            let why = self.last_open_failure.take().unwrap_or_else(|| "the device open failed".into());
            self.configured_failed(why);
        } else if now >= s.next_ns {
            self.try_configured();
        }
    }

    /// A client's Acquire or Stop: the operator takes over, the configured acquisition is not
    /// tried again.
    pub(super) fn forget_configured(&mut self) {
        if let Some(s) = self.startup.take() {
            if s.attempt > 1 || !s.in_flight {
                tracing::info!(
                    "the configured acquisition of {:?} is no longer tried (a client's request takes over)",
                    s.request.device
                );
            }
        }
    }

    /// While the configured acquisition waits for its device (no port yet): Status says so.
    pub(super) fn configured_status(&self, s: &mut Status, now: u64) {
        let Some(st) = self.startup.as_ref().filter(|st| !st.in_flight && self.current.is_none()) else {
            return;
        };
        s.state = State::Idle as u32;
        s.device = st.request.device.clone();
        let error = st.last_error.as_deref().unwrap_or("not opened yet");
        s.message = if st.next_ns == u64::MAX {
            format!(
                "waiting for device {:?}: {error}; not tried again: fix bassd's configuration",
                st.request.device
            )
        } else {
            format!(
                "waiting for device {:?}: {error}; next try in {:.1} s (attempt {}); check the device \
                 name in bassd's configuration (bass devices lists them), or plug the device in",
                st.request.device,
                st.next_ns.saturating_sub(now) as f64 / 1e9,
                st.attempt + 1
            )
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backoff_doubles_from_half_a_second_to_ten() {
        let waits: Vec<u64> = (1..=8).map(|a| backoff_ns(a) / 1_000_000).collect();
        assert_eq!(waits, [500, 1000, 2000, 4000, 8000, 10_000, 10_000, 10_000]);
        assert_eq!(backoff_ns(u32::MAX), MAX_BACKOFF_NS);
    }
}
