//! Measurements of an aligned follower against the analytic field: the residual
//! alignment from the pilot tones' phase, the SNR, the ratio noise, and a recorder that
//! runs a simulated [`Rig`] through an [`Aligner`].
//!
//! The residual alignment of a block of master frames is the time shift of the follower
//! signal against the field at the master's true instants, in samples: all tones of the
//! field are fitted at once (least squares, the frequencies known, the instants the
//! master's true ones), and for each pilot the shift is its phase minus the field's exact
//! phase, over its angular frequency. The pilots' shifts are averaged over pilots and
//! channels. Positive: the follower is early (it shows the field of a later instant).

use std::time::{Duration, Instant};

use crate::sim::{Field, Rig, Source, FULL_SCALE};
use crate::{Aligner, Config, Error};

/// Solves `a x = b` (`n`×`n`, row-major) by Gaussian elimination with partial pivoting.
fn solve(mut a: Vec<f64>, mut b: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[piv * n + col].abs() < 1e-12 {
            return None;
        }
        for c in 0..n {
            a.swap(col * n + c, piv * n + c);
        }
        b.swap(col, piv);
        for r in col + 1..n {
            let f = a[r * n + col] / a[col * n + col];
            for c in col..n {
                a[r * n + c] -= f * a[col * n + c];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|c| a[r * n + c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r * n + r];
    }
    Some(x)
}

/// Least-squares fit of `y(t) = sum a_i sin(w_i t) + b_i cos(w_i t)`; returns `(a_i, b_i)`.
pub fn fit_tones(y: &[f64], t: &[f64], hz: &[f64]) -> Option<Vec<(f64, f64)>> {
    let m = 2 * hz.len();
    let (mut ata, mut atb) = (vec![0.0; m * m], vec![0.0; m]);
    let mut row = vec![0.0; m];
    for (&yi, &ti) in y.iter().zip(t) {
        for (i, &f) in hz.iter().enumerate() {
            let (s, c) = (std::f64::consts::TAU * f * ti).sin_cos();
            row[2 * i] = s;
            row[2 * i + 1] = c;
        }
        for r in 0..m {
            atb[r] += row[r] * yi;
            for c in 0..m {
                ata[r * m + c] += row[r] * row[c];
            }
        }
    }
    let x = solve(ata, atb, m)?;
    Some(x.chunks_exact(2).map(|p| (p[0], p[1])).collect())
}

/// The residual alignment of one channel of a block, samples (see the module doc).
pub fn pilot_shift(field: &Field, ch: usize, y: &[f64], t: &[f64], rate_hz: f64) -> Option<f64> {
    let hz: Vec<f64> = field.tones.iter().map(|t| t.hz).collect();
    let fit = fit_tones(y, t, &hz)?;
    let shifts: Vec<f64> = field
        .pilots()
        .iter()
        .zip(&fit)
        .map(|(tone, &(a, b))| {
            let w = std::f64::consts::TAU * tone.hz;
            let exact = tone.phase + ch as f64 * tone.channel_phase;
            let d = (b.atan2(a) - exact + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            d / w * rate_hz
        })
        .collect();
    Some(shifts.iter().sum::<f64>() / shifts.len() as f64)
}

/// Signal-to-noise ratio of `y` against `expected`, dB.
pub fn snr_db(y: &[f64], expected: &[f64]) -> f64 {
    let (mut s, mut e) = (0.0, 0.0);
    for (&a, &b) in y.iter().zip(expected) {
        s += b * b;
        e += (a - b) * (a - b);
    }
    10.0 * (s / e.max(1e-300)).log10()
}

/// Root mean square.
pub fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The `q` quantile (0..1) of the absolute values.
pub fn abs_quantile(v: &[f64], q: f64) -> f64 {
    let mut a: Vec<f64> = v.iter().map(|x| x.abs()).collect();
    a.sort_by(f64::total_cmp);
    a.get(((a.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN)
}

/// The ratio noise, ppm: the standard deviation of the per-chunk step about its linear
/// trend over windows of `per_window` chunks, averaged over the windows.
pub fn ratio_noise_ppm(steps: &[f64], per_window: usize) -> f64 {
    let windows: Vec<f64> = steps
        .chunks_exact(per_window.max(3))
        .map(|w| {
            let n = w.len() as f64;
            let xm = (n - 1.0) / 2.0;
            let ym = w.iter().sum::<f64>() / n;
            let sxy: f64 = w.iter().enumerate().map(|(i, y)| (i as f64 - xm) * (y - ym)).sum();
            let sxx: f64 = (0..w.len()).map(|i| (i as f64 - xm).powi(2)).sum();
            let b = sxy / sxx;
            let r: Vec<f64> =
                w.iter().enumerate().map(|(i, y)| (y - ym - b * (i as f64 - xm)) / ym * 1e6).collect();
            rms(&r)
        })
        .collect();
    windows.iter().sum::<f64>() / windows.len().max(1) as f64
}

/// Follower 0 of a simulated run, on every master frame.
#[derive(Clone, Debug, Default)]
pub struct Recording {
    /// Master frames recorded.
    pub frames: usize,
    /// Channels of follower 0.
    pub channels: usize,
    /// Aligned samples, full scale 1, interleaved.
    pub aligned: Vec<f64>,
    /// The field at the master's true instants, interleaved.
    pub expected: Vec<f64>,
    /// The master's true instant of every frame, seconds.
    pub times: Vec<f64>,
    /// Per frame validity.
    pub valid: Vec<bool>,
    /// Per chunk: first master frame, lock flag, error estimate, step.
    pub chunks: Vec<(u64, bool, f64, f64)>,
    /// Time spent in the aligner's calls.
    pub aligner_time: Duration,
}

impl Recording {
    /// The first master frame of the first locked chunk.
    pub fn lock_frame(&self) -> Option<u64> {
        self.chunks.iter().find(|c| c.1).map(|c| c.0)
    }

    /// Residual alignment per block of `block` frames from master frame `from` on, over
    /// blocks whose frames are all valid, samples.
    pub fn residuals(&self, field: &Field, from: usize, block: usize, rate_hz: f64) -> Vec<f64> {
        let ch = self.channels;
        let mut out = Vec::new();
        let mut start = from;
        while start + block <= self.frames {
            if self.valid[start..start + block].iter().all(|&v| v) {
                let t = &self.times[start..start + block];
                let mut sum = 0.0;
                for c in 0..ch {
                    let y: Vec<f64> = (start..start + block).map(|f| self.aligned[f * ch + c]).collect();
                    sum += pilot_shift(field, c, &y, t, rate_hz).unwrap_or(f64::NAN);
                }
                out.push(sum / ch as f64);
            }
            start += block;
        }
        out
    }

    /// Aligned and expected samples of the valid frames from master frame `from` on.
    pub fn valid_samples(&self, from: usize) -> (Vec<f64>, Vec<f64>) {
        let ch = self.channels;
        let (mut y, mut e) = (Vec::new(), Vec::new());
        for f in from..self.frames {
            if self.valid[f] {
                y.extend_from_slice(&self.aligned[f * ch..(f + 1) * ch]);
                e.extend_from_slice(&self.expected[f * ch..(f + 1) * ch]);
            }
        }
        (y, e)
    }
}

/// Runs `rig` through an aligner with `cfg` for `seconds` of master frames and records
/// follower 0.
pub fn record(rig: &mut Rig, cfg: Config, seconds: f64) -> Result<Recording, Error> {
    let channels: Vec<usize> = rig.followers.iter().map(|f| f.channels).collect();
    let mut aligner = Aligner::new(cfg, &channels)?;
    let total = (seconds * rig.master.clock.nominal_hz) as usize;
    let mut rec = Recording { channels: channels[0], ..Recording::default() };
    while rec.frames < total {
        let (source, chunk) = rig.next_event();
        let t0 = Instant::now();
        match source {
            Source::Master => aligner.push_master(chunk.as_chunk())?,
            Source::Follower(i) => aligner.push_follower(i, chunk.as_chunk())?,
        }
        let mut outs = Vec::new();
        while let Some(out) = aligner.pop() {
            outs.push(out);
        }
        rec.aligner_time += t0.elapsed();
        for out in outs {
            let f = &out.followers[0];
            rec.chunks.push((out.master_frame, f.locked, f.error_estimate, f.step));
            for j in 0..out.frames {
                let t = rig.master.clock.instant((out.master_frame + j as u64) as f64);
                rec.times.push(t);
                rec.valid.push(f.valid[j]);
                for c in 0..rec.channels {
                    rec.aligned.push(f64::from(f.samples[j * rec.channels + c]) / FULL_SCALE);
                    rec.expected.push(rig.field.value(rig.followers[0].first_field_channel + c, t));
                }
            }
            rec.frames += out.frames;
        }
    }
    Ok(rec)
}
