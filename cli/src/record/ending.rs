//! How a recording ends: the file closed (and what a failed write left), then the summary.

use anyhow::Result;
use basskit::sidecar;

use crate::exit::{self, Exit};
use crate::out::outln;

use super::mcap_out;
use super::recording::{Ended, Out, Recording};
use super::RecordArgs;

/// Closes the recording (`Recording::finish`); a write that failed (now or while recording)
/// is an error naming the file, the OS error and the frames kept.
pub(super) fn close(
    a: &RecordArgs,
    rec: &mut Recording,
    reason: &str,
    failure: Option<&Ended>,
    layout: Option<&mcap_out::Layout>,
) -> Result<sidecar::Sidecar> {
    let disk_failed = matches!(failure, Some(Ended::Disk(_)));
    let xdf = matches!(rec.out, Out::Xdf(_));
    let done = rec.finish(reason, disk_failed).map_err(|e| {
        let what = match layout {
            Some(l) => format!("the MCAP file {} could not be closed", l.file().display()),
            None if xdf => "the file could not be closed".to_owned(),
            None => format!("its sidecar {} could not be written", rec.side_path.display()),
        };
        Exit::new(
            exit::FAILURE,
            format!("{}: the recording ended ({reason}), but {what}: {e}", a.file.display()),
        )
    })?;
    let error = match (failure, &done.error) {
        (Some(Ended::Disk(e)), _) => Some(e.to_string()),
        (_, Some(e)) => Some(e.to_string()),
        _ if done.cut > 0 => Some("no space left for the sidecar".into()),
        _ => None,
    };
    let Some(error) = error else { return Ok(done.side) };
    let frames = done.side.recording.frames;
    let closed_at_checkpoint = |file: &std::path::Path, what: &str| {
        let cut =
            if done.cut > 0 { format!(" (the last {} frames did not fit)", done.cut) } else { String::new() };
        format!("{}: {error}: the recording ends with {frames} frames written{cut}; the file is closed at its last checkpoint, {what} (`bass record --check` passes it)", file.display())
    };
    let text = match layout {
        None if xdf => closed_at_checkpoint(
            &a.file,
            "with the footers of what it holds if they fitted (XDF readers read it to the end)",
        ),
        Some(l) => {
            let cut = if done.cut > 0 {
                format!(" (the last {} frames did not fit)", done.cut)
            } else {
                String::new()
            };
            format!(
                "{}: {error}: the recording ends with {frames} frames written{cut}; the file is closed at its last checkpoint, without a summary (readers read it front to back; `bass record --check` passes it)",
                l.file().display()
            )
        }
        None => {
            let room = if done.cut > 0 {
                format!(" ({} frames cut to make room for the sidecar)", done.cut)
            } else {
                String::new()
            };
            format!(
                "{}: {error}: the recording ends with {frames} frames written{room}; the header and the sidecar {} describe them",
                a.file.display(),
                rec.side_path.display()
            )
        }
    };
    Err(Exit::new(exit::FAILURE, text).into())
}

/// The summary line (or JSON object) of a finished recording.
pub(super) fn summary(
    a: &RecordArgs,
    r: &sidecar::Recording,
    rec: &Recording,
    layout: Option<&mcap_out::Layout>,
) -> Result<()> {
    if a.json {
        return outln!("{}", serde_json::to_string(r)?);
    }
    if a.quiet {
        return Ok(());
    }
    let head = format!(
        "recorded {} frames ({:.3} s) from frame {} to {}: {} bytes, {} gap frames, {} frames lost by the recorder; {}",
        r.frames,
        r.seconds,
        r.first_frame,
        layout.map_or(a.file.as_path(), |l| l.file()).display(),
        r.bytes,
        r.gap_frames,
        r.lost_frames,
        r.end
    );
    match layout {
        Some(mcap_out::Layout::Bag { dir, .. }) => outln!("{head}; bag directory {}", dir.display()),
        Some(mcap_out::Layout::File(_)) => outln!("{head}"),
        None if matches!(rec.out, Out::Xdf(_)) => outln!("{head}"),
        None => outln!("{head}; sidecar {}", rec.side_path.display()),
    }
}
