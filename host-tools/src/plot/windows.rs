//! Strips that show when something holds rather than a level: a special connection's windows
//! (suppress, inhibit, write-inhibit, override: active from a frame until its period has passed
//! without one) and a competitive-dynamics gate's open intervals. Both come from the samples'
//! `active` flag, the connection's x as the port's node computes it; each interval is a filled
//! band from the sample that sets it to the one that clears it (or to the end of the axis), named
//! inside where the name fits.

use plotters::element::{PathElement, Rectangle};
use plotters::style::Color;
use plotters::style::RGBColor;
use plotters::style::text_anchor::HPos;

use super::{
    Area, BORDER, Band, Canvas, ConnectionSeries, LABEL_SIZE, MIN_FONT, NOT_SELECTED, PLOT_X1,
    SELECTED, SOFT_TEXT, TEXT, TimeAxis, clean, draw_error, px, rectangle, style, text, text_width,
};

/// The intervals (seconds) in which a flag holds, from `(time, flag)` points in time order: from
/// the point that sets it to the one that clears it, or to `until`. Points with a non-finite time
/// are skipped.
pub(super) fn intervals(
    points: impl IntoIterator<Item = (f64, bool)>,
    until: f64,
) -> Vec<(f64, f64)> {
    let mut intervals = Vec::new();
    let mut open: Option<f64> = None;
    for (t, on) in points.into_iter().filter(|(t, _)| t.is_finite()) {
        match (open, on) {
            (None, true) => open = Some(t),
            (Some(from), false) => {
                intervals.push((from, t));
                open = None;
            }
            _ => {}
        }
    }
    if let Some(from) = open {
        intervals.push((from, until.max(from)));
    }
    intervals
}

/// The windows in which `connection` is active.
pub(super) fn windows(connection: &ConnectionSeries, until: f64) -> Vec<(f64, f64)> {
    intervals(connection.samples.iter().map(|s| (s.t, s.active)), until)
}

/// A special connection's strip: a band per window, named after its `kind`; for one that
/// `delivers` (an override), a line along the band's top, green while it is selected and orange
/// while it is not.
pub(super) fn draw_windows<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    connection: &ConnectionSeries,
    kind: &str,
    delivers: bool,
    b: Band,
) -> anyhow::Result<()> {
    let fill = if delivers {
        style::OVERRIDE
    } else {
        style::WINDOW
    };
    let spans = windows(connection, axis.until);
    draw_bands(root, axis, &spans, fill, kind, b)?;
    if delivers {
        let selected = intervals(
            connection.samples.iter().map(|s| (s.t, s.selected)),
            axis.until,
        );
        let top = b.y0 + 1.0;
        for (spans, colour) in [(&spans, NOT_SELECTED), (&selected, SELECTED)] {
            for &(from, to) in spans.iter() {
                if to < 0.0 || from > axis.until {
                    continue;
                }
                let path = PathElement::new(
                    vec![px(axis.x(from), top), px(axis.x(to), top)],
                    colour.stroke_width(3),
                );
                root.draw(&path).map_err(draw_error)?;
            }
        }
    }
    rectangle(root, b, BORDER.stroke_width(1))
}

/// A gate's strip: a band while it is open, named after the gate.
pub(super) fn draw_gate<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    connection: &ConnectionSeries,
    b: Band,
) -> anyhow::Result<()> {
    let spans = windows(connection, axis.until);
    let name = format!("{} open", connection.name);
    draw_bands(root, axis, &spans, style::GATE, &name, b)?;
    rectangle(root, b, BORDER.stroke_width(1))
}

/// Bands of colour `fill` over the intervals `spans` (clipped to the axis; at least a pixel
/// wide), each with `name` centred inside where it fits.
pub(super) fn draw_bands<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    spans: &[(f64, f64)],
    fill: RGBColor,
    name: &str,
    b: Band,
) -> anyhow::Result<()> {
    let size = style::snap(LABEL_SIZE.min(b.height() * 0.6));
    let name = clean(name);
    let width = text_width(root, &name, size, false)?;
    let shown: Vec<(f64, f64)> = spans
        .iter()
        .copied()
        .filter(|&(from, to)| to >= 0.0 && from <= axis.until)
        .collect();
    for (k, &(from, to)) in shown.iter().enumerate() {
        // Columns from the start's to the one before the end's (plotters fills up to, not
        // including, the right edge), at least one: a window of a step shows.
        let (x0, y0) = px(axis.x(from), b.y0);
        let (x1, y1) = px(axis.x(to), b.y1);
        let x1 = x1.max(x0 + 1);
        let band = Rectangle::new([(x0, y0), (x1, y1)], fill.filled());
        root.draw(&band).map_err(draw_error)?;
        if size < MIN_FONT || name.is_empty() {
            continue;
        }
        // The name inside the band, else right of it if that leaves room before the next.
        let (x0, x1) = (f64::from(x0), f64::from(x1));
        let next = shown.get(k + 1).map_or(PLOT_X1, |&(from, _)| axis.x(from));
        if width <= x1 - x0 - 6.0 {
            let centre = ((x0 + x1) / 2.0, b.middle());
            text(root, &name, centre, size, false, TEXT, HPos::Center)?;
        } else if x1 + 4.0 + width <= next - 4.0 {
            let at = (x1 + 4.0, b.middle());
            text(root, &name, at, size, false, SOFT_TEXT, HPos::Left)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::{Sample, Shows};

    fn sample(t: f64, level: f64, active: bool) -> Sample {
        Sample {
            t,
            level,
            active,
            selected: false,
        }
    }

    #[test]
    fn a_suppressors_windows_run_from_its_frames_to_their_period_s_end() {
        // As the simulator samples a suppressor with a period of 1 s and frames at 2 s and
        // 2.5 s, then 6 s: inactive on the grid, active from a frame's instant, inactive again
        // 1 µs after the last frame's period (its wake-up), where the level is 0.
        let samples = vec![
            sample(0.0, 0.0, false),
            sample(1.0, 0.0, false),
            sample(2.0, 1.0, true),
            sample(2.2, 0.9, true),
            sample(2.5, 1.0, true),
            sample(3.0, 0.6, true),
            sample(3.5, 0.0, true),
            sample(3.500001, 0.0, false),
            sample(4.0, 0.0, false),
            sample(6.0, 1.0, true),
            sample(f64::NAN, 1.0, false),
            sample(6.5, 0.7, true),
        ];
        let connection = ConnectionSeries {
            name: "HALT".into(),
            label: String::new(),
            shows: Shows::Window {
                kind: "suppress".into(),
                delivers: false,
            },
            samples,
        };
        // The last window is still open when the axis ends.
        assert_eq!(windows(&connection, 6.8), [(2.0, 3.500001), (6.0, 6.8)]);
        assert_eq!(intervals([], 5.0), []);
        assert_eq!(intervals([(1.0, false), (f64::INFINITY, true)], 5.0), []);
        // A window opened after the end of the axis ends where it starts.
        assert_eq!(intervals([(7.0, true)], 5.0), [(7.0, 7.0)]);
    }
}
