//! A schema server's run: the end-effector's height (measured and attractor), its lateral
//! position, the contact force, and a lane naming the schema installed at each moment, on one
//! time axis. What the book's insertion figure shows (docs/schema-server.md). Drawn in the
//! plots' one style (`plot/style.rs`): the same title, columns, palette, fonts and axes as the
//! stimulation plot.

use std::path::Path;

use anyhow::ensure;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use pab_lang::sim::schema::{Installed, Run, Sample};

use super::style::{
    self, ALERT, Area, BACKGROUND, BORDER, Canvas, GRID, LABEL_SIZE, LEGEND_SIZE, LINES, MARGIN_X,
    PLOT_X0, PLOT_X1, Picture, SHADES, SOFT_TEXT, TEXT, TICK_SIZE, TITLE_H, TITLE_SIZE, WIDTH,
    draw_error,
};
use super::{Band, clean, draw_label, fit_line, px, text};

const HEIGHT: u32 = 1000;
const MEASURED: RGBColor = LINES[0];
const ATTRACTOR: RGBColor = LINES[1];
const Y_COLOUR: RGBColor = LINES[2];
const FORCE: RGBColor = LINES[3];
/// The rows of the charts (height, lateral position, force) and of the schema lane, pixels.
const ROWS: [(f64, f64); 3] = [(TITLE_H, 300.0), (300.0, 540.0), (540.0, 810.0)];
const LANE: Band = Band {
    y0: 826.0,
    y1: 990.0,
};

/// Draws `run` from `from` to `until` seconds into `path` (PNG or SVG, after its extension),
/// titled `title`.
pub fn render(run: &Run, from: f64, until: f64, title: &str, path: &Path) -> anyhow::Result<()> {
    ensure!(
        until > from,
        "cannot plot: the time axis must end after it starts"
    );
    let samples: Vec<&Sample> = run
        .samples
        .iter()
        .filter(|s| {
            let t = s.t_us as f64 * 1e-6;
            t >= from && t <= until
        })
        .collect();
    ensure!(
        !samples.is_empty(),
        "cannot plot: no tick between {from} and {until} s"
    );
    let picture = SchemaPlot {
        run,
        samples,
        from,
        until,
        title,
    };
    style::render(&picture, path)
}

struct SchemaPlot<'a> {
    run: &'a Run,
    samples: Vec<&'a Sample>,
    from: f64,
    until: f64,
    title: &'a str,
}

impl Picture for SchemaPlot<'_> {
    fn size(&self) -> (u32, u32) {
        (WIDTH, HEIGHT)
    }

    fn draw<DB: Canvas>(&self, root: &Area<DB>) -> anyhow::Result<()> {
        draw(root, self)
    }
}

fn t(us: u64) -> f64 {
    us as f64 * 1e-6
}

fn mm(um: i32) -> f64 {
    f64::from(um) * 1e-3
}

/// The values' range with a little room above and below.
fn range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let pad = ((hi - lo) * 0.08).max(0.05);
    (lo - pad)..(hi + pad)
}

/// The area of chart row `row`, its plot area spanning the plots' columns.
fn row<DB: Canvas>(root: &Area<DB>, (y0, y1): (f64, f64)) -> Area<DB> {
    root.clone()
        .shrink((0, y0.round() as u32), (WIDTH, (y1 - y0).round() as u32))
}

/// A chart on `area` over `from..until` and `y`, with the plots' axis style, the y axis named
/// `name`, time labels under it when `time_labels`.
fn chart<'a, DB: Canvas>(
    area: &'a Area<DB>,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    name: &str,
    time_labels: bool,
) -> anyhow::Result<ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(10)
        .margin_left(MARGIN_X as u32)
        .margin_right((f64::from(WIDTH) - PLOT_X1) as u32)
        .x_label_area_size(if time_labels { 50 } else { 0 })
        .y_label_area_size((PLOT_X0 - MARGIN_X) as u32)
        .build_cartesian_2d(x, y)
        .map_err(draw_error)?;
    let ticks = DB::font(TICK_SIZE, false).color(&SOFT_TEXT);
    chart
        .configure_mesh()
        .y_desc(name)
        .x_desc("time (s)")
        .axis_desc_style(DB::font(LABEL_SIZE, false).color(&TEXT))
        .label_style(ticks)
        .axis_style(BORDER)
        .bold_line_style(GRID)
        .light_line_style(TRANSPARENT)
        .x_labels(12)
        .y_labels(8)
        .disable_x_mesh()
        .draw()
        .map_err(draw_error)?;
    Ok(chart)
}

/// The legend of a chart's lines, upper right, in the plots' style.
fn legend<'a, DB: Canvas + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .border_style(BORDER)
        .background_style(BACKGROUND.mix(0.9))
        .label_font(DB::font(LEGEND_SIZE, false).color(&SOFT_TEXT))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_error)
}

