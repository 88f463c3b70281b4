//! The source state `serve` publishes (`NS/<broker>/state`, and the `info` queryable's
//! answer): what the port reader reports, completed with the instance, the Zenoh id and any
//! conflict ([`super::conflict`]), and put by a thread of its own so that the port reader
//! never waits for the network.

use std::sync::mpsc::SyncSender;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Result;
use bassport::Port;

use super::conflict::Conflicts;
use super::lock;
use crate::net::{BridgeState, SourceState};

/// A state is published on a change, when asked to (`force`), and at least this often.
const REPUBLISH: Duration = Duration::from_millis(500);

/// Publishes the source state (see the module's comment).
pub struct StatePublisher {
    /// The state the `info` queryable answers with.
    pub shared: Arc<Mutex<SourceState>>,
    /// Other instances of this name.
    pub conflicts: Arc<Mutex<Conflicts>>,
    /// To the state thread (one slot: a state that finds it full goes with the next refresh).
    pub tx: SyncSender<Vec<u8>>,
    /// This instance (hex).
    pub instance: String,
    /// This session's Zenoh id.
    pub zid: String,
    /// `--insecure`.
    pub insecure: bool,
    /// When a state was last handed to the state thread.
    pub last: Option<Instant>,
    /// Remote control requests answered and refused so far.
    pub control: Arc<crate::control::Audit>,
}

impl StatePublisher {
    /// Publishes `s` if it changed, if `force`, or if the last one is [`REPUBLISH`] old.
    pub fn publish(&mut self, s: &SourceState, force: bool) {
        let conflict = {
            let mut c = lock(&self.conflicts);
            for line in c.reminders(Instant::now()) {
                tracing::error!("{line}");
            }
            c.describe()
        };
        let mut cur = lock(&self.shared);
        let changed = (cur.state, cur.epoch, cur.error_code, &cur.conflict)
            != (s.state, s.epoch, s.error_code, &conflict);
        *cur = SourceState {
            instance: self.instance.clone(),
            zid: self.zid.clone(),
            conflict,
            insecure: self.insecure,
            control_requests: self.control.answered(),
            control_refused: self.control.refused(),
            ..s.clone()
        };
        if changed || force || self.last.map_or(true, |t| t.elapsed() >= REPUBLISH) {
            self.last = Some(Instant::now());
            // Through the state thread: a put may block (the chunks' put holds the link's
            // queue while it waits on a dead link), the port reader must not.
            if let Ok(b) = serde_json::to_vec(&*cur) {
                let _ = self.tx.try_send(b);
            }
        }
    }
}

/// What the port reader knows of a port it follows, for its state.
pub struct Followed {
    /// Acquisition epoch.
    pub epoch: u64,
    /// Geometry.
    pub geometry: bassport::Geometry,
}

/// The state of `port` for the state message: `state`, the port's error and newest frame,
/// and serve's counters of this port.
pub fn state_of(port: &Port, f: &Followed, state: BridgeState, sent: u64, dropped: u64) -> SourceState {
    let i = port.info().ok();
    let g = &f.geometry;
    SourceState {
        state,
        error_code: i.as_ref().map_or(0, |i| i.error_code),
        message: i.as_ref().map_or(String::new(), |i| i.message.clone()),
        epoch: f.epoch,
        channels: g.channels,
        sample_rate: g.sample_rate,
        frames_per_chunk: g.frames_per_chunk,
        chunks_on_port: g.chunks_on_port,
        last_frame_index: i.as_ref().map_or(0, |i| i.last_frame_index),
        chunks_sent: sent,
        chunks_dropped: dropped,
        // Instance, Zenoh id and conflict: filled in by `StatePublisher::publish`.
        ..Default::default()
    }
}

/// The port's state, `gone` when its writer process died.
pub fn current_state(port: &Port) -> Result<BridgeState> {
    let i = port.info()?;
    Ok(if i.writer_alive { BridgeState::of_port(i.state) } else { BridgeState::Gone })
}

#[cfg(test)]
mod tests {
    use crate::net::{BridgeState, SourceState};

    /// The JSON names are the lowercase ones (the network suite and older mirrors read them).
    #[test]
    fn the_published_state_is_a_lowercase_name_and_starting_is_one_of_them() {
        let all = [
            (BridgeState::Idle, "idle"),
            (BridgeState::Starting, "starting"),
            (BridgeState::Capturing, "capturing"),
            (BridgeState::Stopped, "stopped"),
            (BridgeState::Error, "error"),
            (BridgeState::Gone, "gone"),
        ];
        for (s, name) in all {
            assert_eq!(serde_json::to_string(&s).unwrap(), format!("\"{name}\""));
            let st = SourceState { state: s, ..Default::default() };
            let json = serde_json::to_string(&st).unwrap();
            assert!(json.contains(&format!("\"state\":\"{name}\"")), "{json}");
            assert_eq!(serde_json::from_str::<SourceState>(&json).unwrap().state, s);
        }
        assert_eq!(BridgeState::of_port(Some(bassport::State::Starting)), BridgeState::Starting);
        assert_eq!(BridgeState::of_port(Some(bassport::State::Superseded)), BridgeState::Gone);
        // A state this version does not know is not a state message.
        let json = serde_json::to_string(&SourceState::default()).unwrap().replace("\"gone\"", "\"melting\"");
        assert!(json.contains("melting") && serde_json::from_str::<SourceState>(&json).is_err());
    }
}
