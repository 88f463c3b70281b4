//! `bass lsl`: the port as a Lab Streaming Layer stream, for the lab's recorders and tools
//! (LabRecorder, pylsl, ...). One outlet of type `Audio` (int32 channels at the nominal rate,
//! one push per chunk, every sample stamped with its own capture time: the chunk's first-frame
//! CLOCK_MONOTONIC stamp plus its offset in the chunk, in LSL's clock), and a marker outlet
//! (`<stream>-loss`, one JSON string per event: `{"first_frame", "frames", "cause", "epoch"}`,
//! cause `overrun` for frames the outlet lost to the port's window, `gap` for the zeros of a
//! GAP chunk it pushed) — LSL itself has no field for loss. liblsl is loaded at run time
//! (`bass_lsl`), never built or shipped by bass.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use bass_lsl::{ChannelFormat, Lsl, Outlet, StreamSpec};
use basskit::args::parse_seconds;
use bassport::format::chunk_flags;
use bassport::sys::monotonic_ns;
use bassport::{ChunkInfo, Error, Port};

use crate::exit::{self, Exit};
use crate::follow::{after_stop, open_port, AfterStop, Outage};
use crate::labstream::{self, zero_filled, Run, ZeroRuns, GAP, OVERRUN};
use crate::out::{note, outln};

/// `bass lsl` options.
#[derive(clap::Args, Debug)]
pub struct LslArgs {
    /// LSL stream name [default: bass for the broker "default", else bass-NAME]; the markers
    /// are STREAM-loss
    #[arg(long, value_name = "NAME")]
    pub stream: Option<String>,
    /// The liblsl to load [default: $PYLSL_LIB, the system's liblsl.so, or PyPI pylsl's copy]
    #[arg(long, value_name = "PATH")]
    pub liblsl: Option<PathBuf>,
    /// Stop after S seconds [default: until the acquisition stops, or Ctrl-C]
    #[arg(short = 'd', long = "seconds", value_name = "S", value_parser = parse_seconds)]
    pub seconds: Option<f64>,
    /// End with an error when no frame comes for S seconds after a device error or a broker
    /// gone [default: wait for the acquisition to go on]
    #[arg(long, value_name = "S", value_parser = parse_seconds)]
    pub max_outage: Option<f64>,
}

/// What the outlet pushed.
#[derive(Default)]
struct Totals {
    frames: u64,
    lost: u64,
    gap: u64,
    markers: u64,
}

/// Runs `bass lsl` on broker `name`.
pub fn run(name: &str, a: &LslArgs, timeout: Duration) -> Result<()> {
    let lsl = Lsl::load(a.liblsl.as_deref()).map_err(|e| Exit::new(exit::USAGE, e))?;
    let offset = lsl.clock_offset_s(|| monotonic_ns() as f64 / 1e9);
    let stream = a.stream.clone().unwrap_or_else(|| labstream::stream_name(name));
    let end = a.seconds.and_then(|s| Instant::now().checked_add(Duration::from_secs_f64(s)));
    let mut port = open_port(name, timeout, None)?;
    let mut totals = Totals::default();
    let mut outage = Outage::new(a.max_outage);
    outln!(
        "lsl: liblsl {} ({}); LSL's clock = CLOCK_MONOTONIC {:+.1} µs",
        lsl.version(),
        lsl.path.display(),
        offset * 1e6
    )?;
    let reason = loop {
        let epoch = port.epoch();
        let outlets = Outlets::new(&lsl, &stream, name, &port)?;
        outln!(
            "lsl: streams {stream:?} (Audio, {} ch int32, {} Hz) and {:?} (Markers) from port {name}, epoch {epoch}",
            port.geometry().channels,
            port.geometry().sample_rate,
            labstream::marker_stream_name(&stream)
        )?;
        let ended = outlets.follow(name, &port, offset, end, timeout, &mut outage, &mut totals)?;
        match ended {
            Ended::Restarted => {
                outln!("lsl: a new acquisition replaced the port; following it")?;
                port = open_port(name, timeout, Some(epoch))?;
            }
            Ended::Stopped(last) => break format!("the acquisition stopped at frame {last}"),
            Ended::Limit => break "the time limit".to_owned(),
        }
    };
    outln!(
        "lsl: {} frames pushed ({} of them zero-filled gaps), {} frames lost, {} markers; ended by {reason}",
        totals.frames,
        totals.gap,
        totals.lost,
        totals.markers
    )?;
    Ok(())
}

/// How following one acquisition ended.
enum Ended {
    Restarted,
    Stopped(u64),
    Limit,
}

/// The audio and marker outlets of one acquisition.
struct Outlets<'a> {
    audio: Outlet<'a>,
    markers: Outlet<'a>,
    rate: f64,
    epoch: u64,
}

