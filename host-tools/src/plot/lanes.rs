//! Step lanes under the dynamics: HBBA's selected strategies (a lane full while the strategy
//! runs) and its filters' commanded pass rates (a lane filled up to 1/φ, with the φ written at
//! each change where there is room). A value holds from its step to the next one, or to the end
//! of the axis; before the first step it is 0.

use plotters::element::Rectangle;
use plotters::style::text_anchor::HPos;
use plotters::style::{Color, RGBColor};

use super::{
    Area, BORDER, Band, Canvas, LEGEND_SIZE, MIN_FONT, PLOT_X0, SOFT_TEXT, TimeAxis, clean,
    draw_error, draw_grid, draw_label, px, rectangle, style, text, text_width,
};
use pab_lang::series::Lane;

/// A lane is this many connection strips high.
pub(super) const LANE_STRIPS: f64 = 0.5;

/// The fill of a lane's value.
pub(super) const FILL: RGBColor = style::FILL;

/// The intervals (seconds, clipped to [0, until]) and values of a lane's steps; non-finite
/// steps are skipped, values clamped to [0, 1].
pub(super) fn intervals(lane: &Lane, until: f64) -> Vec<(f64, f64, f64)> {
    let steps: Vec<(f64, f64)> = lane
        .steps
        .iter()
        .filter(|s| s.t.is_finite() && !s.value.is_nan())
        .map(|s| (s.t.clamp(0.0, until), s.value.clamp(0.0, 1.0)))
        .collect();
    steps
        .iter()
        .enumerate()
        .map(|(k, &(t, value))| {
            let end = steps.get(k + 1).map_or(until, |next| next.0);
            (t, end.max(t), value)
        })
        .filter(|&(from, to, value)| to > from && value > 0.0)
        .collect()
}

/// One lane: grid, fill, box, label and the notes of its steps.
pub(super) fn draw_lane<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    lane: &Lane,
    b: Band,
) -> anyhow::Result<()> {
    if b.height() < 1.0 {
        return Ok(());
    }
    draw_grid(root, axis, b)?;
    for (from, to, value) in intervals(lane, axis.until) {
        let top = b.y1 - value * b.height();
        let (x0, y0) = px(axis.x(from), top);
        let (x1, y1) = px(axis.x(to), b.y1);
        let fill = Rectangle::new([(x0, y0), (x1.max(x0 + 1), y1)], FILL.filled());
        root.draw(&fill).map_err(draw_error)?;
    }
    rectangle(root, b, BORDER.stroke_width(1))?;
    draw_label(root, &lane.label, &lane.name, b, 2)?;

    let size = LEGEND_SIZE.min(b.height() * 0.6);
    if size >= MIN_FONT {
        // A note only where the previous one ends: steps closer than a note's width share one.
        let mut free_from = PLOT_X0;
        for step in &lane.steps {
            let Some(note) = &step.text else {
                continue;
            };
            if !step.t.is_finite() || step.t > axis.until {
                continue;
            }
            let x = axis.x(step.t) + 3.0;
            if x < free_from {
                continue;
            }
            let note = clean(note);
            text(
                root,
                &note,
                (x, b.middle()),
                size,
                false,
                SOFT_TEXT,
                HPos::Left,
            )?;
            free_from = x + text_width(root, &note, size, false)? + 4.0;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{Layout, PLOT_X1, PlotData, render};
    use super::*;
    use pab_lang::series::{LaneGroup, LaneStep};

    fn step(t: f64, value: f64) -> LaneStep {
        LaneStep {
            t,
            value,
            text: None,
        }
    }

    #[test]
    fn steps_hold_until_the_next_and_zero_or_broken_steps_draw_nothing() {
        let lane = Lane {
            name: "FACE".into(),
            label: String::new(),
            steps: vec![
                step(0.0, 0.0),
                step(1.0, 1.0),
                step(8.0, 1.0 / 3.0),
                step(f64::NAN, 1.0),
                step(12.0, 2.0),
            ],
        };
        assert_eq!(
            intervals(&lane, 20.0),
            [(1.0, 8.0, 1.0), (8.0, 12.0, 1.0 / 3.0), (12.0, 20.0, 1.0)]
        );
        // Past the axis: clipped, and a step at the end draws nothing.
        assert_eq!(
            intervals(&lane, 10.0),
            [(1.0, 8.0, 1.0), (8.0, 10.0, 1.0 / 3.0)]
        );
    }

    #[test]
    fn a_lane_is_filled_up_to_its_value_from_step_to_step() {
        let steps = |v: &[(f64, f64)]| v.iter().map(|&(t, value)| step(t, value)).collect();
        let data = PlotData {
            title: "lanes".into(),
            until: 10.0,
            lanes: vec![LaneGroup {
                name: "HBBA intention".into(),
                lanes: vec![
                    Lane {
                        name: "on".into(),
                        label: "on  from 2 s to 6 s".into(),
                        steps: steps(&[(0.0, 0.0), (2.0, 1.0), (6.0, 0.0)]),
                    },
                    Lane {
                        name: "third".into(),
                        label: String::new(),
                        steps: steps(&[(4.0, 1.0 / 3.0)]),
                    },
                ],
            }],
            ..PlotData::default()
        };
        let layout = Layout::new(&data);
        // Title 48, header 30, 2 lanes of 33, ticks 22, caption 20, bottom 10.
        assert_eq!(layout.height, 196);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lanes.png");
        render(&data, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        let axis = TimeAxis::new(10.0);
        let filled = |b: Band| -> Vec<(u32, u32)> {
            let mut at = Vec::new();
            for y in b.y0.ceil() as u32..b.y1.floor() as u32 {
                for x in PLOT_X0 as u32..=PLOT_X1 as u32 {
                    if img.get_pixel(x, y).0 == [FILL.0, FILL.1, FILL.2] {
                        at.push((x, y));
                    }
                }
            }
            at
        };
        let lanes = &layout.lanes[0].strips;
        let on = filled(lanes[0]);
        let xs = |v: &[(u32, u32)]| (v.iter().map(|p| p.0).min(), v.iter().map(|p| p.0).max());
        assert_eq!(xs(&on).0, Some(axis.x(2.0).round() as u32));
        assert_eq!(xs(&on).1, Some(axis.x(6.0).round() as u32 - 1));
        let third = filled(lanes[1]);
        assert_eq!(xs(&third).0, Some(axis.x(4.0).round() as u32));
        // A third of the lane's height, from its bottom.
        let top = third.iter().map(|p| p.1).min().unwrap() as f64;
        let expected = lanes[1].y1 - lanes[1].height() / 3.0;
        assert!((top - expected).abs() <= 1.5, "{top} vs {expected}");
    }
}
