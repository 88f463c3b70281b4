//! `bass record --check FILE.wav`: a WAV and its sidecar, held against each other.

use std::fs::File;
use std::path::Path;

use anyhow::Result;
use bassport::format::chunk_flags;

use crate::wav;
use basskit::sidecar::{self, Sidecar};

/// `bass record --check FILE.wav`: the one-line summary if the WAV and its sidecar agree,
/// else every problem found.
pub fn check(path: &Path) -> Result<String, Vec<String>> {
    let side = match Sidecar::load_for(path) {
        Ok(Some(s)) => s,
        Ok(None) => return Err(vec![format!("no sidecar {}", sidecar::path_of(path).display())]),
        Err(e) => return Err(vec![e]),
    };
    let mut f = File::open(path).map_err(|e| vec![format!("{}: {e}", path.display())])?;
    let info = wav::parse(&mut f).map_err(|e| vec![format!("{}: {e}", path.display())])?;
    let (a, r) = (&side.acquisition, &side.recording);
    let mut v = Vec::new();
    if info.sample_rate != a.sample_rate {
        v.push(format!("the WAV's rate is {} Hz; the sidecar's {}", info.sample_rate, a.sample_rate));
    }
    if usize::from(info.channels) != r.channels.len() {
        v.push(format!("the WAV has {} channels; the sidecar records {}", info.channels, r.channels.len()));
    }
    if info.bits != r.bits {
        v.push(format!("the WAV has {} bits per sample; the sidecar says {}", info.bits, r.bits));
    }
    let fb = u64::from(r.bits / 8) * r.channels.len() as u64;
    if u64::from(info.block_align) != fb {
        v.push(format!(
            "the WAV's block align is {}; {} channels of {} bits need {fb}",
            info.block_align,
            r.channels.len(),
            r.bits
        ));
    }
    let found = info.format().map_or(format!("format tag {:#x}", info.tag), |f| f.name().to_owned());
    if let Some(w) = &r.wav_format {
        if *w != found {
            v.push(format!("the WAV header is {found}; the sidecar says {w}"));
        }
    }
    let data = u64::from(info.data_size);
    if fb > 0 && data % fb != 0 {
        v.push(format!("the WAV's data chunk holds {data} bytes, not whole frames of {fb}"));
    }
    let frames = data.checked_div(fb).unwrap_or(0);
    if frames != r.frames {
        v.push(format!("the WAV holds {frames} frames; the sidecar says {}", r.frames));
    }
    let extent = info.data_offset + data + (data & 1);
    if extent != r.bytes {
        v.push(format!("the WAV's header describes {extent} bytes; the sidecar says {}", r.bytes));
    }
    if u64::from(info.riff_size) + 8 != extent {
        v.push(format!("the RIFF size is {}; the chunks take {}", info.riff_size, extent - 8));
    }
    if info.file_len < info.data_offset + data {
        v.push(format!("the file holds {} bytes; its header claims {extent}", info.file_len));
    } else if info.file_len > extent && !r.in_progress {
        v.push(format!("{} bytes after the data chunk", info.file_len - extent));
    }
    if (r.seconds - r.frames as f64 / f64::from(a.sample_rate.max(1))).abs() > 1e-6 {
        v.push(format!("recording.seconds {} is not frames / rate", r.seconds));
    }
    if v.is_empty() {
        v.extend(zeros_where_due(path, &side));
    }
    if !v.is_empty() {
        return Err(v);
    }
    let mut line = format!(
        "ok: {}: {} frames ({:.3} s), frames {}..={} of epoch {}, {} channels, {} bits, {found}; {} frames lost in {} losses, {} gap frames, {} chunk rows{}",
        path.display(),
        r.frames,
        r.seconds,
        r.first_frame,
        side.last_frame(),
        a.epoch,
        r.channels.len(),
        r.bits,
        r.lost_frames,
        side.losses.len(),
        r.gap_frames,
        side.chunks.len(),
        side.ext_summary()
    );
    if let Some(q) = r.requested_first_frame {
        line += &format!("; started {} frames after the requested frame {q}", r.started_after_requested);
    }
    if r.in_progress {
        line += "; in progress: the last checkpoint of a recorder that did not finish (killed?)";
    }
    Ok(line)
}

/// The frames of losses and of GAP chunks must be zeros in the WAV, and so must a chunk's
/// missing channels (`missing_channels`) among those recorded.
pub(super) fn zeros_where_due(path: &Path, side: &Sidecar) -> Vec<String> {
    let (first, last) = (side.recording.first_frame, side.last_frame());
    let all = u64::MAX;
    let mut runs: Vec<(u64, u64, &str, u64)> =
        side.losses.iter().map(|l| (l.first_frame, l.first_frame + l.frames - 1, "lost", all)).collect();
    // File channel i is port channel channels[i]: the file channels of a port mask.
    let in_file = |m: u64| {
        let on = side.recording.channels.iter().enumerate().filter(|(_, &c)| c < 64 && m >> c & 1 != 0);
        on.fold(0u64, |acc, (i, _)| acc | 1 << i)
    };
    for c in &side.chunks {
        let (a, b) = (c.first_frame.max(first), (c.first_frame + u64::from(c.frames) - 1).min(last));
        if a > b {
            continue;
        }
        if c.flags & chunk_flags::GAP != 0 {
            runs.push((a, b, "GAP", all));
        } else if in_file(c.missing_channels) != 0 {
            runs.push((a, b, "missing-channel", in_file(c.missing_channels)));
        }
    }
    let mut r = match hound::WavReader::open(path) {
        Ok(r) => r,
        Err(e) => return vec![format!("hound cannot read {}: {e}", path.display())],
    };
    let ch = u64::from(r.spec().channels);
    let mut v = Vec::new();
    for (a, b, what, mask) in runs {
        let Ok(at) = u32::try_from(a - first) else { continue };
        if let Err(e) = r.seek(at) {
            v.push(format!("seek to frame {a}: {e}"));
            continue;
        }
        let n = (b - a + 1) * ch;
        let due = |i: usize| mask >> (i as u64 % ch) & 1 != 0;
        let nonzero =
            r.samples::<i32>().take(n as usize).enumerate().position(|(i, s)| due(i) && !matches!(s, Ok(0)));
        if let Some(i) = nonzero {
            v.push(format!(
                "{what} frame {} is not zero in the WAV (frames {a}..={b} must be{})",
                a + i as u64 / ch,
                if mask == all { String::new() } else { format!(", in file channel {}", i as u64 % ch) }
            ));
        }
    }
    v
}