impl<'a> Outlets<'a> {
    fn new(lsl: &'a Lsl, stream: &str, name: &str, port: &Port) -> Result<Outlets<'a>> {
        let g = port.geometry();
        let host = labstream::hostname();
        let channels: Vec<u32> = (0..g.channels).collect();
        let desc = labstream::audio_desc(name, &host, port.epoch(), g, &channels, labstream::Clock::Lsl);
        let source = labstream::source_id(&host, name);
        let audio = lsl
            .outlet(&StreamSpec {
                name: stream,
                kind: "Audio",
                channels: g.channels as i32,
                rate: f64::from(g.sample_rate),
                format: ChannelFormat::Int32,
                source_id: &source,
                desc: &desc,
            })
            .map_err(anyhow::Error::msg)?;
        let marker_desc = labstream::marker_desc(stream);
        let markers = lsl
            .outlet(&StreamSpec {
                name: &labstream::marker_stream_name(stream),
                kind: "Markers",
                channels: 1,
                rate: 0.0,
                format: ChannelFormat::String,
                source_id: &format!("{source}:loss"),
                desc: &marker_desc,
            })
            .map_err(anyhow::Error::msg)?;
        Ok(Outlets { audio, markers, rate: f64::from(g.sample_rate), epoch: port.epoch() })
    }

    /// The LSL time of frame `frame` of the chunk described by `ci`.
    fn time_of(&self, ci: &ChunkInfo, frame: u64, offset: f64) -> f64 {
        labstream::stamp_s(ci.mono_ns, ci.first_frame, frame, self.rate) + offset
    }

    fn marker(&self, first_frame: u64, frames: u64, cause: &str, t: f64, totals: &mut Totals) -> Result<()> {
        let text = labstream::marker_json(first_frame, frames, cause, self.epoch);
        self.markers.push_str(&text, t).map_err(anyhow::Error::msg)?;
        totals.markers += 1;
        Ok(())
    }

    /// Pushes the port chunk by chunk from the next chunk published until the acquisition
    /// ends or is replaced, or the limit.
    #[allow(clippy::too_many_arguments)]
    fn follow(
        &self,
        name: &str,
        port: &Port,
        offset: f64,
        end: Option<Instant>,
        timeout: Duration,
        outage: &mut Outage,
        totals: &mut Totals,
    ) -> Result<Ended> {
        let g = port.geometry().clone();
        let (nfpc, ch) = (u64::from(g.frames_per_chunk), g.channels as usize);
        let mut nfr = port.info()?.last_frame_index + 1;
        let mut bufs = vec![vec![0i32; nfpc as usize]; ch];
        let mut interleaved = Vec::with_capacity(nfpc as usize * ch);
        let mut stamps = Vec::with_capacity(nfpc as usize);
        let mut run = ZeroRuns::default();
        let ended = loop {
            if end.is_some_and(|e| Instant::now() >= e) {
                break Ended::Limit;
            }
            match port.wait(nfr + nfpc - 1, Duration::from_millis(200)) {
                Ok(_) => {
                    if let Some(text) = outage.resumed() {
                        note!("lsl: {text}");
                    }
                }
                Err(Error::Timeout { .. }) | Err(Error::Interrupted) => continue,
                Err(Error::Restarted) => break Ended::Restarted,
                Err(Error::Stopped { last }) => {
                    break match after_stop(name, port, timeout)? {
                        AfterStop::Restarted => Ended::Restarted,
                        AfterStop::Stopped => Ended::Stopped(last),
                    };
                }
                Err(e @ (Error::Device { .. } | Error::WriterGone { .. })) => {
                    if let Some(text) = outage.pause(e, name)? {
                        note!("lsl: {text}");
                    }
                    continue;
                }
                Err(e) => return Err(e.into()),
            }
            // The chunk's row before its frames: intact frames mean the row was not overwritten.
            let before = nfr;
            let pre = port.chunk_info(before).ok();
            let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[..]).collect();
            let r = port.get_audio_data(nfpc as usize, &mut nfr, &mut outs)?;
            let first = before + r.loss;
            let ci = match (r.loss, pre) {
                (0, Some(ci)) => Some(ci),
                _ => port.chunk_info(first).ok(),
            };
            let Some(ci) = ci else {
                // The frames read are intact but their row is gone already: not pushed without
                // a stamp, counted as lost.
                self.end_run(&mut run, totals)?;
                totals.lost += r.loss + r.frames as u64;
                self.marker(before, r.loss + r.frames as u64, OVERRUN, self.rate_time_now(offset), totals)?;
                continue;
            };
            if r.loss > 0 {
                self.end_run(&mut run, totals)?;
                totals.lost += r.loss;
                self.marker(before, r.loss, OVERRUN, self.time_of(&ci, before, offset), totals)?;
            }
            // The zero-filled frames: a GAP chunk's, and the zeros of a chunk flagged
            // DISCONTINUITY (where a gap begins or ends inside a chunk); one marker per run,
            // when it ends (at the first real frame, or a chunk without a gap).
            let flagged = ci.flags & (chunk_flags::GAP | chunk_flags::DISCONTINUITY) != 0;
            for i in 0..r.frames {
                let f = first + i as u64;
                let zero = zero_filled(ci.flags, bufs.iter().all(|b| b[i] == 0));
                if let Some(ended) = run.frame(f, zero, || self.time_of(&ci, f, offset)) {
                    self.gap_marker(ended, totals)?;
                }
            }
            if !flagged {
                self.end_run(&mut run, totals)?;
            }
            interleaved.clear();
            stamps.clear();
            for i in 0..r.frames {
                interleaved.extend(bufs.iter().map(|b| b[i]));
                stamps.push(self.time_of(&ci, first + i as u64, offset));
            }
            self.audio.push_i32(&interleaved, &stamps).map_err(anyhow::Error::msg)?;
            totals.frames += r.frames as u64;
        };
        self.end_run(&mut run, totals)?;
        Ok(ended)
    }

    /// The gap marker of the run of zero-filled frames going on (if any), which ends here.
    fn end_run(&self, run: &mut ZeroRuns, totals: &mut Totals) -> Result<()> {
        match run.end() {
            Some(ended) => self.gap_marker(ended, totals),
            None => Ok(()),
        }
    }

    /// The gap marker of a run of zero-filled frames that ended.
    fn gap_marker(&self, run: Run, totals: &mut Totals) -> Result<()> {
        totals.gap += run.frames;
        self.marker(run.first_frame, run.frames, GAP, run.stamp, totals)
    }

    /// Now, in LSL's clock (for a marker whose frames have no stamp left).
    fn rate_time_now(&self, offset: f64) -> f64 {
        monotonic_ns() as f64 / 1e9 + offset
    }
}
