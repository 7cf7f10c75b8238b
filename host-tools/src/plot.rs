//! Stimulation plots in the style of the paper's Fig. 5.
//!
//! One strip per connection, grouped by port; each strip draws the connection's stimulation over
//! time, green while the connection is the one selected at its port (its frames get through) and
//! orange otherwise. Under the ports, the competitive-dynamics groups' lanes (`plot/dynamics.rs`), then
//! step lanes such as HBBA's selected strategies and filter pass rates (`plot/lanes.rs`), if any. An
//! optional bottom strip names the scenario's phases.

use std::path::Path;

use anyhow::ensure;
use plotters::element::{PathElement, Rectangle, Text};
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{Color, RGBColor, ShapeStyle};

mod dynamics;
mod lanes;
pub mod schema;
mod style;
mod windows;

pub use pab_lang::series::{
    BehaviourSeries, ConnectionSeries, DynamicsSample, DynamicsSeries, Lane, LaneGroup, LaneStep,
    Phase, PlotData, PortSeries, Sample, Shows,
};
pub use style::{EXTENSIONS, Format};

use style::{
    Area, BACKGROUND, BORDER, Canvas, GRID, HEADER_SIZE, LABEL_SIZE, LABEL_X1, LEGEND_SIZE,
    MARGIN_X, MIN_FONT, NOT_SELECTED, PLOT_X0, PLOT_X1, Picture, SELECTED, SEPARATOR, SHADES,
    SOFT_TEXT, TEXT, THRESHOLD, TICK_SIZE, TITLE_H, TITLE_SIZE, VALUE_SIZE, WIDTH, draw_error,
    font,
};

/// No image gets taller than this: past it, strips (and, if need be, everything else) shrink.
const MAX_HEIGHT: u32 = 6000;

// Natural heights (pixels) of the rows the image is made of.
const HEADER_H: f64 = 30.0;
/// One connection: its strip plus the gap to the next one.
const STRIP_H: f64 = 66.0;
/// Strips shrink down to this before anything else does.
const MIN_STRIP_H: f64 = 20.0;
/// Fraction of a strip's height left as a gap between two strips.
const STRIP_GAP: f64 = 0.12;
const TICKS_H: f64 = 22.0;
const PHASE_GAP_H: f64 = 10.0;
const PHASE_H: f64 = 34.0;
const CAPTION_H: f64 = 20.0;
const BOTTOM_H: f64 = 10.0;

/// Levels shown in a strip: a little room below 0 and above the threshold 1.
const LEVEL_LO: f64 = -0.06;
const LEVEL_HI: f64 = 1.14;

/// Labels longer than this are cut before being measured.
const MAX_LABEL_CHARS: usize = 300;

/// Draws `data` into a PNG or SVG file at `path`, after its extension (`.png` or `.svg`); both
/// are drawn by the same code, the SVG with its texts as text.
///
/// The image is 1400 pixels wide. From top to bottom: the title (with a colour legend on the
/// right), then for each port a header with its name and one strip per connection, then for each
/// dynamics group a header with a legend and one lane per behaviour (1.5 strips high: n, ρ, m
/// and the gate, `plot/dynamics.rs`), then for each lane group (HBBA's intention) a header and one
/// half-strip lane per step series (`plot/lanes.rs`), then, if there are phases, a strip naming
/// them. A connection strip shows what its [`Shows`] says (`plot/windows.rs` for windows and
/// gates); a stimulation strip plots the stimulation (0 to 1, with a light line at the
/// activation threshold 1) against time, from 0 to `data.until` seconds: green where the
/// connection is selected at its port, orange elsewhere. A segment between two samples takes
/// the colour of the first; samples sharing a time make a vertical jump. Samples with a
/// non-finite time or level are skipped, levels are clamped to the strip and the curve is
/// clipped to the time axis.
///
/// A connection strip is 66 pixels high (gap included); when the image would be taller than
/// 6000 pixels, strips shrink (down to 20 pixels), then everything below the title does.
///
/// Fails if `data.until` is not a finite positive number, if `path` ends in neither `.png` nor
/// `.svg`, or if the file cannot be written.
pub fn render(data: &PlotData, path: &Path) -> anyhow::Result<()> {
    ensure!(
        data.until.is_finite() && data.until > 0.0,
        "cannot plot: the time axis must end after 0 s, but it ends at {} s",
        data.until
    );
    let layout = Layout::new(data);
    style::render(&Stimulation { data, layout }, path)
}

/// The stimulation plot as a picture.
struct Stimulation<'a> {
    data: &'a PlotData,
    layout: Layout,
}

impl Picture for Stimulation<'_> {
    fn size(&self) -> (u32, u32) {
        (WIDTH, self.layout.height)
    }

    fn draw<DB: Canvas>(&self, root: &Area<DB>) -> anyhow::Result<()> {
        draw(root, self.data, &self.layout)
    }
}

/// A horizontal band of the image, in pixels from the top.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Band {
    y0: f64,
    y1: f64,
}

impl Band {
    fn height(&self) -> f64 {
        self.y1 - self.y0
    }

    fn middle(&self) -> f64 {
        (self.y0 + self.y1) / 2.0
    }
}

/// Where one port's rows go.
#[derive(Clone, Debug, PartialEq)]
struct PortLayout {
    header: Band,
    /// The plot box of each connection (gaps excluded), in the port's order.
    strips: Vec<Band>,
    /// The row of time tick labels under the port's last strip, if it has one.
    ticks: Option<Band>,
}

