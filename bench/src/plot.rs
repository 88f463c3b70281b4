//! PNG plots drawn with embedded-graphics (lines and its built-in bitmap fonts, so no
//! system fonts are needed) and encoded with the `png` crate.

use std::path::Path;

use embedded_graphics::mono_font::ascii::{FONT_6X10, FONT_7X13_BOLD};
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Circle, Line, PrimitiveStyle, Rectangle};
use embedded_graphics::text::{Alignment, Text};

/// Series colours (colour-blind friendly).
pub const COLORS: [Rgb888; 7] = [
    Rgb888::new(0, 114, 178),
    Rgb888::new(213, 94, 0),
    Rgb888::new(0, 158, 115),
    Rgb888::new(204, 121, 167),
    Rgb888::new(86, 180, 233),
    Rgb888::new(230, 159, 0),
    Rgb888::new(80, 80, 80),
];

/// One line of points.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Colour.
    pub color: Rgb888,
    /// (x, y) points, drawn in order.
    pub points: Vec<(f64, f64)>,
    /// Dashed line (for baselines).
    pub dashed: bool,
}

/// One panel.
pub struct Chart {
    /// Title.
    pub title: String,
    /// X axis label.
    pub xlabel: String,
    /// Y axis label.
    pub ylabel: String,
    /// Log-scale x.
    pub xlog: bool,
    /// Log-scale y.
    pub ylog: bool,
    /// Lines.
    pub series: Vec<Series>,
    /// Formats a tick value on x.
    pub xfmt: fn(f64) -> String,
    /// Formats a tick value on y.
    pub yfmt: fn(f64) -> String,
}

struct Canvas {
    w: u32,
    h: u32,
    px: Vec<u8>,
}

impl OriginDimensions for Canvas {
    fn size(&self) -> Size {
        Size::new(self.w, self.h)
    }
}

impl DrawTarget for Canvas {
    type Color = Rgb888;
    type Error = std::convert::Infallible;

    fn draw_iter<I: IntoIterator<Item = Pixel<Rgb888>>>(&mut self, pixels: I) -> Result<(), Self::Error> {
        for Pixel(p, c) in pixels {
            if p.x >= 0 && p.y >= 0 && (p.x as u32) < self.w && (p.y as u32) < self.h {
                let i = 3 * (p.y as usize * self.w as usize + p.x as usize);
                self.px[i..i + 3].copy_from_slice(&[c.r(), c.g(), c.b()]);
            }
        }
        Ok(())
    }
}

const PW: i32 = 600;
const PH: i32 = 400;

fn text(c: &mut Canvas, s: &str, x: i32, y: i32, align: Alignment) {
    // The built-in fonts are ASCII.
    let s = &s.replace('µ', "u").replace('→', "->").replace('×', "x");
    let style = MonoTextStyle::new(&FONT_6X10, Rgb888::BLACK);
    let _ = Text::with_alignment(s, Point::new(x, y), style, align).draw(c);
}

/// Ticks for an axis range: decades on a log axis, about 6 round steps on a linear one.
fn ticks(lo: f64, hi: f64, log: bool) -> Vec<f64> {
    if log {
        let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
        (a..=b).map(|e| 10f64.powi(e)).collect()
    } else {
        let span = (hi - lo).max(1e-12);
        let raw = span / 6.0;
        let mag = 10f64.powf(raw.log10().floor());
        let step =
            [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| span / s <= 7.0).unwrap_or(10.0 * mag);
        let mut v = (lo / step).floor() * step;
        let mut out = Vec::new();
        while v <= hi + step * 0.5 {
            out.push(v);
            v += step;
        }
        out
    }
}

/// A line drawn as 6-pixel dashes with 4-pixel gaps.
fn dashed_line(c: &mut Canvas, a: Point, b: Point, style: PrimitiveStyle<Rgb888>) {
    let (dx, dy) = ((b.x - a.x) as f64, (b.y - a.y) as f64);
    let len = (dx * dx + dy * dy).sqrt();
    let mut t = 0.0;
    while t < len {
        let e = (t + 6.0).min(len);
        let p = |u: f64| Point::new(a.x + (dx * u / len).round() as i32, a.y + (dy * u / len).round() as i32);
        let _ = Line::new(p(t), p(e)).into_styled(style).draw(c);
        t += 10.0;
    }
}

