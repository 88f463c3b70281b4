//! `bass plot --alignment --seconds S -o align.png [--csv FILE] [--interval S]`: a
//! several-device acquisition's alignment over time (docs/multi-device.md, *Plotting the
//! alignment*). It samples the broker's Status every `--interval` for `--seconds` and draws,
//! per follower, its ratio against the master (ppm), its alignment error estimate (samples,
//! with the 0.5-sample lock threshold) and its state (waiting / aligning / locked / lost) as a
//! coloured band; `--csv` writes the same samples, one row per follower per sample.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use bassport::control::DeviceStatus;
use plotters::prelude::*;

use crate::exit::{self, Exit};

/// Width of the picture (pixels).
pub const WIDTH: u32 = 1200;
/// Height of one panel (pixels).
pub const PANEL: u32 = 200;
/// The lock bound drawn on the error panel (the aligner's `lock_threshold`), samples.
const LOCK_BOUND: f64 = 0.5;
/// Most samples taken (a guard on memory: one per interval).
pub const MAX_SAMPLES: f64 = 100_000.0;

/// One Status sample: seconds since the first, the master's last frame, every device's row.
struct Sample {
    t_s: f64,
    frame: u64,
    devices: Vec<DeviceStatus>,
}

/// The header of `--csv`.
pub const CSV_HEADER: &str =
    "t_s,frame,device,name,state,ratio_ppm,error_estimate,locks,xruns,unplugs,missing_frames,unaligned_frames";

/// Runs `bass plot --alignment`.
pub fn run(
    name: &str,
    seconds: f64,
    interval: f64,
    png: &Path,
    csv: Option<&Path>,
    timeout: Duration,
) -> Result<()> {
    if !(0.01..=10.0).contains(&interval) {
        return Err(Exit::new(
            exit::USAGE,
            format!("--interval {interval} is out of range (0.01 to 10 seconds)"),
        )
        .into());
    }
    if seconds / interval > MAX_SAMPLES {
        return Err(Exit::new(
            exit::USAGE,
            format!("--seconds {seconds} at --interval {interval} is more than {MAX_SAMPLES} samples"),
        )
        .into());
    }
    let mut c = crate::bass::connect(name, timeout)?;
    let first = c.status().context("status")?;
    if first.devices.len() < 2 {
        return Err(Exit::new(
            exit::FAILURE,
            format!(
                "the acquisition of {name} has no follower device to plot the alignment of (bass acquire MASTER FOLLOWER...)"
            ),
        )
        .into());
    }
    let names: Vec<String> = first.devices.iter().map(|d| d.name.clone()).collect();
    let t0 = Instant::now();
    let mut samples = Vec::new();
    let mut k = 0u64;
    loop {
        let s = c.status().context("status")?;
        // A new acquisition (other devices) ends the plot: its rows are not this one's.
        if s.devices.iter().map(|d| &d.name).ne(names.iter()) {
            bail!("the acquisition changed while it was sampled (now {:?})", s.device);
        }
        samples.push(Sample {
            t_s: t0.elapsed().as_secs_f64(),
            frame: s.last_frame_index,
            devices: s.devices,
        });
        k += 1;
        let next = Duration::from_secs_f64(interval * k as f64);
        if next.as_secs_f64() > seconds {
            break;
        }
        std::thread::sleep(next.saturating_sub(t0.elapsed()));
    }
    if let Some(path) = csv {
        write_csv(path, &samples).with_context(|| format!("write {}", path.display()))?;
        crate::out::outln!("wrote {}", path.display())?;
    }
    let title =
        format!("{name}: alignment of {} follower(s) onto {}, {seconds} s", names.len() - 1, names[0]);
    draw(&title, &samples, png).with_context(|| format!("draw {}", png.display()))?;
    crate::out::outln!("wrote {}", png.display())?;
    Ok(())
}