/// Where everything goes: computed from the numbers of ports, connections and phases only.
#[derive(Clone, Debug, PartialEq)]
struct Layout {
    height: u32,
    /// 1 unless the image hit `MAX_HEIGHT` even with strips at `MIN_STRIP_H`: then every row
    /// (and its text) below the title is this much smaller.
    scale: f64,
    title: Band,
    ports: Vec<PortLayout>,
    /// Each dynamics group's header, lanes (one per behaviour) and ticks, under the ports.
    dynamics: Vec<PortLayout>,
    /// Each lane group's header, lanes and ticks, under the dynamics.
    lanes: Vec<PortLayout>,
    /// The phase strip's box and the row of tick labels under it.
    phases: Option<(Band, Band)>,
    /// The "time (s)" caption at the bottom, when there is a time axis at all.
    caption: Option<Band>,
}

impl Layout {
    fn new(data: &PlotData) -> Layout {
        let has_phases = !data.phases.is_empty();
        // Sections: the ports, then the dynamics groups; each has a header and strips (a
        // group's lanes are dynamics::LANE_STRIPS strips high).
        let sections: Vec<(usize, f64)> = data
            .ports
            .iter()
            .map(|p| (p.connections.len(), 1.0))
            .chain(
                data.dynamics
                    .iter()
                    .map(|g| (g.behaviours.len(), dynamics::LANE_STRIPS)),
            )
            .chain(
                data.lanes
                    .iter()
                    .map(|g| (g.lanes.len(), lanes::LANE_STRIPS)),
            )
            .collect();
        let last = sections.len().saturating_sub(1);
        // The last section's tick labels would repeat those under the phase strip right below.
        let has_ticks = |i: usize, strips: usize| strips > 0 && (!has_phases || i != last);
        let connections: usize = sections.iter().map(|&(strips, _)| strips).sum();
        let tick_rows = sections
            .iter()
            .enumerate()
            .filter(|&(i, &(strips, _))| has_ticks(i, strips))
            .count();
        let has_axis = has_phases || connections > 0;

        let n: f64 = sections.iter().map(|&(strips, h)| strips as f64 * h).sum();
        let fixed = TITLE_H + BOTTOM_H;
        let others = sections.len() as f64 * HEADER_H
            + tick_rows as f64 * TICKS_H
            + if has_phases {
                PHASE_GAP_H + PHASE_H + TICKS_H
            } else {
                0.0
            }
            + if has_axis { CAPTION_H } else { 0.0 };
        let max = f64::from(MAX_HEIGHT);
        let mut strip_h = STRIP_H;
        if fixed + others + n * strip_h > max {
            strip_h = ((max - fixed - others) / n).clamp(MIN_STRIP_H, STRIP_H);
        }
        let rest = others + n * strip_h;
        let scale = if fixed + rest > max {
            (max - fixed) / rest
        } else {
            1.0
        };

        let mut y = TITLE_H;
        let mut band = |h: f64| {
            let b = Band {
                y0: y,
                y1: y + h * scale,
            };
            y = b.y1;
            b
        };
        let title = Band {
            y0: 0.0,
            y1: TITLE_H,
        };
        let mut sections = sections
            .iter()
            .enumerate()
            .map(|(i, &(count, h))| {
                let header = band(HEADER_H);
                let strips = (0..count)
                    .map(|_| {
                        let slot = band(strip_h * h);
                        let gap = slot.height() / h * STRIP_GAP / 2.0;
                        Band {
                            y0: slot.y0 + gap,
                            y1: slot.y1 - gap,
                        }
                    })
                    .collect();
                let ticks = has_ticks(i, count).then(|| band(TICKS_H));
                PortLayout {
                    header,
                    strips,
                    ticks,
                }
            })
            .collect::<Vec<_>>();
        let lanes =
            sections.split_off((data.ports.len() + data.dynamics.len()).min(sections.len()));
        let dynamics = sections.split_off(data.ports.len().min(sections.len()));
        let ports = sections;
        let phases = has_phases.then(|| {
            band(PHASE_GAP_H);
            (band(PHASE_H), band(TICKS_H))
        });
        let caption = has_axis.then(|| band(CAPTION_H));
        let height = ((y + BOTTOM_H).ceil() as u32).min(MAX_HEIGHT);
        Layout {
            height,
            scale,
            title,
            ports,
            dynamics,
            lanes,
            phases,
            caption,
        }
    }
}

/// Maps times to pixel columns and knows the tick marks.
struct TimeAxis {
    until: f64,
    ticks: Vec<(f64, String)>,
}

impl TimeAxis {
    fn new(until: f64) -> TimeAxis {
        TimeAxis {
            until,
            ticks: time_ticks(until),
        }
    }

    /// The column of time `t` (clamped to the axis), `t` finite.
    fn x(&self, t: f64) -> f64 {
        let f = (t / self.until).clamp(0.0, 1.0);
        PLOT_X0 + f * (PLOT_X1 - PLOT_X0)
    }
}

/// About a dozen round times from 0 to `until` (finite, positive), with their labels.
fn time_ticks(until: f64) -> Vec<(f64, String)> {
    let raw = until / 12.0;
    let magnitude = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * magnitude)
        .find(|&s| s >= raw * (1.0 - 1e-9))
        .unwrap_or(10.0 * magnitude);
    if !(step.is_finite() && step > 0.0) {
        return vec![(0.0, "0".to_string())];
    }
    let count = ((until / step) * (1.0 + 1e-9)).floor().min(100.0) as usize;
    (0..=count)
        .map(|k| {
            let t = k as f64 * step;
            (t, tick_label(t, step, until))
        })
        .collect()
}

/// `t` with as many decimals as the `step` between ticks needs; in scientific notation when
/// the axis, up to `until`, would need more than 7 digits or 4 decimals.
fn tick_label(t: f64, step: f64, until: f64) -> String {
    if t == 0.0 {
        "0".to_string()
    } else if step >= 1.0 && until < 1e7 {
        format!("{t:.0}")
    } else if (1e-4..1.0).contains(&step) {
        let decimals = (-step.log10() - 1e-9).ceil().max(0.0) as usize;
        format!("{t:.decimals$}")
    } else {
        format!("{t:.1e}")
    }
}

