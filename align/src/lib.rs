//! Several sound cards on one frame index: every follower card resampled onto the
//! master card's frames, steered from the cards' CLOCK_MONOTONIC chunk stamps.
//!
//! - [`Aligner`]: takes the chunks of a master and of followers in arrival order and puts
//!   out, for every master chunk, each follower's channels on the master's frames, with a
//!   per-frame validity, a lock flag and the alignment error estimate;
//! - [`timeline`]: a card's time line from its stamps (a lower envelope);
//! - [`control`]: the rate controller (the seed's, on the position error);
//! - [`resample`]: rubato's adjustable sinc resampler and the exact position of its output;
//! - [`sim`]: simulated cards sampling an analytic field (the ground truth);
//! - [`measure`]: the residual alignment from the pilot tones, SNR, ratio noise.
//!
//! The model, the flags and the measured figures are in the crate's README.md.
//!
//! ```
//! use align::{sim, Aligner, Config};
//! let mut rig = sim::Rig::standard(87.0, 0.0, 1);
//! let mut aligner = Aligner::new(Config::new(48_000.0, 2), &[2]).unwrap();
//! let mut locked = false;
//! while !locked {
//!     let (source, chunk) = rig.next_event();
//!     match source {
//!         sim::Source::Master => aligner.push_master(chunk.as_chunk()).unwrap(),
//!         sim::Source::Follower(i) => aligner.push_follower(i, chunk.as_chunk()).unwrap(),
//!     }
//!     while let Some(out) = aligner.pop() {
//!         locked = out.followers[0].locked;
//!     }
//! }
//! ```

#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod aligner;
pub mod control;
pub mod measure;
pub mod resample;
pub mod sim;
pub mod timeline;

pub use aligner::{Aligned, Aligner, Config, FollowerOutput};

/// One chunk of a card as its capture thread sees it.
#[derive(Clone, Copy, Debug)]
pub struct Chunk<'a> {
    /// Interleaved left-justified S32 samples, `frames * channels` of them.
    pub samples: &'a [i32],
    /// Frames in the chunk.
    pub frames: usize,
    /// CLOCK_MONOTONIC stamp of the chunk's first frame, ns, as the capture thread saw it.
    pub stamp_ns: u64,
    /// Frames were lost just before this chunk (an xrun, a reopened device).
    pub after_gap: bool,
}

/// What the aligner refuses, naming the bad value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum Error {
    /// A configuration value out of its range.
    #[error("bad configuration: {name} = {value} ({why})")]
    Config {
        /// The field.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The range it must lie in.
        why: &'static str,
    },
    /// A chunk whose sample count is not frames × channels.
    #[error("chunk of {frames} frames × {channels} channels carries {samples} samples")]
    ChunkShape {
        /// Frames the chunk says it has.
        frames: usize,
        /// The card's channels.
        channels: usize,
        /// Samples it carries.
        samples: usize,
    },
    /// A master chunk longer than the configured maximum.
    #[error("chunk of {frames} frames is longer than the maximum of {max}")]
    ChunkTooLong {
        /// Its frames.
        frames: usize,
        /// The maximum.
        max: usize,
    },
    /// A follower index past the followers given to [`Aligner::new`].
    #[error("follower {index} does not exist ({count} followers)")]
    NoSuchFollower {
        /// The index given.
        index: usize,
        /// Followers there are.
        count: usize,
    },
    /// A gap on the master: the master's frames are the port's frame index and have no
    /// gaps by definition.
    #[error("the master chunk after master frame {master_frame} is marked after a gap; the master clock cannot have gaps")]
    MasterGap {
        /// Master frames before the gap.
        master_frame: u64,
    },
    /// A step the resampler cannot take.
    #[error("resampler step {step} is outside {nominal} ×/÷ {max_relative}")]
    StepOutOfRange {
        /// The step asked for (input frames per output frame).
        step: f64,
        /// The nominal step.
        nominal: f64,
        /// The largest relative change.
        max_relative: f64,
    },
    /// rubato refused (construction or processing), with its message.
    #[error("resampler: {0}")]
    Resampler(String),
}
