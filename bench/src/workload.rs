//! The workload parts 7 (PipeWire) and 8 (callback streams against JACK) share: client counts,
//! the chunk (PipeWire's quantum) and the rate.

/// Client counts.
pub const CLIENTS: &[usize] = &[1, 8, 64];
/// PipeWire's quantum = bass's chunk (frames).
pub const QUANTUM: u32 = 256;
/// Sample rate of both.
pub const RATE: u32 = 48000;
