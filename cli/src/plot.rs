//! `bass plot`: a PNG of a recording (`bass plot rec.wav -o rec.png`) or of the last seconds
//! on the port (`bass plot --live --seconds S -o now.png`): the waveform of each channel
//! (min/max envelope per pixel column), the RMS level of every channel over time in dBFS,
//! and the zero-filled gaps (GAP chunks) shaded, with axes in seconds. Drawn with plotters.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use bassport::format::chunk_flags;
use plotters::prelude::*;

use crate::exit::{self, Exit};
use crate::follow::open_port;
use basskit::args::parse_seconds;

/// Width of the picture (pixels).
const WIDTH: u32 = 1200;
/// Height of one panel (pixels).
const PANEL: u32 = 180;
/// Channels drawn as waveforms at most (the RMS panel shows all).
const MAX_WAVEFORMS: usize = 8;

/// Options of `bass plot`.
#[derive(clap::Args, Debug, Clone)]
pub struct PlotArgs {
    /// WAV file to plot (its sidecar FILE.json, if any, gives the gaps)
    #[arg(required_unless_present_any = ["live", "alignment"], conflicts_with_all = ["live", "alignment"])]
    pub file: Option<PathBuf>,
    /// Plot the last --seconds on the port instead of a file
    #[arg(long, conflicts_with = "alignment")]
    pub live: bool,
    /// Plot a several-device acquisition's alignment over the next --seconds instead: each
    /// follower's ratio (ppm), error estimate and state, from Status every --interval
    #[arg(long)]
    pub alignment: bool,
    /// With --alignment: also write the samples as CSV
    #[arg(long, value_name = "FILE", requires = "alignment")]
    pub csv: Option<PathBuf>,
    /// With --alignment: seconds between two Status samples (0.01 to 10)
    #[arg(long, value_name = "S", default_value = "0.1", value_parser = parse_seconds, requires = "alignment")]
    pub interval: f64,
    /// Seconds of the port to plot with --live (at most the window), or to sample with
    /// --alignment
    #[arg(short = 'd', long, value_name = "S", default_value = "2", value_parser = parse_seconds)]
    pub seconds: f64,
    /// Output PNG
    #[arg(short = 'o', long, value_name = "PNG")]
    pub output: PathBuf,
}

/// Audio to plot: samples at full scale 1.0, and gap runs (sample index, length).
struct Signal {
    rate: u32,
    channels: Vec<Vec<f64>>,
    gaps: Vec<(u64, u64)>,
    title: String,
}

/// Runs `bass plot`.
pub fn run(name: &str, a: &PlotArgs, timeout: Duration) -> Result<()> {
    if a.alignment {
        return crate::alignment::run(name, a.seconds, a.interval, &a.output, a.csv.as_deref(), timeout);
    }
    let sig = match &a.file {
        Some(f) => from_wav(f)?,
        None => from_port(name, a.seconds, timeout)?,
    };
    draw(&sig, &a.output).with_context(|| format!("draw {}", a.output.display()))?;
    crate::out::outln!("wrote {}", a.output.display())?;
    Ok(())
}

fn from_wav(path: &Path) -> Result<Signal> {
    let mut r = hound::WavReader::open(path).with_context(|| format!("open {}", path.display()))?;
    let spec = r.spec();
    let n = usize::from(spec.channels.max(1));
    let mut channels = vec![Vec::with_capacity(r.duration() as usize); n];
    if spec.sample_format == hound::SampleFormat::Float {
        for (i, s) in r.samples::<f32>().enumerate() {
            channels[i % n].push(f64::from(s?));
        }
    } else {
        let scale = 2f64.powi(i32::from(spec.bits_per_sample) - 1);
        for (i, s) in r.samples::<i32>().enumerate() {
            channels[i % n].push(f64::from(s?) / scale);
        }
    }
    let mut side = path.as_os_str().to_owned();
    side.push(".json");
    let mut gaps = Vec::new();
    if let Ok(bytes) = std::fs::read(&side) {
        let v: serde_json::Value = serde_json::from_slice(&bytes).context("the sidecar is not JSON")?;
        let first = v["recording"]["first_frame"].as_u64().unwrap_or(1);
        for row in v["chunks"].as_array().into_iter().flatten() {
            let flags = row["flags"].as_u64().unwrap_or(0);
            if let (Some(f), Some(len)) = (row["first_frame"].as_u64(), row["frames"].as_u64()) {
                if flags & u64::from(chunk_flags::GAP) != 0 && f >= first {
                    gaps.push((f - first, len));
                }
            }
        }
    }
    let title = format!("{} ({} Hz, {} ch)", path.display(), spec.sample_rate, n);
    Ok(Signal { rate: spec.sample_rate, channels, gaps, title })
}

