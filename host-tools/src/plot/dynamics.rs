//! The competitive-dynamics lanes of a plot: per `[dynamics.*]` group, under the port strips, a
//! header and one lane per behaviour with its activity n, refractory filter ρ and memory m as
//! lines on a common scale from −1.2 to 1.2 (n saturates at ±1, ρ is in [0, 1], m in [−1, 1]),
//! over a green band wherever its gate is open.
//!
//! A group steps at 1 kHz by default: 6 s make 6000 samples a line, about 5 per pixel column.
//! Lines are drawn through at most four points per column (the column's first, lowest, highest
//! and last value, in time order), which keeps every peak; gate bands are taken from every sample,
//! so an edge is never moved (it lands on the pixel column of its time).

use plotters::element::{PathElement, Rectangle};
use plotters::style::text_anchor::HPos;
use plotters::style::{Color, RGBColor};

use super::{
    Area, BORDER, Band, BehaviourSeries, Canvas, DynamicsSample, GRID, MIN_FONT, PLOT_X0, PLOT_X1,
    SOFT_TEXT, THRESHOLD, TimeAxis, VALUE_SIZE, draw_error, draw_grid, draw_label, line, px,
    rectangle, style, text, text_width, windows,
};

/// A behaviour lane is this many connection strips high (three lines share it).
pub(super) const LANE_STRIPS: f64 = 1.5;

/// The values a lane shows.
const LO: f64 = -1.2;
const HI: f64 = 1.2;

pub(super) const N: RGBColor = style::LINES[0];
pub(super) const RHO: RGBColor = style::LINES[1];
pub(super) const M: RGBColor = style::LINES[2];
pub(super) const GATE: RGBColor = style::GATE;

/// The row of value `v` in lane `b` (clamped to the lane).
pub(super) fn value_y(v: f64, b: Band) -> f64 {
    let f = (v.clamp(LO, HI) - LO) / (HI - LO);
    b.y1 - f * b.height()
}

/// The intervals (seconds) in which the gate is open: from the sample that opens it to the one
/// that closes it, or to `until`. Every sample counts.
pub(super) fn gate_intervals(samples: &[DynamicsSample], until: f64) -> Vec<(f64, f64)> {
    windows::intervals(samples.iter().map(|s| (s.t, s.gate)), until)
}

/// The pixels of a line through `points` (x, y in pixels, x non-decreasing): per pixel column at
/// most its first, lowest, highest and last point, in time order, without repeats.
pub(super) fn thinned(points: impl Iterator<Item = (f64, f64)>) -> Vec<(i32, i32)> {
    let mut out: Vec<(i32, i32)> = Vec::new();
    // The current column: its points' (index, y) for first, lowest, highest, last.
    let mut column: Option<(i32, [(usize, i32); 4])> = None;
    let flush = |out: &mut Vec<(i32, i32)>, x: i32, mut kept: [(usize, i32); 4]| {
        kept.sort_by_key(|&(k, _)| k);
        for (_, y) in kept {
            if out.last() != Some(&(x, y)) {
                out.push((x, y));
            }
        }
    };
    for (k, (x, y)) in points.enumerate() {
        let (x, y) = px(x, y);
        match &mut column {
            Some((cx, kept)) if *cx == x => {
                if y < kept[1].1 {
                    kept[1] = (k, y);
                }
                if y > kept[2].1 {
                    kept[2] = (k, y);
                }
                kept[3] = (k, y);
            }
            _ => {
                if let Some((cx, kept)) = column.take() {
                    flush(&mut out, cx, kept);
                }
                column = Some((x, [(k, y); 4]));
            }
        }
    }
    if let Some((cx, kept)) = column {
        flush(&mut out, cx, kept);
    }
    out
}