/// The row of a stimulation level in a strip's box (levels out of the strip are clamped).
fn level_y(level: f64, b: Band) -> f64 {
    let f = (level.clamp(LEVEL_LO, LEVEL_HI) - LEVEL_LO) / (LEVEL_HI - LEVEL_LO);
    b.y1 - f * b.height()
}

fn px(x: f64, y: f64) -> (i32, i32) {
    (x.round() as i32, y.round() as i32)
}

fn draw<DB: Canvas>(root: &Area<DB>, data: &PlotData, layout: &Layout) -> anyhow::Result<()> {
    root.fill(&BACKGROUND).map_err(draw_error)?;
    let axis = TimeAxis::new(data.until);
    draw_title(root, &data.title, layout.title)?;

    for (i, (port, place)) in data.ports.iter().zip(&layout.ports).enumerate() {
        let room = PLOT_X1 - MARGIN_X;
        draw_header(root, &place.header, &port.name, room, i > 0, layout.scale)?;
        for (connection, &b) in port.connections.iter().zip(&place.strips) {
            draw_connection(root, &axis, connection, b)?;
        }
        if let (Some(row), Some(&above)) = (place.ticks, place.strips.last()) {
            draw_ticks(root, &axis, above, row, layout.scale)?;
        }
    }

    for (g, (group, place)) in data.dynamics.iter().zip(&layout.dynamics).enumerate() {
        let legend = LEGEND_SIZE * layout.scale;
        dynamics::draw_legend(root, place.header.middle(), legend)?;
        let separated = !data.ports.is_empty() || g > 0;
        draw_header(
            root,
            &place.header,
            &group.name,
            LABEL_X1 * 2.0,
            separated,
            layout.scale,
        )?;
        for (behaviour, &b) in group.behaviours.iter().zip(&place.strips) {
            dynamics::draw_lane(root, &axis, behaviour, b)?;
        }
        if let (Some(row), Some(&above)) = (place.ticks, place.strips.last()) {
            draw_ticks(root, &axis, above, row, layout.scale)?;
        }
    }

    for (g, (group, place)) in data.lanes.iter().zip(&layout.lanes).enumerate() {
        let separated = !data.ports.is_empty() || !data.dynamics.is_empty() || g > 0;
        let room = PLOT_X1 - MARGIN_X;
        draw_header(
            root,
            &place.header,
            &group.name,
            room,
            separated,
            layout.scale,
        )?;
        for (lane, &b) in group.lanes.iter().zip(&place.strips) {
            lanes::draw_lane(root, &axis, lane, b)?;
        }
        if let (Some(row), Some(&above)) = (place.ticks, place.strips.last()) {
            draw_ticks(root, &axis, above, row, layout.scale)?;
        }
    }

    if let Some((b, row)) = layout.phases {
        draw_phases(root, &axis, &data.phases, b, layout.scale)?;
        draw_ticks(root, &axis, b, row, layout.scale)?;
    }
    if let Some(b) = layout.caption {
        let x = (PLOT_X0 + PLOT_X1) / 2.0;
        let size = LEGEND_SIZE * layout.scale;
        text(
            root,
            "time (s)",
            (x, b.middle()),
            size,
            false,
            SOFT_TEXT,
            HPos::Center,
        )?;
    }
    Ok(())
}

/// The title, centred, and a legend of the two colours on the right.
fn draw_title<DB: Canvas>(root: &Area<DB>, title: &str, b: Band) -> anyhow::Result<()> {
    let y = b.middle();
    let size = LEGEND_SIZE;
    let mut x = PLOT_X1;
    for (name, color) in [("not selected", NOT_SELECTED), ("selected", SELECTED)] {
        x -= text_width(root, name, size, false)?;
        text(root, name, (x, y), size, false, SOFT_TEXT, HPos::Left)?;
        x -= 30.0;
        let style = color.stroke_width(2);
        root.draw(&PathElement::new(vec![px(x, y), px(x + 24.0, y)], style))
            .map_err(draw_error)?;
        x -= 18.0;
    }

    let size = TITLE_SIZE;
    let room = x - 20.0 - MARGIN_X;
    let title = fit_line(root, &clean(title), room, size, true)?;
    let half = text_width(root, &title, size, true)? / 2.0;
    let centre = (f64::from(WIDTH) / 2.0)
        .min(x - 20.0 - half)
        .max(MARGIN_X + half);
    text(root, &title, (centre, y), size, true, TEXT, HPos::Center)
}

/// One connection's strip: grid, then what it shows (a stimulation: threshold, box, level ticks
/// and curve; a window or a gate: bands, `plot/windows.rs`), then its label.
fn draw_connection<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    connection: &ConnectionSeries,
    b: Band,
) -> anyhow::Result<()> {
    if b.height() < 1.0 {
        return Ok(());
    }
    draw_grid(root, axis, b)?;
    match &connection.shows {
        Shows::Stimulation => {
            let threshold = level_y(1.0, b);
            let mut x = PLOT_X0;
            while x < PLOT_X1 {
                let end = (x + 6.0).min(PLOT_X1);
                line(root, (x, threshold), (end, threshold), THRESHOLD)?;
                x += 10.0;
            }
            rectangle(root, b, BORDER.stroke_width(1))?;
            if b.height() >= 28.0 {
                for (level, name) in [(0.0, "0"), (1.0, "1")] {
                    let at = (PLOT_X0 - 6.0, level_y(level, b));
                    text(root, name, at, VALUE_SIZE, false, SOFT_TEXT, HPos::Right)?;
                }
            }
            draw_curve(root, axis, &connection.samples, b)?;
        }
        Shows::Window { kind, delivers } => {
            windows::draw_windows(root, axis, connection, kind, *delivers, b)?;
        }
        Shows::Gate => windows::draw_gate(root, axis, connection, b)?,
    }
    draw_label(root, &connection.label, &connection.name, b, 3)
}

