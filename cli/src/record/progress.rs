//! Progress output while recording.

use std::io::IsTerminal;

use crate::blocks::dbfs;

/// Progress: an indicatif bar on a terminal, plain lines once per second otherwise.
pub(super) struct Progress {
    pub(super) bar: Option<indicatif::ProgressBar>,
    pub(super) plain: bool,
    pub(super) rate: u32,
}

impl Progress {
    pub(super) fn new(quiet: bool, limit: Option<u64>, rate: u32) -> Progress {
        if quiet {
            return Progress { bar: None, plain: false, rate };
        }
        if std::io::stderr().is_terminal() {
            let bar = match limit {
                Some(n) => indicatif::ProgressBar::new(n),
                None => indicatif::ProgressBar::new_spinner(),
            };
            let style =
                indicatif::ProgressStyle::with_template("{elapsed_precise} {bar:30} {pos} frames {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
            bar.set_style(style);
            Progress { bar: Some(bar), plain: false, rate }
        } else {
            Progress { bar: None, plain: true, rate }
        }
    }

    pub(super) fn update(&self, frames: u64, bytes: u64, gaps: u64, lost: u64, peaks: &[f64]) {
        let levels: Vec<String> = peaks
            .iter()
            .enumerate()
            .map(|(c, p)| format!("ch{c} {}", dbfs(*p).map_or("-inf".into(), |d| format!("{d:.1}"))))
            .collect();
        let msg = format!(
            "{:.1} s, {:.1} MiB, gaps {gaps}, lost {lost}, peak dBFS {}",
            frames as f64 / f64::from(self.rate),
            bytes as f64 / 1048576.0,
            levels.join(" ")
        );
        if let Some(b) = &self.bar {
            b.set_position(frames);
            b.set_message(msg);
        } else if self.plain {
            crate::out::note!("bass record: {frames} frames, {msg}");
        }
    }

    pub(super) fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