fn from_port(name: &str, seconds: f64, timeout: Duration) -> Result<Signal> {
    let port = open_port(name, timeout, None)?;
    let g = port.geometry().clone();
    let lfi = port.info()?.last_frame_index;
    if lfi == 0 {
        return Err(Exit::new(exit::FAILURE, format!("port {name} holds no frame yet")).into());
    }
    let want = ((seconds * f64::from(g.sample_rate)).round() as u64).clamp(1, port.frames_on_port());
    let first = (lfi + 1).saturating_sub(want).max(1);
    let n = (lfi + 1 - first) as usize;
    let mut bufs = vec![vec![0i32; n]; g.channels as usize];
    let mut nfr = first;
    let mut outs: Vec<&mut [i32]> = bufs.iter_mut().map(|b| &mut b[..]).collect();
    let r = port.get_audio_data(n, &mut nfr, &mut outs)?;
    if r.loss > 0 || r.frames < n {
        bail!("the port moved on while it was read ({} frames lost); plot fewer --seconds", r.loss);
    }
    let mut gaps = Vec::new();
    let nfpc = u64::from(g.frames_per_chunk);
    let mut f = first;
    while f <= lfi {
        if let Ok(ci) = port.chunk_info(f) {
            if ci.flags & chunk_flags::GAP != 0 {
                gaps.push((f - first, ci.first_frame + u64::from(ci.frames) - f));
            }
        }
        f = ((f - 1) / nfpc + 1) * nfpc + 1;
    }
    let channels = bufs.iter().map(|b| b.iter().map(|&s| f64::from(s) / 2_147_483_648.0).collect()).collect();
    let title = format!("port {name}, epoch {}: frames {first}..{lfi} ({} Hz)", port.epoch(), g.sample_rate);
    Ok(Signal { rate: g.sample_rate, channels, gaps, title })
}

fn draw(sig: &Signal, out: &Path) -> Result<()> {
    let frames = sig.channels.first().map_or(0, Vec::len);
    if frames == 0 {
        bail!("nothing to plot: no frames");
    }
    let secs = frames as f64 / f64::from(sig.rate);
    let waves = sig.channels.len().min(MAX_WAVEFORMS);
    let height = PANEL * (waves as u32 + 1) + 40;
    let root = BitMapBackend::new(out, (WIDTH, height)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(&sig.title, ("sans-serif", 20))?;
    let panels = root.split_evenly((waves + 1, 1));
    let t = |i: u64| i as f64 / f64::from(sig.rate);
    let gap_style = RED.mix(0.25).filled();
    let bins = (WIDTH as usize - 80).min(frames);
    for (c, area) in panels.iter().take(waves).enumerate() {
        let mut chart = ChartBuilder::on(area)
            .margin(6)
            .x_label_area_size(28)
            .y_label_area_size(60)
            .caption(format!("channel {c}"), ("sans-serif", 14))
            .build_cartesian_2d(0f64..secs, -1f64..1f64)?;
        chart.configure_mesh().x_desc("seconds").y_desc("full scale").light_line_style(WHITE).draw()?;
        chart.draw_series(
            sig.gaps.iter().map(|&(a, n)| Rectangle::new([(t(a), -1.0), (t(a + n), 1.0)], gap_style)),
        )?;
        let x = &sig.channels[c];
        chart.draw_series((0..bins).map(|b| {
            let (lo, hi) = (b * frames / bins, ((b + 1) * frames / bins).max(b * frames / bins + 1));
            let (mn, mx) = x[lo..hi].iter().fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let tt = t(lo as u64);
            PathElement::new(vec![(tt, mn), (tt, mx)], BLUE)
        }))?;
    }
    let mut chart = ChartBuilder::on(&panels[waves])
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(60)
        .caption("RMS level", ("sans-serif", 14))
        .build_cartesian_2d(0f64..secs, -90f64..0f64)?;
    chart.configure_mesh().x_desc("seconds").y_desc("dBFS").draw()?;
    chart.draw_series(
        sig.gaps.iter().map(|&(a, n)| Rectangle::new([(t(a), -90.0), (t(a + n), 0.0)], gap_style)),
    )?;
    for (c, x) in sig.channels.iter().enumerate() {
        let pts = (0..bins).map(|b| {
            let (lo, hi) = (b * frames / bins, ((b + 1) * frames / bins).max(b * frames / bins + 1));
            let ms = x[lo..hi].iter().map(|v| v * v).sum::<f64>() / (hi - lo) as f64;
            (t(lo as u64), if ms > 0.0 { (10.0 * ms.log10()).max(-90.0) } else { -90.0 })
        });
        let color = Palette99::pick(c);
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(1)))?
            .label(format!("ch{c}"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], Palette99::pick(c)));
    }
    if sig.channels.len() <= 8 {
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    }
    root.present()?;
    Ok(())
}
