//! `bass blocks`: reads blocks of N frames from the port like the BASC client and prints one
//! line (or one JSON object, `--json`) per block: first frame, frames, frames lost by this
//! reader, zero-filled gap frames (device overruns, restarts, a replica's outages: the frames
//! the port counts in `gap_frames`, [`gaps_in`]), RMS and peak level per channel.
//!
//! It follows an Acquire that interrupts the one it reads (a new epoch: it reopens the port)
//! and ends only on a real Stop (exit 0), a device error (exit 5), the broker's death (exit 3)
//! or its own limits (`--count`, `--seconds`).

use std::time::{Duration, Instant};

use anyhow::Result;
use bassport::format::{chunk_flags, State};
use bassport::{Error, Port};
use serde::Serialize;

use crate::follow::{after_stop, open_port, AfterStop, Outage};
use crate::out::outln;
use basskit::args::parse_seconds;

/// Largest block (frames per channel) `--block` accepts.
pub const MAX_BLOCK: u64 = 1 << 24;

/// Options of `bass blocks`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct BlocksArgs {
    /// Frames per block [default: the port's nFramesPerChunk]
    #[arg(short = 'b', long, value_name = "N",
          value_parser = clap::value_parser!(u64).range(1..=MAX_BLOCK))]
    pub block: Option<u64>,
    /// Stop after N blocks [default: no limit]
    #[arg(short = 'n', long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub count: Option<u64>,
    /// Stop after S seconds [default: no limit]
    #[arg(short = 'd', long = "seconds", visible_alias = "duration", value_name = "S",
          value_parser = parse_seconds)]
    pub seconds: Option<f64>,
    /// First frame, counted from the first frame not yet published (negative: frames already
    /// on the port; -12000 = the last 12000 frames)
    #[arg(long, value_name = "N", default_value_t = 0, allow_negative_numbers = true)]
    pub offset: i64,
    /// One JSON object per line instead of text
    #[arg(long)]
    pub json: bool,
    /// End with an error when no frame comes for S seconds after a device error or a broker
    /// gone (a replica's link outage, a restart) [default: wait for the acquisition to go on]
    #[arg(long, value_name = "S", value_parser = parse_seconds)]
    pub max_outage: Option<f64>,
}

/// RMS and peak level (full scale = 1.0) of each channel of a block.
pub fn levels(bufs: &[Vec<i32>]) -> Vec<(f64, f64)> {
    bufs.iter()
        .map(|b| {
            let (mut sum, mut peak) = (0f64, 0f64);
            for &s in b {
                let x = f64::from(s) / 2_147_483_648.0;
                sum += x * x;
                peak = peak.max(x.abs());
            }
            ((sum / b.len().max(1) as f64).sqrt(), peak)
        })
        .collect()
}

/// A level in dBFS (None for silence: JSON `null`, text `-inf`).
pub fn dbfs(x: f64) -> Option<f64> {
    (x > 0.0).then(|| 20.0 * x.log10())
}

fn dbfs_text(x: f64) -> String {
    dbfs(x).map_or_else(|| "  -inf".into(), |d| format!("{d:6.1}"))
}

/// Zero-filled frames and discontinuities among frames `first..=last`, whose samples are
/// `bufs` (`bufs[c][i]`: channel `c`, frame `first + i`): every frame of a chunk flagged GAP,
/// and in a chunk flagged DISCONTINUITY (data and zeros mixed: an overrun's or a restart's
/// fill ends or starts inside it) the frames that are zero in every channel — the port counts
/// the same frames in its `gap_frames`, but does not say which frames of such a chunk it
/// filled, so a frame of digital silence there counts too. Chunks that already left the
/// window are not counted.
pub fn gaps_in(port: &Port, first: u64, last: u64, bufs: &[Vec<i32>]) -> (u64, u32) {
    let nfpc = u64::from(port.geometry().frames_per_chunk.max(1));
    let (mut gap, mut disc) = (0u64, 0u32);
    let mut chunk = (first - 1) / nfpc;
    let zero = |f: u64| bufs.iter().all(|b| b.get((f - first) as usize) == Some(&0));
    while chunk * nfpc < last {
        let (c0, c1) = (chunk * nfpc + 1, (chunk + 1) * nfpc);
        let (a, b) = (c0.max(first), c1.min(last));
        if let Ok(ci) = port.chunk_info(a) {
            if ci.flags & chunk_flags::GAP != 0 {
                gap += b - a + 1;
            } else if ci.flags & chunk_flags::DISCONTINUITY != 0 {
                gap += (a..=b).filter(|&f| zero(f)).count() as u64;
            }
            if ci.flags & chunk_flags::DISCONTINUITY != 0 {
                disc += 1;
            }
        }
        chunk += 1;
    }
    (gap, disc)
}

