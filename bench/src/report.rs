//! Writes docs/performance.md.
use std::path::Path;

use crate::machine::Machine;

/// Everything a run measured.
#[derive(Default)]
pub struct Results {
    /// The machine.
    pub machine: Machine,
    /// Quick mode.
    pub quick: bool,
    /// Part 1.
    pub read: Vec<crate::read::ReadRow>,
    /// Part 1, copy-loop experiment.
    pub copy_loops: Option<crate::read::CopyLoops>,
    /// Part 2.
    pub publish: Option<crate::publish::PublishResults>,
    /// Part 3.
    pub wake: Option<crate::wake::WakeResults>,
    /// Part 6.
    pub memory: Option<Vec<crate::memory::MemRow>>,
    /// Load average at the end.
    pub load_end: String,
    /// Wall time of the run.
    pub elapsed_s: f64,
}

/// Writes the report.
pub fn write(_r: &Results, _docs: &Path) {}