/// The vertical grid lines of the time ticks across box `b`.
fn draw_grid<DB: Canvas>(root: &Area<DB>, axis: &TimeAxis, b: Band) -> anyhow::Result<()> {
    for &(t, _) in &axis.ticks {
        let x = axis.x(t);
        line(root, (x, b.y0), (x, b.y1), GRID)?;
    }
    Ok(())
}

/// A strip's or a lane's label left of its box `b` (its `name` if the label is blank), on at most
/// `max_lines` lines, as many as the box's height holds.
fn draw_label<DB: Canvas>(
    root: &Area<DB>,
    label: &str,
    name: &str,
    b: Band,
    max_lines: usize,
) -> anyhow::Result<()> {
    let label = if label.trim().is_empty() { name } else { label };
    let size = style::snap(LABEL_SIZE.min(b.height() * 0.7));
    if size < MIN_FONT {
        return Ok(());
    }
    let line_h = size * 1.3;
    let max_lines = ((b.height() / line_h).floor() as usize).clamp(1, max_lines.max(1));
    let lines = wrap(root, &clean(label), LABEL_X1 - MARGIN_X, size, max_lines)?;
    let first = b.middle() - (lines.len() as f64 - 1.0) * line_h / 2.0;
    for (k, l) in lines.iter().enumerate() {
        let at = (MARGIN_X, first + k as f64 * line_h);
        text(root, l, at, size, false, TEXT, HPos::Left)?;
    }
    Ok(())
}

/// The stimulation, 2 pixels wide, in runs of segments of the same colour.
fn draw_curve<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    samples: &[Sample],
    b: Band,
) -> anyhow::Result<()> {
    let color = |selected: bool| if selected { SELECTED } else { NOT_SELECTED };
    let mut runs: Vec<(bool, Vec<(i32, i32)>)> = Vec::new();
    let mut usable = samples
        .iter()
        .filter(|s| s.t.is_finite() && !s.level.is_nan())
        .map(|s| (s.t, s.level.clamp(LEVEL_LO, LEVEL_HI), s.selected));
    let Some(mut previous) = usable.next() else {
        return Ok(());
    };
    let mut segments = 0usize;
    for current in usable {
        segments += 1;
        let selected = previous.2;
        if let Some((a, z)) = clip(previous, current, axis.until) {
            let a = px(axis.x(a.0), level_y(a.1, b));
            let z = px(axis.x(z.0), level_y(z.1, b));
            match runs.last_mut() {
                Some((s, points)) if *s == selected && points.last() == Some(&a) => {
                    if points.last() != Some(&z) {
                        points.push(z);
                    }
                }
                _ if a == z => runs.push((selected, vec![a])),
                _ => runs.push((selected, vec![a, z])),
            }
        }
        previous = current;
    }
    if segments == 0 && (0.0..=axis.until).contains(&previous.0) {
        // A single sample: a dot.
        runs.push((
            previous.2,
            vec![px(axis.x(previous.0), level_y(previous.1, b))],
        ));
    }
    for (selected, points) in runs {
        if let [(x, y)] = points[..] {
            let dot = Rectangle::new([(x - 1, y - 1), (x + 1, y + 1)], color(selected).filled());
            root.draw(&dot).map_err(draw_error)?;
        } else {
            // Segment by segment: a 2-pixel polyline gets mitred joins, which overshoot into
            // spikes where the curve turns back (a jump followed by a decay).
            for pair in points.windows(2) {
                let path = PathElement::new(pair.to_vec(), color(selected).stroke_width(2));
                root.draw(&path).map_err(draw_error)?;
            }
        }
    }
    Ok(())
}

/// The part of the segment from `a` to `z` (time, level, _) within times 0..=until, or None.
/// Times are finite, levels finite and clamped.
fn clip(a: (f64, f64, bool), z: (f64, f64, bool), until: f64) -> Option<((f64, f64), (f64, f64))> {
    let ((ta, la), (tz, lz)) = ((a.0, a.1), (z.0, z.1));
    if (ta < 0.0 && tz < 0.0) || (ta > until && tz > until) {
        return None;
    }
    if ta == tz {
        return Some(((ta, la), (tz, lz)));
    }
    let at = |t: f64| {
        let f = ((t - ta) / (tz - ta)).clamp(0.0, 1.0);
        (t, la + (lz - la) * f)
    };
    let limit = |t: f64| {
        if t < 0.0 {
            at(0.0)
        } else if t > until {
            at(until)
        } else {
            at(t)
        }
    };
    Some((limit(ta), limit(tz)))
}

/// Tick marks under the box `above` and their labels in `row`.
fn draw_ticks<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    above: Band,
    row: Band,
    scale: f64,
) -> anyhow::Result<()> {
    let size = TICK_SIZE * scale;
    for (t, label) in &axis.ticks {
        let x = axis.x(*t);
        line(root, (x, above.y1), (x, above.y1 + 4.0 * scale), BORDER)?;
        text(
            root,
            label,
            (x, row.middle()),
            size,
            false,
            SOFT_TEXT,
            HPos::Center,
        )?;
    }
    Ok(())
}

