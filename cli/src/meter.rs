//! `bass meter`: a live level meter, one line per channel (RMS and peak dBFS bars, clip and
//! gap markers), redrawn in place on a terminal like `arecord -V`; plain lines when stdout is
//! not a terminal; `--json` prints one object per update. More than 8 channels use a compact
//! form (4 channels per line).

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::Result;
use bassport::Error;
use serde::Serialize;

use crate::blocks::{dbfs, gaps_in, levels};
use crate::follow::{after_stop, open_port, AfterStop, Outage};
use crate::out::{self, note, outln};
use basskit::args::parse_seconds;

/// A peak at or above this (dBFS) counts as clipping.
pub const CLIP_DBFS: f64 = -0.01;
/// The bars span this range (dBFS).
const FLOOR_DBFS: f64 = -60.0;

/// Options of `bass meter`.
#[derive(clap::Args, Debug, Clone)]
pub struct MeterArgs {
    /// Seconds of audio per update
    #[arg(short = 'i', long, value_name = "S", default_value = "0.1", value_parser = parse_seconds)]
    pub interval: f64,
    /// Stop after N updates [default: no limit]
    #[arg(short = 'n', long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub count: Option<u64>,
    /// Stop after S seconds
    #[arg(short = 'd', long = "duration", value_name = "S", value_parser = parse_seconds)]
    pub duration: Option<f64>,
    /// One JSON object per update
    #[arg(long)]
    pub json: bool,
    /// End with an error when no frame comes for S seconds after a device error or a broker
    /// gone (a replica's link outage, a restart) [default: wait for the acquisition to go on]
    #[arg(long, value_name = "S", value_parser = parse_seconds)]
    pub max_outage: Option<f64>,
}

#[derive(Serialize)]
struct Update {
    epoch: u64,
    first_frame: u64,
    frames: u64,
    loss: u64,
    gap_frames: u64,
    rms_dbfs: Vec<Option<f64>>,
    peak_dbfs: Vec<Option<f64>>,
    clip: Vec<bool>,
}

fn bar(db: Option<f64>, width: usize) -> String {
    let x = db.map_or(0.0, |d| ((d - FLOOR_DBFS) / -FLOOR_DBFS).clamp(0.0, 1.0));
    let n = (x * width as f64).round() as usize;
    format!("{}{}", "#".repeat(n), "-".repeat(width - n))
}

fn num(db: Option<f64>) -> String {
    db.map_or("  -inf".into(), |d| format!("{d:6.1}"))
}

/// The text lines of one update.
fn render(u: &Update) -> Vec<String> {
    let ch = u.rms_dbfs.len();
    let marks = |c: usize| {
        let mut m = String::new();
        if u.clip[c] {
            m.push_str(" CLIP");
        }
        m
    };
    let mut lines = Vec::new();
    if ch <= 8 {
        for c in 0..ch {
            lines.push(format!(
                "ch{c:<2} {} rms {} peak {} dBFS{}",
                bar(u.rms_dbfs[c], 40),
                num(u.rms_dbfs[c]),
                num(u.peak_dbfs[c]),
                marks(c)
            ));
        }
    } else {
        for row in (0..ch).collect::<Vec<_>>().chunks(4) {
            let cells: Vec<String> = row
                .iter()
                .map(|&c| {
                    format!(
                        "{c:>2} {} {}{}",
                        bar(u.rms_dbfs[c], 10),
                        num(u.peak_dbfs[c]),
                        if u.clip[c] { "!" } else { " " }
                    )
                })
                .collect();
            lines.push(cells.join(" "));
        }
    }
    lines.push(format!(
        "frames {}..{}  gap {}{}  loss {}",
        u.first_frame,
        u.first_frame + u.frames - 1,
        u.gap_frames,
        if u.gap_frames > 0 { " GAP" } else { "" },
        u.loss
    ));
    lines
}

