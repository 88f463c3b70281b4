//! One line of the goal table and its verdict (the goals of each part are made in
//! `goals.rs` and, for the PipeWire comparison, `pipewire.rs`).

/// One line of the goal table.
pub(super) struct Goal {
    pub(super) part: &'static str,
    pub(super) goal: String,
    pub(super) measured: String,
    pub(super) met: Option<bool>,
    /// The repetitions fall on both sides of the threshold.
    pub(super) borderline: bool,
}

pub(super) fn verdict(g: &Goal) -> &'static str {
    match g.met {
        Some(true) if g.borderline => "**met** (borderline: repetitions on both sides)",
        Some(false) if g.borderline => "**missed** (borderline: repetitions on both sides)",
        Some(true) => "**met**",
        Some(false) => "**missed**",
        None if g.measured.starts_with("not measured") => "not measured",
        None => "measured (no numeric goal)",
    }
}