#[derive(Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
enum Line {
    Port {
        epoch: u64,
        sample_rate: u32,
        channels: u32,
        frames_per_chunk: u32,
        chunks_on_port: u32,
        block_frames: u64,
    },
    Block {
        block: u64,
        epoch: u64,
        first_frame: u64,
        frames: u64,
        loss: u64,
        gap_frames: u64,
        discontinuities: u32,
        rms_dbfs: Vec<Option<f64>>,
        peak_dbfs: Vec<Option<f64>>,
    },
    Restarted {
        old_epoch: u64,
    },
    /// The acquisition paused (device error, broker gone): the reader waits for it.
    Outage {
        message: String,
    },
    /// Frames flow again after an outage.
    Resumed {
        message: String,
    },
    End {
        reason: &'static str,
        last_frame_index: u64,
        blocks: u64,
    },
}

/// How reading one acquisition ended.
enum Ended {
    Limit,
    Stopped(u64),
    Restarted,
}

/// Runs `bass blocks` on broker `name`; `timeout` bounds waiting for the port and the broker.
pub fn run(name: &str, a: &BlocksArgs, timeout: Duration) -> Result<()> {
    let end = a.seconds.and_then(|s| Instant::now().checked_add(Duration::from_secs_f64(s)));
    let mut port = open_port(name, timeout, None)?;
    let mut n_blocks = 0u64;
    loop {
        let epoch = port.epoch();
        match read_acquisition(name, &port, a, end, timeout, &mut n_blocks)? {
            Ended::Limit => {
                let last = port.info().map(|i| i.last_frame_index).unwrap_or(0);
                emit(a.json, Line::End { reason: "limit", last_frame_index: last, blocks: n_blocks }, "")?;
                return Ok(());
            }
            Ended::Stopped(last) => {
                let text = format!("-- acquisition stopped at frame {last}");
                emit(
                    a.json,
                    Line::End { reason: "stopped", last_frame_index: last, blocks: n_blocks },
                    &text,
                )?;
                return Ok(());
            }
            Ended::Restarted => {
                let text = "-- a new acquisition replaced the port; following it";
                emit(a.json, Line::Restarted { old_epoch: epoch }, text)?;
                port = open_port(name, timeout, Some(epoch))?;
            }
        }
    }
}

fn emit(json: bool, line: Line, text: &str) -> Result<()> {
    if json {
        outln!("{}", serde_json::to_string(&line)?)
    } else if !text.is_empty() {
        outln!("{text}")
    } else {
        Ok(())
    }
}

/// The BASC loop over one port: blocks of N frames, following each other without loss
/// unless the port overtakes us.
fn read_acquisition(
    name: &str,
    port: &Port,
    a: &BlocksArgs,
    end: Option<Instant>,
    timeout: Duration,
    n_blocks: &mut u64,
) -> Result<Ended> {
    let g = port.geometry().clone();
    let block = a.block.unwrap_or(u64::from(g.frames_per_chunk)) as usize;
    let epoch = port.epoch();
    print_port(name, port, a, block)?;
    let first_unpublished = port.info()?.last_frame_index.saturating_add(1);
    let mut nfr = if a.offset >= 0 {
        first_unpublished.saturating_add(a.offset.unsigned_abs())
    } else {
        first_unpublished.saturating_sub(a.offset.unsigned_abs()).max(1)
    };
    let mut bufs = vec![vec![0i32; block]; g.channels as usize];
    let mut outage = Outage::new(a.max_outage);
    let reading = Reading { name, port, a, end, timeout };
    loop {
        if a.count.is_some_and(|c| *n_blocks >= c) || reading.past_end() {
            return Ok(Ended::Limit);
        }
        let loss = match reading.collect(&mut bufs, &mut nfr, &mut outage)? {
            Collected::Block { loss } => loss,
            Collected::End(e) => return Ok(e),
        };
        *n_blocks += 1;
        print_block(port, a, *n_blocks, epoch, nfr, loss, &bufs)?;
        if port.info().map(|i| i.state == Some(State::Superseded)).unwrap_or(false) {
            return Ok(Ended::Restarted);
        }
    }
}

