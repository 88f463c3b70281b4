//! The broker's configuration (the command line of `bassd`): a leaf module the control loop
//! ([`crate::server`]) and the port hand-off ([`crate::handoff`]) both read.

use std::time::Duration;

use bassport::control::AcquireRequest;
use bassport::paths;

use crate::policy::DevicePolicy;
use crate::request::Limits;

/// Broker configuration (command line of `bassd`).
#[derive(Clone, Debug)]
pub struct Config {
    /// Broker name (port `bass-NAME.port`, socket `bass-NAME.sock`).
    pub name: String,
    /// Group allowed to control the broker and read its port, besides its own user.
    pub group: Option<u32>,
    /// SCHED_FIFO priority of the capture thread (0 = none).
    pub rt_priority: i32,
    /// Stall watchdog threshold in ms (0 = max(4 chunks, 250 ms)).
    pub stall_ms: u64,
    /// An Acquire to run at start-up.
    pub acquire: Option<AcquireRequest>,
    // --- hardening: device policy, bounds, connection limits ---
    /// Which devices clients may name (default policy + `--allow-device` patterns).
    pub policy: DevicePolicy,
    /// Operator bounds on Acquire requests (`--min-chunk-us`, `--max-rate`, ...).
    pub limits: Limits,
    /// A control connection with no request for this long is closed (`--idle-timeout-ms`).
    pub idle_timeout: Duration,
    /// What holds the port (`--port-backing`; see crate::handoff).
    pub port_backing: bassport::Backing,
    /// Longest wait for a device to open and configure (`--open-timeout-ms`).
    pub open_timeout: Duration,
    /// Under a service manager with an fd store: how long readers wait for a restarted
    /// broker to take its port back (`--restart-grace-ms`; 0 = do not use the store).
    pub restart_grace_ms: u32,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            name: paths::DEFAULT_NAME.into(),
            group: None,
            rt_priority: 70,
            stall_ms: 0,
            acquire: None,
            policy: DevicePolicy::default(),
            limits: Limits::default(),
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            port_backing: bassport::Backing::File,
            open_timeout: DEFAULT_OPEN_TIMEOUT,
            restart_grace_ms: crate::supervise::DEFAULT_RESTART_GRACE_MS,
        }
    }
}

/// Default memory cap of a port: 512 MiB (about 23 minutes of 48 kHz stereo).
pub use basskit::limits::DEFAULT_MAX_PORT_BYTES;
/// Default idle timeout of a control connection.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// Default bound on one device open (`bassd --open-timeout-ms`).
pub const DEFAULT_OPEN_TIMEOUT: Duration = Duration::from_secs(5);