fn write_csv(path: &Path, samples: &[Sample]) -> Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "{CSV_HEADER}")?;
    for s in samples {
        for (i, d) in s.devices.iter().enumerate().skip(1) {
            writeln!(
                w,
                "{:.3},{},{i},{},{},{:.3},{:.4},{},{},{},{},{}",
                s.t_s,
                s.frame,
                csv_field(&d.name),
                d.state,
                d.ratio_ppm,
                d.error_estimate,
                d.locks,
                d.xruns,
                d.unplugs,
                d.missing_frames,
                d.unaligned_frames
            )?;
        }
    }
    w.flush()?;
    Ok(())
}

/// A CSV field: quoted (doubling quotes) when it holds a comma or a quote (`sim:field?a=1&b=2`
/// holds neither, a PCM name might).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// The colour of a follower's state in the state panel.
fn state_color(state: &str) -> RGBColor {
    match state {
        "locked" => RGBColor(60, 170, 60),
        "aligning" => RGBColor(240, 190, 40),
        "lost" => RGBColor(210, 40, 40),
        _ => RGBColor(170, 170, 170),
    }
}

fn draw(title: &str, samples: &[Sample], out: &Path) -> Result<()> {
    let followers = samples.first().map_or(0, |s| s.devices.len().saturating_sub(1));
    let secs = samples.last().map_or(0.0, |s| s.t_s).max(1e-3);
    let root = BitMapBackend::new(out, (WIDTH, 3 * PANEL + 40)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(title, ("sans-serif", 20))?;
    let panels = root.split_evenly((3, 1));
    let series = |f: usize, v: fn(&DeviceStatus) -> f64| -> Vec<(f64, f64)> {
        samples.iter().map(|s| (s.t_s, v(&s.devices[f]))).collect()
    };
    let range = |v: fn(&DeviceStatus) -> f64, floor: f64| -> f64 {
        samples.iter().flat_map(|s| s.devices.iter().skip(1).map(v)).map(f64::abs).fold(floor, f64::max) * 1.1
    };

    // Ratio against the master, ppm.
    let r = range(|d| d.ratio_ppm, 1.0);
    let mut chart = ChartBuilder::on(&panels[0])
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(70)
        .caption("ratio against the master (ppm)", ("sans-serif", 14))
        .build_cartesian_2d(0f64..secs, -r..r)?;
    chart.configure_mesh().x_desc("seconds").y_desc("ppm").draw()?;
    for f in 1..=followers {
        let color = Palette99::pick(f);
        chart
            .draw_series(LineSeries::new(series(f, |d| d.ratio_ppm), color.stroke_width(2)))?
            .label(samples[0].devices[f].name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], Palette99::pick(f)));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;

    // Error estimate, samples, with the lock bound.
    let e = range(|d| d.error_estimate, 2.0 * LOCK_BOUND);
    let mut chart = ChartBuilder::on(&panels[1])
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(70)
        .caption("alignment error estimate (samples); dashed: the lock bound", ("sans-serif", 14))
        .build_cartesian_2d(0f64..secs, 0f64..e)?;
    chart.configure_mesh().x_desc("seconds").y_desc("samples").draw()?;
    chart.draw_series(DashedLineSeries::new(
        vec![(0.0, LOCK_BOUND), (secs, LOCK_BOUND)],
        8,
        6,
        BLACK.into(),
    ))?;
    for f in 1..=followers {
        chart.draw_series(LineSeries::new(
            series(f, |d| d.error_estimate),
            Palette99::pick(f).stroke_width(2),
        ))?;
    }

    // State bands: one row per follower.
    let mut chart = ChartBuilder::on(&panels[2])
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(70)
        .caption("state: grey waiting, yellow aligning, green locked, red lost", ("sans-serif", 14))
        .build_cartesian_2d(0f64..secs, 0f64..followers as f64)?;
    chart.configure_mesh().x_desc("seconds").y_desc("follower").y_labels(followers + 1).draw()?;
    for f in 1..=followers {
        let y = (followers - f) as f64;
        chart.draw_series(samples.windows(2).map(|w| {
            Rectangle::new(
                [(w[0].t_s, y + 0.1), (w[1].t_s, y + 0.9)],
                state_color(&w[0].devices[f].state).filled(),
            )
        }))?;
    }
    root.present()?;
    Ok(())
}