/// The line (or JSON object) that opens the reading of a port: its geometry and the block size.
fn print_port(name: &str, port: &Port, a: &BlocksArgs, block: usize) -> Result<()> {
    let g = port.geometry();
    let epoch = port.epoch();
    let text = format!(
        "port {name}: epoch {epoch}, {} Hz, {} ch, {} frames/chunk, {} chunks; blocks of {block} frames",
        g.sample_rate, g.channels, g.frames_per_chunk, g.chunks_on_port
    );
    let header = Line::Port {
        epoch,
        sample_rate: g.sample_rate,
        channels: g.channels,
        frames_per_chunk: g.frames_per_chunk,
        chunks_on_port: g.chunks_on_port,
        block_frames: block as u64,
    };
    emit(a.json, header, &text)
}

/// What collecting one block came to.
enum Collected {
    /// A whole block, with the frames the port overtook (lost) while it was collected.
    Block { loss: u64 },
    /// The reading ends (a limit, a Stop, a new acquisition).
    End(Ended),
}

/// One port being read: what `collect` needs besides the block.
struct Reading<'a> {
    name: &'a str,
    port: &'a Port,
    a: &'a BlocksArgs,
    end: Option<Instant>,
    timeout: Duration,
}

impl Reading<'_> {
    fn past_end(&self) -> bool {
        self.end.is_some_and(|e| Instant::now() >= e)
    }

    /// Collects one block into `bufs` from `nfr` (getAudioData may return fewer frames than
    /// asked); waits through an outage, saying so once and when it ends.
    fn collect(&self, bufs: &mut [Vec<i32>], nfr: &mut u64, outage: &mut Outage) -> Result<Collected> {
        let (name, port, a) = (self.name, self.port, self.a);
        let block = bufs[0].len();
        let nfpc = u64::from(port.geometry().frames_per_chunk);
        let (mut got, mut loss) = (0usize, 0u64);
        while got < block {
            if self.past_end() {
                return Ok(Collected::End(Ended::Limit));
            }
            let want = nfr.saturating_add((block - got) as u64 - 1);
            match port.wait(want.min(nfr.saturating_add(nfpc)), Duration::from_millis(200)) {
                Ok(_) => {
                    if let Some(text) = outage.resumed() {
                        emit(a.json, Line::Resumed { message: text.clone() }, &text)?;
                    }
                }
                Err(Error::Timeout { .. }) | Err(Error::Interrupted) => {}
                Err(Error::Restarted) => return Ok(Collected::End(Ended::Restarted)),
                Err(Error::Stopped { last }) => {
                    return Ok(Collected::End(match after_stop(name, port, self.timeout)? {
                        AfterStop::Restarted => Ended::Restarted,
                        AfterStop::Stopped => Ended::Stopped(last),
                    }))
                }
                Err(e @ (Error::Device { .. } | Error::WriterGone { .. })) => {
                    if let Some(text) = outage.pause(e, name)? {
                        emit(a.json, Line::Outage { message: text.clone() }, &text)?;
                    }
                    continue;
                }
                Err(e) => return Err(e.into()),
            }
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[got..]).collect();
            let r = port.get_audio_data(block - got, nfr, &mut outs)?;
            if r.loss > 0 {
                // The port overtook us: the block restarts at the oldest frame on the port.
                loss += r.loss;
                if got > 0 {
                    for b in bufs.iter_mut() {
                        b.copy_within(got..got + r.frames, 0);
                    }
                    got = 0;
                }
            }
            got += r.frames;
        }
        Ok(Collected::Block { loss })
    }
}

/// The line (or JSON object) of block `n`, which ends before `nfr`.
fn print_block(
    port: &Port,
    a: &BlocksArgs,
    n: u64,
    epoch: u64,
    nfr: u64,
    loss: u64,
    bufs: &[Vec<i32>],
) -> Result<()> {
    let block = bufs[0].len();
    let start = nfr - block as u64;
    let (gap, disc) = gaps_in(port, start, nfr - 1, bufs);
    let lv = levels(bufs);
    if a.json {
        let line = Line::Block {
            block: n,
            epoch,
            first_frame: start,
            frames: block as u64,
            loss,
            gap_frames: gap,
            discontinuities: disc,
            rms_dbfs: lv.iter().map(|l| dbfs(l.0)).collect(),
            peak_dbfs: lv.iter().map(|l| dbfs(l.1)).collect(),
        };
        return emit(true, line, "");
    }
    let mut line = format!(
        "block {n:5}  frames {start:>10}..{:<10} ({block}) loss {loss:<6} gap {gap:<6}{}",
        nfr - 1,
        if disc > 0 { " xrun" } else { "" }
    );
    for (c, (rms, peak)) in lv.iter().enumerate() {
        line.push_str(&format!(" | ch{c} rms {} peak {} dBFS", dbfs_text(*rms), dbfs_text(*peak)));
    }
    outln!("{line}")
}