fn draw_panel(c: &mut Canvas, ch: &Chart, ox: i32, oy: i32) {
    let (left, right, top, bottom) = (ox + 70, ox + PW - 15, oy + 28, oy + PH - 45);
    let title_style = MonoTextStyle::new(&FONT_7X13_BOLD, Rgb888::BLACK);
    let _ = Text::with_alignment(&ch.title, Point::new(ox + PW / 2, oy + 16), title_style, Alignment::Center)
        .draw(c);
    let pts: Vec<(f64, f64)> = ch
        .series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&(x, y)| x.is_finite() && y.is_finite() && (!ch.xlog || x > 0.0) && (!ch.ylog || y > 0.0))
        .collect();
    if pts.is_empty() {
        text(c, "no data", ox + PW / 2, oy + PH / 2, Alignment::Center);
        return;
    }
    let range = |v: Vec<f64>, log: bool| {
        let (mut lo, mut hi) =
            v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        if log {
            lo = 10f64.powf(lo.log10().floor());
            hi = 10f64.powf(hi.log10().ceil());
            if hi <= lo {
                hi = lo * 10.0;
            }
        } else {
            lo = lo.min(0.0);
            hi = if hi <= lo { lo + 1.0 } else { hi * 1.08 };
        }
        (lo, hi)
    };
    let (x0, x1) = range(pts.iter().map(|p| p.0).collect(), ch.xlog);
    let (y0, y1) = range(pts.iter().map(|p| p.1).collect(), ch.ylog);
    let fx = |x: f64| {
        let t =
            if ch.xlog { (x.log10() - x0.log10()) / (x1.log10() - x0.log10()) } else { (x - x0) / (x1 - x0) };
        left + (t * (right - left) as f64).round() as i32
    };
    let fy = |y: f64| {
        let t =
            if ch.ylog { (y.log10() - y0.log10()) / (y1.log10() - y0.log10()) } else { (y - y0) / (y1 - y0) };
        bottom - (t * (bottom - top) as f64).round() as i32
    };
    let grid = PrimitiveStyle::with_stroke(Rgb888::new(225, 225, 225), 1);
    let axis = PrimitiveStyle::with_stroke(Rgb888::BLACK, 1);
    for t in ticks(x0, x1, ch.xlog).into_iter().filter(|&t| t >= x0 * 0.999 && t <= x1 * 1.001) {
        let x = fx(t);
        let _ = Line::new(Point::new(x, top), Point::new(x, bottom)).into_styled(grid).draw(c);
        text(c, &(ch.xfmt)(t), x, bottom + 13, Alignment::Center);
    }
    for t in ticks(y0, y1, ch.ylog).into_iter().filter(|&t| t >= y0 * 0.999 && t <= y1 * 1.001) {
        let y = fy(t);
        let _ = Line::new(Point::new(left, y), Point::new(right, y)).into_styled(grid).draw(c);
        text(c, &(ch.yfmt)(t), left - 4, y + 3, Alignment::Right);
    }
    let _ =
        Rectangle::with_corners(Point::new(left, top), Point::new(right, bottom)).into_styled(axis).draw(c);
    text(c, &ch.xlabel, (left + right) / 2, bottom + 30, Alignment::Center);
    text(c, &ch.ylabel, ox + 4, top - 6, Alignment::Left);
    for s in &ch.series {
        let style = PrimitiveStyle::with_stroke(s.color, 2);
        let p: Vec<Point> = s
            .points
            .iter()
            .filter(|&&(x, y)| {
                x.is_finite() && y.is_finite() && (!ch.xlog || x > 0.0) && (!ch.ylog || y > 0.0)
            })
            .map(|&(x, y)| Point::new(fx(x), fy(y)))
            .collect();
        for w in p.windows(2) {
            if s.dashed {
                dashed_line(c, w[0], w[1], style);
            } else {
                let _ = Line::new(w[0], w[1]).into_styled(style).draw(c);
            }
        }
        if p.len() < 40 {
            for q in &p {
                let _ = Circle::with_center(*q, 5).into_styled(PrimitiveStyle::with_fill(s.color)).draw(c);
            }
        }
    }
    // Legend, top left inside the plot.
    for (i, s) in ch.series.iter().enumerate() {
        let y = top + 10 + 12 * i as i32;
        let style = PrimitiveStyle::with_stroke(s.color, 3);
        let (a, b) = (Point::new(left + 6, y - 3), Point::new(left + 22, y - 3));
        if s.dashed {
            dashed_line(c, a, b, style);
        } else {
            let _ = Line::new(a, b).into_styled(style).draw(c);
        }
        text(c, &s.name, left + 26, y, Alignment::Left);
    }
}

/// Renders panels in a grid of `cols` columns and writes a PNG.
pub fn render(charts: &[Chart], cols: usize, path: &Path) -> std::io::Result<()> {
    let rows = charts.len().div_ceil(cols);
    let (w, h) = (PW as u32 * cols as u32, PH as u32 * rows as u32);
    let mut c = Canvas { w, h, px: vec![255; (w * h * 3) as usize] };
    for (i, ch) in charts.iter().enumerate() {
        draw_panel(&mut c, ch, PW * (i % cols) as i32, PH * (i / cols) as i32);
    }
    let f = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().map_err(std::io::Error::other)?;
    wr.write_image_data(&c.px).map_err(std::io::Error::other)?;
    wr.finish().map_err(std::io::Error::other)?;
    Ok(())
}

/// Tick formatter: nanoseconds.
pub fn fmt_ns_tick(v: f64) -> String {
    crate::stats::fmt_ns(v).replace(".0 ", " ").replace(".00 ", " ").replace(' ', "").replace('µ', "u")
}

/// Tick formatter: bytes, decimal prefixes (ticks fall on powers of ten).
pub fn fmt_bytes_tick(v: f64) -> String {
    match v {
        v if v >= 1e9 => format!("{}GB", v / 1e9),
        v if v >= 1e6 => format!("{}MB", v / 1e6),
        v if v >= 1e3 => format!("{}kB", v / 1e3),
        v => format!("{v}B"),
    }
}

/// Tick formatter: plain number.
pub fn fmt_num_tick(v: f64) -> String {
    if v >= 1.0 || v == 0.0 {
        format!("{v}")
    } else {
        format!("{v:.3}").trim_end_matches('0').to_owned()
    }
}