/// The legend of the lanes, right-aligned in the group's header row.
pub(super) fn draw_legend<DB: Canvas>(root: &Area<DB>, y: f64, size: f64) -> anyhow::Result<()> {
    if size < MIN_FONT {
        return Ok(());
    }
    let mut x = PLOT_X1;
    for (name, color, width) in [("m", M, 1), ("ρ", RHO, 1), ("n", N, 2)] {
        x -= text_width(root, name, size, false)?;
        text(root, name, (x, y), size, false, SOFT_TEXT, HPos::Left)?;
        x -= 30.0;
        root.draw(&PathElement::new(
            vec![px(x, y), px(x + 24.0, y)],
            color.stroke_width(width),
        ))
        .map_err(draw_error)?;
        x -= 18.0;
    }
    let name = "gate open";
    x -= text_width(root, name, size, false)?;
    text(root, name, (x, y), size, false, SOFT_TEXT, HPos::Left)?;
    x -= 30.0;
    let swatch = Rectangle::new(
        [px(x, y - size * 0.45), px(x + 24.0, y + size * 0.45)],
        GATE.filled(),
    );
    root.draw(&swatch).map_err(draw_error)
}

/// Which value of a sample a line draws.
type Value = fn(&DynamicsSample) -> f64;

/// One behaviour's lane: gate bands, grid, box, value ticks, label, then ρ, m and n on top.
pub(super) fn draw_lane<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    behaviour: &BehaviourSeries,
    b: Band,
) -> anyhow::Result<()> {
    if b.height() < 1.0 {
        return Ok(());
    }
    let open = gate_intervals(&behaviour.samples, axis.until);
    windows::draw_bands(root, axis, &open, GATE, "", b)?;
    draw_grid(root, axis, b)?;
    for v in [-1.0, 1.0] {
        line(
            root,
            (PLOT_X0, value_y(v, b)),
            (PLOT_X1, value_y(v, b)),
            GRID,
        )?;
    }
    line(
        root,
        (PLOT_X0, value_y(0.0, b)),
        (PLOT_X1, value_y(0.0, b)),
        THRESHOLD,
    )?;
    rectangle(root, b, BORDER.stroke_width(1))?;
    if b.height() >= 40.0 {
        for (v, name) in [(-1.0, "−1"), (0.0, "0"), (1.0, "1")] {
            let at = (PLOT_X0 - 6.0, value_y(v, b));
            text(root, name, at, VALUE_SIZE, false, SOFT_TEXT, HPos::Right)?;
        }
    }
    draw_label(root, &behaviour.label, &behaviour.name, b, 3)?;

    let usable: Vec<&DynamicsSample> = behaviour
        .samples
        .iter()
        .filter(|s| s.t.is_finite() && (0.0..=axis.until).contains(&s.t))
        .collect();
    // ρ and m under n.
    let series: [(Value, RGBColor, u32); 3] =
        [(|s| s.rho, RHO, 1), (|s| s.m, M, 1), (|s| s.n, N, 2)];
    for (value, color, width) in series {
        let points = thinned(
            usable
                .iter()
                .filter(|s| !value(s).is_nan())
                .map(|s| (axis.x(s.t), value_y(value(s), b))),
        );
        if let [(x, y)] = points[..] {
            let dot = Rectangle::new([(x - 1, y - 1), (x + 1, y + 1)], color.filled());
            root.draw(&dot).map_err(draw_error)?;
            continue;
        }
        // Segment by segment, as the stimulation curves (no mitred spikes).
        for pair in points.windows(2) {
            let path = PathElement::new(pair.to_vec(), color.stroke_width(width));
            root.draw(&path).map_err(draw_error)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{DynamicsSeries, Layout, PlotData, render};
    use super::*;

    fn at(t: f64, gate: bool) -> DynamicsSample {
        DynamicsSample {
            t,
            n: 0.0,
            rho: 0.0,
            m: -1.0,
            gate,
        }
    }

    /// Four behaviours over 6 s at 1 kHz, no port: behaviour k's gate is open from k + 0.6 s
    /// (to the millisecond: k + 0.6 + k / 1000; off the grid lines of the ticks) to k + 1.7 s, n at ±1 there and noisy near 0
    /// elsewhere.
    fn four_behaviours() -> PlotData {
        let mut noise = 1u32;
        let behaviours = (0..4u32)
            .map(|k| {
                let opens = 600 + 1001 * k;
                let closes = 1700 + 1000 * k;
                let samples = (0..=6000u32)
                    .map(|step| {
                        noise ^= noise << 13;
                        noise ^= noise >> 17;
                        noise ^= noise << 5;
                        let open = (opens..closes).contains(&step);
                        let n = if open {
                            if k % 2 == 0 { 1.0 } else { -1.0 }
                        } else {
                            f64::from(noise) / f64::from(u32::MAX) * 0.1 - 0.05
                        };
                        DynamicsSample {
                            t: f64::from(step) / 1000.0,
                            n,
                            rho: f64::from(step.min(1000)) / 1000.0,
                            m: if open { 1.0 } else { -1.0 },
                            gate: open,
                        }
                    })
                    .collect();
                BehaviourSeries {
                    name: format!("g.b{k}"),
                    label: format!("g.b{k}  context C{k}"),
                    samples,
                }
            })
            .collect();
        PlotData {
            title: "dynamics (test)".to_string(),
            until: 6.0,
            dynamics: vec![DynamicsSeries {
                name: "dynamics g (node base, step 1 ms)".to_string(),
                behaviours,
            }],
            ..PlotData::default()
        }
    }

    #[test]
    fn four_lanes_over_six_seconds_with_their_gates_at_their_edges() {
        let data = four_behaviours();
        let layout = Layout::new(&data);
        // Title 48, header 30, 4 lanes of 1.5 × 66, ticks 22, caption 20, bottom 10.
        assert_eq!(layout.height, 526);
        assert_eq!(layout.dynamics.len(), 1);
        let lanes = &layout.dynamics[0].strips;
        assert_eq!(lanes.len(), 4);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lanes.png");
        render(&data, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1400, 526));
        let axis = TimeAxis::new(6.0);
        let colour = |c: RGBColor| image::Rgb([c.0, c.1, c.2]);
        for (k, lane) in lanes.iter().enumerate() {
            let pixels = |c: RGBColor| -> Vec<u32> {
                let mut xs = Vec::new();
                for y in lane.y0.ceil() as u32..lane.y1.floor() as u32 {
                    for x in PLOT_X0 as u32..=PLOT_X1 as u32 {
                        if *img.get_pixel(x, y) == colour(c) {
                            xs.push(x);
                        }
                    }
                }
                xs
            };
            // The band spans exactly the columns from its opening's to the one before its
            // closing's.
            let band = pixels(GATE);
            let from = axis.x(0.6 + 1.001 * k as f64).round() as u32;
            let to = axis.x(1.7 + k as f64).round() as u32 - 1;
            assert_eq!(band.iter().min(), Some(&from), "lane {k}");
            assert_eq!(band.iter().max(), Some(&to), "lane {k}");
            // Each line is there; n at ±1 inside the band.
            assert!(pixels(N).len() > 1000, "lane {k}");
            assert!(pixels(RHO).len() > 300, "lane {k}");
            assert!(pixels(M).len() > 300, "lane {k}");
            let level = if k % 2 == 0 { 1.0 } else { -1.0 };
            let y = value_y(level, *lane).round() as u32;
            let middle = axis.x(1.0 + k as f64).round() as u32;
            assert!(
                (y - 1..=y + 1).any(|y| *img.get_pixel(middle, y) == colour(N)),
                "lane {k}"
            );
        }
    }

    #[test]
    fn gate_intervals_keep_every_edge() {
        let samples: Vec<DynamicsSample> = (0..=6000)
            .map(|k| {
                let t = f64::from(k) / 1000.0;
                at(t, (1237..2001).contains(&k) || k >= 5999)
            })
            .collect();
        assert_eq!(
            gate_intervals(&samples, 6.0),
            [(1.237, 2.001), (5.999, 6.0)]
        );
        assert_eq!(gate_intervals(&[], 6.0), []);
        assert_eq!(gate_intervals(&[at(f64::NAN, true)], 6.0), []);
    }

    #[test]
    fn thinning_keeps_the_extremes_of_each_column_in_time_order() {
        // Ten points in column 10 going down to 3 then up to 30, then one in column 11.
        let ys = [10.0, 5.0, 3.0, 8.0, 30.0, 12.0, 12.0, 12.0, 12.0, 11.0];
        let points = ys
            .iter()
            .map(|&y| (10.2, y))
            .chain([(11.0, 11.0), (11.1, 11.0)]);
        assert_eq!(
            thinned(points),
            [(10, 10), (10, 3), (10, 30), (10, 11), (11, 11)]
        );
        assert_eq!(thinned(std::iter::empty()), []);
    }
}