/// The phases as alternately shaded bands, each with its name centred if it fits.
fn draw_phases<DB: Canvas>(
    root: &Area<DB>,
    axis: &TimeAxis,
    phases: &[Phase],
    b: Band,
    scale: f64,
) -> anyhow::Result<()> {
    let size = LABEL_SIZE.min(b.height() * 0.6);
    text(
        root,
        "phases",
        (MARGIN_X, b.middle()),
        LEGEND_SIZE * scale,
        false,
        SOFT_TEXT,
        HPos::Left,
    )?;
    let mut shade = 0;
    for phase in phases {
        if !(phase.from.is_finite() && phase.to.is_finite()) {
            continue;
        }
        let (from, to) = (phase.from.min(phase.to), phase.from.max(phase.to));
        if to < 0.0 || from > axis.until {
            continue;
        }
        let (x0, x1) = (axis.x(from), axis.x(to));
        let band = Rectangle::new([px(x0, b.y0), px(x1, b.y1)], SHADES[shade].filled());
        root.draw(&band).map_err(draw_error)?;
        shade = 1 - shade;
        let name = clean(&phase.name);
        if size >= MIN_FONT && text_width(root, &name, size, true)? <= x1 - x0 - 4.0 {
            text(
                root,
                &name,
                ((x0 + x1) / 2.0, b.middle()),
                size,
                true,
                TEXT,
                HPos::Center,
            )?;
        }
    }
    rectangle(root, b, BORDER.stroke_width(1))
}

/// A section's header (a port, a dynamics group, a lane group): its name in bold, fitted into
/// `room`, after a separator line when `separated` (not the first section).
fn draw_header<DB: Canvas>(
    root: &Area<DB>,
    header: &Band,
    name: &str,
    room: f64,
    separated: bool,
    scale: f64,
) -> anyhow::Result<()> {
    if separated {
        line(root, (MARGIN_X, header.y0), (PLOT_X1, header.y0), SEPARATOR)?;
    }
    let size = HEADER_SIZE * scale;
    let name = fit_line(root, &clean(name), room, size, true)?;
    text(
        root,
        &name,
        (MARGIN_X, header.middle()),
        size,
        true,
        TEXT,
        HPos::Left,
    )
}

fn line<DB: Canvas>(
    root: &Area<DB>,
    from: (f64, f64),
    to: (f64, f64),
    color: RGBColor,
) -> anyhow::Result<()> {
    let path = PathElement::new(vec![px(from.0, from.1), px(to.0, to.1)], color);
    root.draw(&path).map_err(draw_error)
}

fn rectangle<DB: Canvas>(root: &Area<DB>, b: Band, style: ShapeStyle) -> anyhow::Result<()> {
    let r = Rectangle::new([px(PLOT_X0, b.y0), px(PLOT_X1, b.y1)], style);
    root.draw(&r).map_err(draw_error)
}

/// Draws `s` starting at, centred on or ending at `x` (after `h`), its capitals centred on `y`.
fn text<DB: Canvas>(
    root: &Area<DB>,
    s: &str,
    (x, y): (f64, f64),
    size: f64,
    bold: bool,
    color: RGBColor,
    h: HPos,
) -> anyhow::Result<()> {
    let size = style::snap(size);
    if s.is_empty() || size < MIN_FONT {
        return Ok(());
    }
    let style = DB::font(size, bold)
        .color(&color)
        .pos(Pos::new(h, VPos::Top));
    let top = y - size * DB::TEXT_RAISE;
    root.draw(&Text::new(s, px(x, top), style))
        .map_err(draw_error)
}

/// The width of `s` in the plot font (the rasteriser's measure, whatever the canvas).
fn text_width<DB: Canvas>(root: &Area<DB>, s: &str, size: f64, bold: bool) -> anyhow::Result<f64> {
    if s.is_empty() || style::snap(size) < MIN_FONT {
        return Ok(0.0);
    }
    let (w, _) = root
        .estimate_text_size(s, &font(size, bold))
        .map_err(draw_error)?;
    Ok(f64::from(w))
}

/// `s` without control characters, cut to `MAX_LABEL_CHARS`.
fn clean(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .take(MAX_LABEL_CHARS)
        .collect()
}

/// `s`, shortened with an ellipsis if it is wider than `room`.
fn fit_line<DB: Canvas>(
    root: &Area<DB>,
    s: &str,
    room: f64,
    size: f64,
    bold: bool,
) -> anyhow::Result<String> {
    if text_width(root, s, size, bold)? <= room {
        return Ok(s.to_string());
    }
    let mut cut = s.trim_end().to_string();
    while !cut.is_empty() {
        cut.pop();
        let candidate = format!("{}…", cut.trim_end());
        if text_width(root, &candidate, size, bold)? <= room {
            return Ok(candidate);
        }
    }
    Ok(String::new())
}

