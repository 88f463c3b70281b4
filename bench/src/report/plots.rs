//! The docs/perf-*.png plots of one run.

use std::path::Path;

use crate::plot::{self, Chart, Series, COLORS};
use crate::publish::Design;
use crate::stats::median;

use super::Results;

pub(super) fn plots(r: &Results, docs: &Path) -> Vec<String> {
    let mut made = Vec::new();
    if !r.read.is_empty() {
        let s = |name: &str, color, f: &dyn Fn(&crate::read::ReadRow) -> f64, dashed| Series {
            name: name.into(),
            color,
            points: r.read.iter().map(|x| (x.bytes as f64, f(x))).collect(),
            dashed,
        };
        let chart = Chart {
            title: "Read throughput vs block size (44.1 kHz stereo)".into(),
            xlabel: "block size (bytes, both channels)".into(),
            ylabel: "GB/s".into(),
            xlog: true,
            ylog: true,
            series: vec![
                s("bass_get_audio_data, hot", COLORS[0], &|x| median(&x.ffi_gbs), false),
                s("memcpy, hot", COLORS[1], &|x| median(&x.memcpy_gbs), false),
                s("bass_get_audio_data, streaming", COLORS[2], &|x| median(&x.stream_ffi_gbs), false),
                s("memcpy, streaming", COLORS[3], &|x| median(&x.stream_memcpy_gbs), false),
            ],
            xfmt: plot::fmt_bytes_tick,
            yfmt: plot::fmt_num_tick,
        };
        if plot::render(&[chart], 1, &docs.join("perf-read.png")).is_ok() {
            made.push("perf-read.png".into());
        }
    }
    if let Some(p) = &r.publish {
        let mut series = Vec::new();
        for (i, &k) in [0usize, 1, 8, 64].iter().enumerate() {
            for (design, dashed, name) in
                [(Design::Ring, false, "ring"), (Design::Original, true, "original")]
            {
                series.push(Series {
                    name: format!("{name}, {k} readers"),
                    color: COLORS[i],
                    points: crate::publish::WINDOWS
                        .iter()
                        .map(|&(w, _)| (w, p.publish_median(design, w, k)))
                        .collect(),
                    dashed,
                });
            }
        }
        let chart = Chart {
            title: "Publish: writer CPU per 2205-frame chunk vs window".into(),
            xlabel: "window (s)".into(),
            ylabel: "CPU per chunk".into(),
            xlog: true,
            ylog: true,
            series,
            xfmt: plot::fmt_num_tick,
            yfmt: plot::fmt_ns_tick,
        };
        if plot::render(&[chart], 1, &docs.join("perf-publish.png")).is_ok() {
            made.push("perf-publish.png".into());
        }
    }
    if let Some(w) = &r.wake {
        // CDFs on a log time axis.
        let cdf = |name: String, color, d: &crate::wake::Dist, dashed| {
            let s = crate::stats::sorted(&d.all);
            let n = s.len().max(1) as f64;
            let step = (s.len() / 200).max(1);
            Series {
                name,
                color,
                points: s
                    .iter()
                    .enumerate()
                    .step_by(step)
                    .map(|(i, &v)| (v.max(1.0), (i + 1) as f64 / n))
                    .collect(),
                dashed,
            }
        };
        let mut series = vec![cdf("raw futex".into(), COLORS[6], &w.raw, true)];
        for (i, (k, d)) in w.bass.iter().enumerate() {
            series.push(cdf(format!("bass, {k} reader(s), each"), COLORS[i], d, false));
        }
        series.push(cdf("250 ms polling client".into(), COLORS[3], &w.poll, false));
        let chart = Chart {
            title: "Wake latency, publish -> reader running (CDF)".into(),
            xlabel: "latency".into(),
            ylabel: "fraction of wakes".into(),
            xlog: true,
            ylog: false,
            series,
            xfmt: plot::fmt_ns_tick,
            yfmt: plot::fmt_num_tick,
        };
        if plot::render(&[chart], 1, &docs.join("perf-wake.png")).is_ok() {
            made.push("perf-wake.png".into());
        }
    }
    made
}