fn draw<DB: Canvas>(root: &Area<DB>, plot: &SchemaPlot<'_>) -> anyhow::Result<()> {
    let SchemaPlot {
        run,
        samples,
        from,
        until,
        title,
    } = plot;
    let (from, until) = (*from, *until);
    root.fill(&BACKGROUND).map_err(draw_error)?;
    let centre = (f64::from(WIDTH) / 2.0, TITLE_H / 2.0);
    text(root, title, centre, TITLE_SIZE, true, TEXT, HPos::Center)?;

    // Height.
    let top = row(root, ROWS[0]);
    let z_range = range(
        samples
            .iter()
            .flat_map(|s| [mm(s.pose[2]), mm(s.attractor[2])]),
    );
    let mut height = chart(&top, from..until, z_range, "z (mm)", false)?;
    for (name, colour, value) in [
        (
            "attractor",
            ATTRACTOR,
            (|s: &Sample| mm(s.attractor[2])) as fn(&Sample) -> f64,
        ),
        ("measured", MEASURED, |s: &Sample| mm(s.pose[2])),
    ] {
        height
            .draw_series(LineSeries::new(
                samples.iter().map(|s| (t(s.t_us), value(s))),
                colour.stroke_width(2),
            ))
            .map_err(draw_error)?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    legend(&mut height)?;

    // Lateral position, relative to where the window starts: the search's spiral.
    let middle = row(root, ROWS[1]);
    let x0 = samples.first().map_or(0, |s| s.pose[0]);
    let y0 = samples.first().map_or(0, |s| s.pose[1]);
    let xy_range = range(
        samples
            .iter()
            .flat_map(|s| [mm(s.pose[0] - x0), mm(s.pose[1] - y0)]),
    );
    let mut lateral = chart(
        &middle,
        from..until,
        xy_range,
        "x, y from start (mm)",
        false,
    )?;
    for (axis, colour, name, origin) in [(0, MEASURED, "x", x0), (1, Y_COLOUR, "y", y0)] {
        lateral
            .draw_series(LineSeries::new(
                samples
                    .iter()
                    .map(|s| (t(s.t_us), mm(s.pose[axis] - origin))),
                colour.stroke_width(2),
            ))
            .map_err(draw_error)?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    legend(&mut lateral)?;

    // Force.
    let bottom = row(root, ROWS[2]);
    let f_max = samples.iter().map(|s| s.force_n).fold(1.0, f64::max) * 1.1;
    let mut force = chart(&bottom, from..until, 0.0..f_max, "contact force (N)", true)?;
    force
        .draw_series(LineSeries::new(
            samples.iter().map(|s| (t(s.t_us), s.force_n)),
            FORCE.stroke_width(2),
        ))
        .map_err(draw_error)?;

    // The installed schemas, on the charts' time axis.
    let x_of = |s: f64| PLOT_X0 + (s - from) / (until - from) * (PLOT_X1 - PLOT_X0);
    let mut shade = 0usize;
    for (name, start, end, safety) in spans(&run.installed, run.end_us) {
        let (a, b) = (t(start).max(from), t(end).min(until));
        if b <= a {
            continue;
        }
        let colour = if safety { ALERT } else { SHADES[shade % 2] };
        shade += 1;
        let (x0, y0) = px(x_of(a), LANE.y0);
        let (x1, y1) = px(x_of(b), LANE.y1);
        let x1 = x1.max(x0 + 1);
        root.draw(&Rectangle::new([(x0, y0), (x1, y1)], colour.filled()))
            .map_err(draw_error)?;
        // The name, upright, where it fits (shortened to the lane's height).
        if x1 - x0 >= 14 {
            let name = fit_line(root, &clean(&name), LANE.height() - 8.0, LEGEND_SIZE, false)?;
            let style = DB::font(LEGEND_SIZE, false)
                .color(&TEXT)
                .transform(FontTransform::Rotate270)
                .pos(Pos::new(HPos::Left, VPos::Center));
            root.draw(&Text::new(name, ((x0 + x1) / 2, y1 - 4), style))
                .map_err(draw_error)?;
        }
    }
    let (x0, y0) = px(PLOT_X0, LANE.y0);
    let (x1, y1) = px(PLOT_X1, LANE.y1);
    root.draw(&Rectangle::new(
        [(x0, y0), (x1, y1)],
        BORDER.stroke_width(1),
    ))
    .map_err(draw_error)?;
    draw_label(root, "installed schema", "", LANE, 2)
}

/// Each installed schema's name and time span (µs), and whether it is a safety recovery.
fn spans(installed: &[Installed], end_us: u64) -> Vec<(String, u64, u64, bool)> {
    installed
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let end = installed.get(i + 1).map_or(end_us, |n| n.t_us);
            (s.name.clone(), s.t_us, end, s.name.starts_with("safety:"))
        })
        .collect()
}
