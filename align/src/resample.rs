//! The adjustable resampler (rubato's `SincFixedOut`) and the exact input position of
//! every frame it puts out.
//!
//! rubato keeps a fractional read index `idx` in the frames of the current call and
//! advances it by `1/ratio` before each output frame; the windowed sinc it applies at
//! `idx` (oversampled by `f`, linear or cubic between the oversampled points) is centred on input
//! frame `idx + L/2 - 1 + 1/f` of the call (`L` the sinc length); after a call it carries
//! `idx - frames consumed` over. So, counting input frames from the first fed, the output
//! frame `j` of a call lies at `g + sum(step) + L/2 - 1 + 1/f` where `g` starts at
//! `-L/2` and grows by the steps of every output frame. [`Stage`] keeps `g` beside
//! rubato and so knows the input position of each output frame exactly (the test
//! `the_position_model_matches_the_resampled_signal` checks it on a tone, to 1e-4 frame).
//! The ratio is set without a ramp, so the steps of a call are all `1/ratio`.
//! rubato's `output_delay()` (`L*ratio/2` output frames, truncated) is the latency of
//! the lookahead it needs, not an offset of positions, and is not used.

use rubato::{Resampler, SincFixedOut, SincInterpolationParameters, SincInterpolationType, WindowFunction};

use crate::Error;

/// The resampler's design.
#[derive(Clone, Copy, Debug)]
pub struct Design {
    /// Sinc length in input frames (a multiple of 8).
    pub sinc_len: usize,
    /// Cutoff relative to the Nyquist frequency.
    pub f_cutoff: f32,
    /// Oversampling of the sinc table.
    pub oversampling: usize,
    /// Cubic interpolation between the table's points (four kernel sums per output frame)
    /// instead of linear (two).
    pub cubic: bool,
}

impl Design {
    /// 256 taps, cutoff 0.95, 256× oversampled table, linear between table points: half the
    /// CPU of cubic (`examples/rsbench.rs`: 1.2 against 2.4 % of a core per stereo follower),
    /// and the tone test's error stays under its 2e-6 bound.
    pub fn standard() -> Design {
        Design { sinc_len: 256, f_cutoff: 0.95, oversampling: 256, cubic: false }
    }
}

/// The largest relative ratio change the stage may be asked for.
pub const MAX_RELATIVE_RATIO: f64 = 1.1;

/// A resampler with its exact output positions.
pub struct Stage {
    rs: SincFixedOut<f64>,
    design: Design,
    nominal_ratio: f64,
    /// `g`: the read index before the next output frame, in input frames from the first fed.
    g: f64,
    /// The step of the next call's output frames (1/ratio).
    step: f64,
    in_buf: Vec<Vec<f64>>,
    out_buf: Vec<Vec<f64>>,
    max_out: usize,
}

impl Stage {
    /// A stage for `channels`, at most `max_out` frames per call, nominal ratio
    /// `nominal_ratio` (output rate / input rate).
    pub fn new(design: Design, channels: usize, max_out: usize, nominal_ratio: f64) -> Result<Stage, Error> {
        let params = SincInterpolationParameters {
            sinc_len: design.sinc_len,
            f_cutoff: design.f_cutoff,
            interpolation: if design.cubic {
                SincInterpolationType::Cubic
            } else {
                SincInterpolationType::Linear
            },
            oversampling_factor: design.oversampling,
            window: WindowFunction::BlackmanHarris2,
        };
        let rs = SincFixedOut::<f64>::new(nominal_ratio, MAX_RELATIVE_RATIO, params, max_out, channels)
            .map_err(|e| Error::Resampler(e.to_string()))?;
        Ok(Stage {
            rs,
            design,
            nominal_ratio,
            g: -((design.sinc_len / 2) as f64),
            step: 1.0 / nominal_ratio,
            in_buf: vec![Vec::new(); channels],
            out_buf: vec![vec![0.0; max_out]; channels],
            max_out,
        })
    }

    /// Half the sinc length: how far an output frame reads on either side, input frames.
    pub fn half_len(&self) -> f64 {
        (self.design.sinc_len / 2) as f64
    }

    /// The input position (frames from the first fed) of the next output frame, at the
    /// current step.
    pub fn next_position(&self) -> f64 {
        self.g + self.step + self.offset()
    }

    fn offset(&self) -> f64 {
        self.half_len() - 1.0 + 1.0 / self.design.oversampling as f64
    }

    /// Sets the step (input frames per output frame) of the next call.
    pub fn set_step(&mut self, step: f64) -> Result<(), Error> {
        let ratio = 1.0 / step;
        self.rs.set_resample_ratio(ratio, false).map_err(|_| Error::StepOutOfRange {
            step,
            nominal: 1.0 / self.nominal_ratio,
            max_relative: MAX_RELATIVE_RATIO,
        })?;
        self.step = step;
        Ok(())
    }

    /// The step of the next call.
    pub fn step(&self) -> f64 {
        self.step
    }

    /// Input frames the next call of `frames` output frames consumes.
    pub fn input_needed(&mut self, frames: usize) -> Result<usize, Error> {
        self.rs.set_chunk_size(frames).map_err(|_| Error::ChunkTooLong { frames, max: self.max_out })?;
        Ok(self.rs.input_frames_next())
    }

    /// Resamples `frames` output frames from `input` (per channel, exactly
    /// [`Stage::input_needed`] frames each), into `out` (per channel).
    pub fn process(&mut self, input: &[&[f64]], frames: usize, out: &mut [Vec<f64>]) -> Result<(), Error> {
        let need = self.input_needed(frames)?;
        for (b, i) in self.in_buf.iter_mut().zip(input) {
            b.clear();
            b.extend_from_slice(&i[..need]);
        }
        let (_, produced) = self
            .rs
            .process_into_buffer(&self.in_buf, &mut self.out_buf, None)
            .map_err(|e| Error::Resampler(e.to_string()))?;
        debug_assert_eq!(produced, frames);
        for (o, b) in out.iter_mut().zip(&self.out_buf) {
            o.clear();
            o.extend_from_slice(&b[..frames]);
        }
        self.g += frames as f64 * self.step;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1 kHz tone through the stage at two steps: every output frame equals the tone
    /// at the position the model gives (within the resampler's own error).
    #[test]
    fn the_position_model_matches_the_resampled_signal() {
        let tone = |x: f64| (std::f64::consts::TAU * 1000.0 / 48_000.0 * x + 0.4).sin();
        let mut stage = Stage::new(Design::standard(), 1, 480, 1.0).unwrap();
        let mut fed = 0usize;
        let mut out = vec![Vec::new()];
        let mut worst = 0.0f64;
        for call in 0..40 {
            stage.set_step(if call < 20 { 1.0 + 1e-3 } else { 1.0 - 7.3e-4 }).unwrap();
            let p0 = stage.next_position();
            let need = stage.input_needed(480).unwrap();
            let input: Vec<f64> = (fed..fed + need).map(|x| tone(x as f64)).collect();
            stage.process(&[&input], 480, &mut out).unwrap();
            fed += need;
            if call >= 2 {
                for (j, &y) in out[0].iter().enumerate() {
                    let p = p0 + j as f64 * stage.step();
                    worst = worst.max((y - tone(p)).abs());
                }
            }
        }
        // 1e-4 frame of position error at 1 kHz is 1.3e-5 of amplitude.
        assert!(worst < 2e-6, "the output strayed {worst:e} from the tone at the modelled positions");
    }
}
