//! A schema server's run: the end-effector's height (measured and attractor), its lateral
//! position, the contact force, and a lane naming the schema installed at each moment, on one
//! time axis. What the book's insertion figure shows (docs/schema-server.md).

use std::path::Path;

use anyhow::{anyhow, ensure};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use pab_lang::sim::schema::{Installed, Run};

use super::{draw_error, register_fonts};

const WIDTH: u32 = 1400;
const HEIGHT: u32 = 1000;
const MEASURED: RGBColor = RGBColor(0, 110, 190);
const ATTRACTOR: RGBColor = RGBColor(235, 120, 0);
const FORCE: RGBColor = RGBColor(190, 30, 45);
const Y_COLOUR: RGBColor = RGBColor(0, 150, 0);
const SHADES: [RGBColor; 2] = [RGBColor(225, 233, 245), RGBColor(200, 214, 236)];
const SAFETY: RGBColor = RGBColor(245, 190, 190);

/// Draws `run` from `from` to `until` seconds into `path` (PNG), titled `title`.
pub fn render_png(
    run: &Run,
    from: f64,
    until: f64,
    title: &str,
    path: &Path,
) -> anyhow::Result<()> {
    ensure!(
        until > from,
        "cannot plot: the time axis must end after it starts"
    );
    ensure!(
        path.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("png")),
        "cannot plot into {}: the file name must end in .png",
        path.display()
    );
    register_fonts()?;
    let samples: Vec<_> = run
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
    let root = BitMapBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area();
    root.fill(&WHITE).map_err(draw_error)?;
    let root = root.titled(title, ("sans-serif", 26)).map_err(draw_error)?;
    let (top, rest) = root.split_vertically(300);
    let (middle, rest) = rest.split_vertically(250);
    let (force_area, lane_area) = rest.split_vertically(250);

    let t = |us: u64| us as f64 * 1e-6;
    let mm = |um: i32| f64::from(um) * 1e-3;
    let range = |values: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        let pad = ((hi - lo) * 0.08).max(0.05);
        (lo - pad)..(hi + pad)
    };

    // Height.
    let z_range = range(
        &mut samples
            .iter()
            .flat_map(|s| [mm(s.pose[2]), mm(s.attractor[2])]),
    );
    let mut chart = ChartBuilder::on(&top)
        .margin(10)
        .x_label_area_size(0)
        .y_label_area_size(70)
        .build_cartesian_2d(from..until, z_range)
        .map_err(draw_error)?;
    chart
        .configure_mesh()
        .y_desc("z (mm)")
        .x_labels(12)
        .y_labels(8)
        .disable_x_mesh()
        .draw()
        .map_err(draw_error)?;
    chart
        .draw_series(LineSeries::new(
            samples.iter().map(|s| (t(s.t_us), mm(s.attractor[2]))),
            ATTRACTOR.stroke_width(2),
        ))
        .map_err(draw_error)?
        .label("attractor")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], ATTRACTOR.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            samples.iter().map(|s| (t(s.t_us), mm(s.pose[2]))),
            MEASURED.stroke_width(2),
        ))
        .map_err(draw_error)?
        .label("measured")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], MEASURED.stroke_width(2)));
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_error)?;

    // Lateral position, relative to where the window starts: the search's spiral.
    let x0 = samples.first().map_or(0, |s| s.pose[0]);
    let y0 = samples.first().map_or(0, |s| s.pose[1]);
    let xy_range = range(
        &mut samples
            .iter()
            .flat_map(|s| [mm(s.pose[0] - x0), mm(s.pose[1] - y0)]),
    );
    let mut chart = ChartBuilder::on(&middle)
        .margin(10)
        .x_label_area_size(0)
        .y_label_area_size(70)
        .build_cartesian_2d(from..until, xy_range)
        .map_err(draw_error)?;
    chart
        .configure_mesh()
        .y_desc("x, y from start (mm)")
        .y_labels(8)
        .disable_x_mesh()
        .draw()
        .map_err(draw_error)?;
    for (axis, colour, name, origin) in [(0, MEASURED, "x", x0), (1, Y_COLOUR, "y", y0)] {
        chart
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
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.9))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_error)?;

    // Force.
    let f_max = samples.iter().map(|s| s.force_n).fold(1.0, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&force_area)
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(70)
        .build_cartesian_2d(from..until, 0.0..f_max)
        .map_err(draw_error)?;
    chart
        .configure_mesh()
        .y_desc("contact force (N)")
        .x_desc("t (s)")
        .y_labels(8)
        .disable_x_mesh()
        .draw()
        .map_err(draw_error)?;
    chart
        .draw_series(LineSeries::new(
            samples.iter().map(|s| (t(s.t_us), s.force_n)),
            FORCE.stroke_width(2),
        ))
        .map_err(draw_error)?;

    // The installed schemas.
    let lane = lane_area.margin(10, 10, 80, 10);
    let (w, h) = lane.dim_in_pixel();
    let x_of = |s: f64| ((s - from) / (until - from) * f64::from(w)).round() as i32;
    let spans = spans(&run.installed, run.end_us);
    let mut shade = 0usize;
    for (name, start, end, safety) in spans {
        let (a, b) = (t(start).max(from), t(end).min(until));
        if b <= a {
            continue;
        }
        let colour = if safety { SAFETY } else { SHADES[shade % 2] };
        shade += 1;
        let (x0, x1) = (x_of(a), x_of(b).max(x_of(a) + 1));
        lane.draw(&Rectangle::new([(x0, 0), (x1, h as i32)], colour.filled()))
            .map_err(draw_error)?;
        // The name, upright, where it fits.
        let style = TextStyle::from(("sans-serif", 13).into_font())
            .transform(FontTransform::Rotate270)
            .pos(Pos::new(HPos::Left, VPos::Center));
        if x1 - x0 >= 14 {
            lane.draw(&Text::new(
                name.clone(),
                ((x0 + x1) / 2, h as i32 - 4),
                style,
            ))
            .map_err(draw_error)?;
        }
    }
    lane.draw(&Text::new(
        "installed schema",
        (0, -2),
        TextStyle::from(("sans-serif", 15).into_font()).pos(Pos::new(HPos::Left, VPos::Bottom)),
    ))
    .map_err(draw_error)?;
    root.present()
        .map_err(|e| anyhow!("cannot write the plot to {}: {e}", path.display()))
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