/// Breaks a label into at most `max_lines` lines no wider than `room`: between fields (runs of
/// two or more spaces) if the label has several, else between words; the last line is
/// shortened with an ellipsis if the rest does not fit.
fn wrap<DB: Canvas>(
    root: &Area<DB>,
    s: &str,
    room: f64,
    size: f64,
    max_lines: usize,
) -> anyhow::Result<Vec<String>> {
    let s = s.trim();
    if s.is_empty() || max_lines == 0 {
        return Ok(Vec::new());
    }
    if text_width(root, s, size, false)? <= room {
        return Ok(vec![s.to_string()]);
    }
    let fields: Vec<&str> = s
        .split("  ")
        .map(str::trim)
        .filter(|f| !f.is_empty())
        .collect();
    let (pieces, joint) = if fields.len() > 1 {
        (fields, "  ")
    } else {
        (s.split_whitespace().collect(), " ")
    };
    let mut lines = Vec::new();
    let mut rest = &pieces[..];
    while !rest.is_empty() {
        if lines.len() + 1 == max_lines {
            lines.push(fit_line(root, &rest.join(joint), room, size, false)?);
            break;
        }
        // The longest prefix of the remaining pieces that fits (at least one piece).
        let mut take = 1;
        while take < rest.len()
            && text_width(root, &rest[..=take].join(joint), size, false)? <= room
        {
            take += 1;
        }
        lines.push(fit_line(
            root,
            &rest[..take].join(joint),
            room,
            size,
            false,
        )?);
        rest = &rest[take..];
    }
    Ok(lines)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Rgb, RgbImage};

    fn sample(t: f64, level: f64, selected: bool) -> Sample {
        Sample {
            t,
            level,
            active: level >= 1.0,
            selected,
        }
    }

    fn connection(name: &str, label: &str, samples: Vec<Sample>) -> ConnectionSeries {
        ConnectionSeries {
            name: name.to_string(),
            label: label.to_string(),
            shows: Shows::Stimulation,
            samples,
        }
    }

    fn phase(name: &str, from: f64, to: f64) -> Phase {
        Phase {
            name: name.to_string(),
            from,
            to,
        }
    }

    /// Two ports, three connections: C1 selected from 2 s to 6 s, C2 never, C3 jumps and is
    /// selected at 5 s.
    fn small() -> PlotData {
        let c1 = (0..=20)
            .map(|k| {
                let t = k as f64 * 0.5;
                sample(t, (t / 8.0).min(1.0), (2.0..6.0).contains(&t))
            })
            .collect();
        let c2 = vec![sample(0.0, 0.5, false), sample(10.0, 0.5, false)];
        let c3 = vec![
            sample(0.0, 0.1, false),
            sample(5.0, 0.1, false),
            sample(5.0, 0.9, true),
            sample(10.0, 0.6, true),
        ];
        PlotData {
            dynamics: Vec::new(),
            lanes: Vec::new(),
            title: "Take and Return (test)".to_string(),
            until: 10.0,
            ports: vec![
                PortSeries {
                    name: "arm.target".to_string(),
                    connections: vec![
                        connection("C1", "C1  object_pos  σ 0.2  τ 3 s", c1),
                        connection("C2", "", c2),
                    ],
                },
                PortSeries {
                    name: "hand.cmd".to_string(),
                    connections: vec![connection("C3", "C3  grasp", c3)],
                },
            ],
            phases: vec![
                phase("A", 0.0, 3.0),
                phase("B", 3.0, 7.0),
                phase("C", 7.0, 10.0),
            ],
        }
    }

    fn render(data: &PlotData) -> anyhow::Result<RgbImage> {
        let dir = tempfile::tempdir()?;
        let path = dir.path().join("plot.png");
        super::render(data, &path)?;
        Ok(image::open(&path)?.to_rgb8())
    }

    fn rgb(c: RGBColor) -> Rgb<u8> {
        Rgb([c.0, c.1, c.2])
    }

    /// Columns of the pixels of colour `c` in the rows of band `b`, within the plot area.
    fn columns(img: &RgbImage, b: Band, c: RGBColor) -> Vec<u32> {
        let mut xs = Vec::new();
        for y in b.y0.round() as u32..=b.y1.round() as u32 {
            for x in PLOT_X0 as u32..=PLOT_X1 as u32 {
                if *img.get_pixel(x, y) == rgb(c) {
                    xs.push(x);
                }
            }
        }
        xs
    }

    /// Pixels darker than the borders (150) in a rectangle: text.
    fn dark(img: &RgbImage, xs: std::ops::Range<f64>, b: Band) -> usize {
        let mut n = 0;
        for y in b.y0.max(0.0) as u32..(b.y1 as u32).min(img.height()) {
            for x in xs.start as u32..xs.end as u32 {
                if img.get_pixel(x, y).0.iter().all(|&v| v < 128) {
                    n += 1;
                }
            }
        }
        n
    }

    fn column(t: f64) -> f64 {
        TimeAxis::new(10.0).x(t)
    }

    #[test]
    fn small_plot_has_the_designed_size_and_both_colours_where_expected() {
        let data = small();
        let layout = Layout::new(&data);
        // Title 48, port 30 + 2 × 66 + ticks 22, port 30 + 66, phases 10 + 34 + ticks 22,
        // caption 20, bottom 10.
        assert_eq!(layout.height, 424);
        let img = render(&data).unwrap();
        assert_eq!(img.dimensions(), (1400, 424));

        let c1 = layout.ports[0].strips[0];
        let green = columns(&img, c1, SELECTED);
        let orange = columns(&img, c1, NOT_SELECTED);
        assert!(!green.is_empty() && !orange.is_empty());
        let (from, to) = (column(2.0) - 3.0, column(6.0) + 3.0);
        assert!(green.iter().all(|&x| (from..=to).contains(&f64::from(x))));
        assert!(green.iter().any(|&x| f64::from(x) > column(5.0)));
        assert!(orange.iter().any(|&x| f64::from(x) < from));
        assert!(orange.iter().any(|&x| f64::from(x) > to));

        let c2 = layout.ports[0].strips[1];
        assert!(columns(&img, c2, SELECTED).is_empty());
        assert!(columns(&img, c2, NOT_SELECTED).len() > 500);

        // C3: orange up to 5 s and up the vertical jump from 0.1 to 0.9 (the segment takes the
        // colour of its first sample), then green.
        let c3 = layout.ports[1].strips[0];
        let jump = column(5.0);
        let green = columns(&img, c3, SELECTED);
        let orange = columns(&img, c3, NOT_SELECTED);
        assert!(green.iter().all(|&x| f64::from(x) >= jump - 3.0));
        assert!(green.iter().any(|&x| f64::from(x) >= column(9.0)));
        assert!(orange.iter().all(|&x| f64::from(x) <= jump + 3.0));
        let on_jump = orange
            .iter()
            .filter(|&&x| (f64::from(x) - jump).abs() <= 1.5)
            .count();
        let jump_height = level_y(0.1, c3) - level_y(0.9, c3);
        assert!(
            on_jump as f64 >= jump_height,
            "{on_jump} orange pixels on the jump"
        );

        // Texts: title, labels, port header, phase names.
        assert!(dark(&img, 0.0..1400.0, layout.title) > 200);
        assert!(dark(&img, MARGIN_X..LABEL_X1, c1) > 100);
        assert!(dark(&img, MARGIN_X..LABEL_X1, layout.ports[1].header) > 50);
        let (phases, ticks) = layout.phases.unwrap();
        assert!(dark(&img, PLOT_X0..PLOT_X1, phases) > 30);
        assert!(dark(&img, PLOT_X0..PLOT_X1, ticks) > 30);
        for shade in SHADES {
            assert!(columns(&img, phases, shade).len() > 1000);
        }
        let white = img.pixels().filter(|p| **p == Rgb([255, 255, 255])).count();
        assert!(white < img.pixels().count() * 95 / 100);
    }

    #[test]
    fn sixteen_connections_on_three_ports_with_phases() {
        // Frames arrive now and then; each adds σ to the stimulation, which decays with τ. At
        // each port the most stimulated connection over 0.5 is selected.
        let mut seed = 7u64;
        let mut random = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / f64::from(1u32 << 31)
        };
        let names = [
            "Release Detect",
            "Grasped",
            "Grasp Detect",
            "Object Detector",
            "Face Detector",
            "Rest Arm",
        ];
        let mut port = |name: &str, n: usize| {
            let params: Vec<(f64, f64, f64)> = (0..n)
                .map(|_| (0.1 + 0.3 * random(), 2.0 + 8.0 * random(), random()))
                .collect();
            let mut levels = vec![0.0; n];
            let mut series: Vec<Vec<Sample>> = vec![Vec::new(); n];
            let mut selected = None;
            for k in 0..=600 {
                let t = f64::from(k) * 0.5;
                let busy = ((t / 40.0) as usize) % n;
                for i in 0..n {
                    levels[i] *= (-0.5 / params[i].1).exp();
                    series[i].push(sample(t, levels[i], selected == Some(i)));
                    let rate = if i == busy { 0.9 } else { 0.15 * params[i].2 };
                    if random() < rate {
                        levels[i] = (levels[i] + params[i].0).min(1.0);
                        series[i].push(sample(t, levels[i], selected == Some(i)));
                    }
                }
                let best = (0..n).max_by(|&a, &b| levels[a].total_cmp(&levels[b]));
                selected = best.filter(|&i| levels[i] > 0.5);
                for (i, s) in series.iter_mut().enumerate() {
                    if let Some(last) = s.last_mut() {
                        last.selected = selected == Some(i);
                    }
                }
            }
            PortSeries {
                name: name.to_string(),
                connections: series
                    .into_iter()
                    .enumerate()
                    .map(|(i, samples)| {
                        let (sigma, tau, _) = params[i];
                        let label =
                            format!("C{}  {}  σ {sigma:.2}  τ {tau:.1} s", i + 1, names[i % 6]);
                        connection(&format!("C{}", i + 1), &label, samples)
                    })
                    .collect(),
            }
        };
        let ports = vec![
            port("Arm Control", 6),
            port("Hand Control", 5),
            port("Head Control", 5),
        ];
        let bounds = [0.0, 140.0, 170.0, 190.0, 230.0, 270.0, 300.0];
        let data = PlotData {
            dynamics: Vec::new(),
            lanes: Vec::new(),
            title: "Arbitration during the Take and Return scenario".to_string(),
            until: 300.0,
            ports,
            phases: ["A", "B", "C", "D", "E", "F"]
                .iter()
                .zip(bounds.windows(2))
                .map(|(n, w)| phase(n, w[0], w[1]))
                .collect(),
        };
        let layout = Layout::new(&data);
        assert_eq!(layout.scale, 1.0);
        // 48 + 3 × 30 + 16 × 66 + 2 × 22 + (10 + 34 + 22) + 20 + 10
        assert_eq!(layout.height, 1334);
        let img = render(&data).unwrap();
        assert_eq!(img.dimensions(), (1400, 1334));
        let strips = layout.ports.iter().flat_map(|p| &p.strips);
        let (mut green, mut orange) = (0, 0);
        for &b in strips {
            green += usize::from(!columns(&img, b, SELECTED).is_empty());
            orange += usize::from(!columns(&img, b, NOT_SELECTED).is_empty());
        }
        assert!(
            green >= 3 && orange == 16,
            "{green} green, {orange} orange strips"
        );
    }

    #[test]
    fn many_connections_shrink_strips_to_the_height_cap() {
        let many = |ports: usize, each: usize| PlotData {
            dynamics: Vec::new(),
            lanes: Vec::new(),
            title: "many".to_string(),
            until: 1.0,
            ports: (0..ports)
                .map(|p| PortSeries {
                    name: format!("p{p}"),
                    connections: (0..each)
                        .map(|i| {
                            let samples = vec![sample(0.0, 0.0, false), sample(1.0, 1.0, true)];
                            connection(&format!("C{i}"), "", samples)
                        })
                        .collect(),
                })
                .collect(),
            phases: vec![phase("A", 0.0, 1.0)],
        };
        let data = many(2, 120);
        let layout = Layout::new(&data);
        assert_eq!(layout.height, MAX_HEIGHT);
        assert_eq!(layout.scale, 1.0);
        let strip = layout.ports[0].strips[0].height() / (1.0 - STRIP_GAP);
        assert!((MIN_STRIP_H..STRIP_H).contains(&strip), "{strip}");
        let img = render(&data).unwrap();
        assert_eq!(img.dimensions(), (WIDTH, MAX_HEIGHT));
        let last = *layout.ports[1].strips.last().unwrap();
        assert!(columns(&img, last, NOT_SELECTED).len() > 1000);

        // So many ports that even the headers must shrink.
        let layout = Layout::new(&many(3000, 1));
        assert!(layout.height <= MAX_HEIGHT);
        assert!(layout.scale < 1.0);
        let (phases, _) = layout.phases.unwrap();
        assert!(phases.y1 <= f64::from(MAX_HEIGHT));
        let mut y = layout.title.y1;
        for port in &layout.ports {
            assert!(port.header.y0 >= y - 1e-6);
            y = port.header.y1;
            for b in &port.strips {
                assert!(b.y0 >= y - 1e-6 && b.y1 > b.y0);
                y = b.y1;
            }
        }
    }

    #[test]
    fn empty_data_renders_the_title_only() {
        let data = PlotData {
            title: "nothing to show".to_string(),
            until: 5.0,
            ..PlotData::default()
        };
        let img = render(&data).unwrap();
        assert_eq!(img.dimensions(), (1400, 58));
        assert!(dark(&img, 0.0..1400.0, Layout::new(&data).title) > 100);

        let with_phases = PlotData {
            phases: vec![phase("A", 0.0, 2.0), phase("B", 2.0, 5.0)],
            ..data
        };
        let img = render(&with_phases).unwrap();
        assert_eq!(img.dimensions(), (1400, 144));
        let (phases, _) = Layout::new(&with_phases).phases.unwrap();
        assert!(columns(&img, phases, SHADES[1]).len() > 1000);

        // A port without connections and a connection without samples.
        let hollow = PlotData {
            dynamics: Vec::new(),
            lanes: Vec::new(),
            title: String::new(),
            until: 1.0,
            ports: vec![
                PortSeries::default(),
                PortSeries {
                    name: "p".to_string(),
                    connections: vec![ConnectionSeries::default()],
                },
            ],
            phases: Vec::new(),
        };
        let layout = Layout::new(&hollow);
        let img = render(&hollow).unwrap();
        assert_eq!(img.dimensions(), (1400, layout.height));
        let strip = layout.ports[1].strips[0];
        assert!(columns(&img, strip, SELECTED).is_empty());
        assert!(columns(&img, strip, NOT_SELECTED).is_empty());
        assert!(!columns(&img, strip, BORDER).is_empty());
    }

    #[test]
    fn a_time_axis_that_does_not_end_after_zero_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plot.png");
        for until in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let data = PlotData { until, ..small() };
            assert!(super::render(&data, &path).is_err(), "until = {until}");
            assert!(!path.exists());
        }
        assert!(super::render(&PlotData::default(), &path).is_err());
        assert!(!path.exists());
    }

    #[test]
    fn other_file_names_and_unwritable_places_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        assert!(super::render(&small(), &dir.path().join("plot.pdf")).is_err());
        assert!(!dir.path().join("plot.pdf").exists());
        assert!(super::render(&small(), &dir.path().join("plot.svg")).is_ok());
        assert!(super::render(&small(), &dir.path().join("missing/plot.png")).is_err());
        assert!(super::render(&small(), &dir.path().join("plot.PNG")).is_ok());
    }

    #[test]
    fn hostile_inputs_do_not_panic() {
        let weird = vec![
            sample(f64::NAN, 0.5, true),
            sample(-5.0, 2.0, true),
            sample(3.0, f64::INFINITY, false),
            sample(f64::INFINITY, 0.5, true),
            sample(2.0, f64::NEG_INFINITY, true),
            sample(2.0, f64::NAN, false),
            sample(1e300, -1e300, false),
            sample(4.0, 0.5, true),
            sample(4.0, 0.5, false),
            sample(-1e300, 1e300, true),
        ];
        let long = "x".repeat(5000) + "\n\t\u{0}  y  " + &"z ".repeat(2000);
        let base = PlotData {
            dynamics: Vec::new(),
            lanes: Vec::new(),
            title: long.clone(),
            until: 10.0,
            ports: vec![PortSeries {
                name: long.clone(),
                connections: vec![
                    connection("", &long, weird.clone()),
                    connection("", "", vec![sample(20.0, 0.5, true)]),
                    connection("", "", vec![sample(5.0, 0.5, true)]),
                ],
            }],
            phases: vec![
                phase(&long, 8.0, 2.0),
                phase("nan", f64::NAN, 1.0),
                phase("out", 20.0, 30.0),
                phase("", -1e300, 1e300),
            ],
        };
        let img = render(&base).unwrap();
        let layout = Layout::new(&base);
        // The single sample at 5 s is a dot; the one at 20 s is off the axis.
        assert!(!columns(&img, layout.ports[0].strips[2], SELECTED).is_empty());
        assert!(columns(&img, layout.ports[0].strips[1], SELECTED).is_empty());
        for until in [1e-300, 5e-324, 1e300, f64::MAX] {
            let data = PlotData {
                until,
                ..base.clone()
            };
            render(&data).unwrap();
        }
    }

    #[test]
    fn ticks_are_round_and_labelled() {
        let labels =
            |until: f64| -> Vec<String> { time_ticks(until).into_iter().map(|(_, l)| l).collect() };
        assert_eq!(
            labels(10.0),
            (0..=10).map(|k| k.to_string()).collect::<Vec<_>>()
        );
        assert_eq!(
            labels(300.0),
            ["0", "50", "100", "150", "200", "250", "300"]
        );
        assert_eq!(labels(0.3)[1..3], ["0.05", "0.10"]);
        assert_eq!(labels(1.2e7)[1..3], ["1.0e6", "2.0e6"]);
        for until in [1e-300, 5e-324, 1e300, f64::MAX, 7.3] {
            let ticks = time_ticks(until);
            assert!((1..=100).contains(&ticks.len()), "{until}: {}", ticks.len());
            assert!(ticks.iter().all(|(t, _)| *t <= until));
        }
    }
}