/// Runs `bass meter` on broker `name`.
pub fn run(name: &str, a: &MeterArgs, timeout: Duration) -> Result<()> {
    let end = a.duration.and_then(|s| Instant::now().checked_add(Duration::from_secs_f64(s)));
    let tty = std::io::stdout().is_terminal() && !a.json;
    let mut port = open_port(name, timeout, None)?;
    let mut updates = 0u64;
    let mut drawn = 0usize;
    let mut outage = Outage::new(a.max_outage);
    'acquisition: loop {
        let g = port.geometry().clone();
        let per = ((a.interval * f64::from(g.sample_rate)).round() as u64)
            .clamp(1, port.frames_on_port().max(2) / 2);
        let mut bufs = vec![vec![0i32; per as usize]; g.channels as usize];
        let mut nfr = port.info()?.last_frame_index + 1;
        loop {
            if a.count.is_some_and(|c| updates >= c) || end.is_some_and(|e| Instant::now() >= e) {
                return Ok(());
            }
            let (mut got, mut loss, mut first) = (0usize, 0u64, nfr);
            while got < per as usize {
                if end.is_some_and(|e| Instant::now() >= e) {
                    return Ok(());
                }
                match port.wait(nfr + (per as usize - got) as u64 - 1, Duration::from_millis(200)) {
                    Ok(_) => {
                        if let Some(text) = outage.resumed() {
                            note!("{text}");
                        }
                    }
                    Err(Error::Timeout { .. }) | Err(Error::Interrupted) => {}
                    Err(Error::Restarted) => {
                        port = open_port(name, timeout, Some(port.epoch()))?;
                        continue 'acquisition;
                    }
                    Err(Error::Stopped { last }) => match after_stop(name, &port, timeout)? {
                        AfterStop::Restarted => {
                            port = open_port(name, timeout, Some(port.epoch()))?;
                            continue 'acquisition;
                        }
                        AfterStop::Stopped => {
                            if !a.json {
                                outln!("-- acquisition stopped at frame {last}")?;
                            }
                            return Ok(());
                        }
                    },
                    Err(e @ (Error::Device { .. } | Error::WriterGone { .. })) => {
                        if let Some(text) = outage.pause(e, name)? {
                            note!("{text}");
                        }
                        continue;
                    }
                    Err(e) => return Err(e.into()),
                }
                let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[got..]).collect();
                let r = port.get_audio_data(per as usize - got, &mut nfr, &mut outs)?;
                if r.loss > 0 {
                    loss += r.loss;
                    for b in bufs.iter_mut() {
                        b.copy_within(got..got + r.frames, 0);
                    }
                    got = 0;
                    first = nfr - r.frames as u64;
                }
                got += r.frames;
            }
            updates += 1;
            let lv = levels(&bufs);
            let u = Update {
                epoch: port.epoch(),
                first_frame: first,
                frames: per,
                loss,
                gap_frames: gaps_in(&port, first, first + per - 1, &bufs).0,
                rms_dbfs: lv.iter().map(|l| dbfs(l.0)).collect(),
                peak_dbfs: lv.iter().map(|l| dbfs(l.1)).collect(),
                clip: lv.iter().map(|l| dbfs(l.1).is_some_and(|d| d >= CLIP_DBFS)).collect(),
            };
            // One write per update: a terminal redraws it at once, a closed pipe ends the meter.
            let mut text = String::new();
            if a.json {
                writeln!(text, "{}", serde_json::to_string(&u)?)?;
            } else {
                let lines = render(&u);
                if tty && drawn > 0 {
                    // Back to the first line of the previous update, redraw over it.
                    write!(text, "\x1b[{drawn}F")?;
                }
                for l in &lines {
                    if tty {
                        text.push_str("\x1b[2K");
                    }
                    writeln!(text, "{l}")?;
                }
                drawn = lines.len();
            }
            out::bytes(text.as_bytes())?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn update(ch: usize) -> Update {
        Update {
            epoch: 1,
            first_frame: 1,
            frames: 100,
            loss: 0,
            gap_frames: 100,
            rms_dbfs: (0..ch).map(|c| Some(-3.0 * c as f64)).collect(),
            peak_dbfs: (0..ch).map(|c| if c == 0 { Some(0.0) } else { None }).collect(),
            clip: (0..ch).map(|c| c == 0).collect(),
        }
    }

    #[test]
    fn one_line_per_channel_up_to_8_then_compact() {
        let l = render(&update(2));
        assert_eq!(l.len(), 3);
        assert!(l[0].starts_with("ch0 ") && l[0].ends_with("CLIP"), "{}", l[0]);
        assert!(l[1].contains("peak   -inf"), "{}", l[1]);
        assert!(l[2].contains("GAP"));
        assert_eq!(render(&update(64)).len(), 16 + 1);
        assert_eq!(render(&update(1)).len(), 2);
        assert_eq!(bar(Some(0.0), 10), "##########");
        assert_eq!(bar(None, 4), "----");
        assert_eq!(bar(Some(-30.0), 10), "#####-----");
    }
}
