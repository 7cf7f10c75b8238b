//! One style for every plot (the stimulation plot with its dynamics and HBBA lanes, the schema
//! server's plot): the image's width and columns, the palette, the font and its sizes, and the
//! two output formats, PNG and SVG, drawn by the same code through [`Canvas`].
//!
//! Font sizes are whole even numbers of pixels ([`snap`]): plotters' glyph rasteriser places
//! each glyph at `size / 2 + its top`, truncated towards zero, which puts glyphs that sit on the
//! baseline (`.`, `,`, `_`) a pixel higher than the letters whenever `size / 2` has a fraction:
//! "0.2" then reads "0·2".

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{anyhow, ensure};
use plotters::backend::{BitMapBackend, DrawingBackend, SVGBackend};
use plotters::coord::Shift;
use plotters::drawing::{DrawingArea, IntoDrawingArea};
use plotters::style::{FontDesc, FontFamily, FontStyle, RGBColor, TextStyle, register_font};

/// Width of every image, pixels.
pub(crate) const WIDTH: u32 = 1400;
/// Left edge of the texts (a centred title aside).
pub(crate) const MARGIN_X: f64 = 14.0;
/// Right end of the labels left of the plot areas; the value tick labels sit between it and the
/// plot area.
pub(crate) const LABEL_X1: f64 = 276.0;
/// Left edge of the plot areas (the start of the time axis).
pub(crate) const PLOT_X0: f64 = 300.0;
/// Right edge of the plot areas (the end of the time axis).
pub(crate) const PLOT_X1: f64 = WIDTH as f64 - 24.0;
/// Height of the title row.
pub(crate) const TITLE_H: f64 = 48.0;

// Font sizes (pixels; whole and even, see the module's documentation).
/// The title.
pub(crate) const TITLE_SIZE: f64 = 22.0;
/// A section's header (a port, a dynamics group, a lane group, a chart's name).
pub(crate) const HEADER_SIZE: f64 = 16.0;
/// A strip's label, a band's name, the phases' names.
pub(crate) const LABEL_SIZE: f64 = 14.0;
/// Legends, the axis caption, the notes in lanes.
pub(crate) const LEGEND_SIZE: f64 = 12.0;
/// The time tick labels.
pub(crate) const TICK_SIZE: f64 = 12.0;
/// The value tick labels left of a strip.
pub(crate) const VALUE_SIZE: f64 = 10.0;
/// Texts smaller than this are left out (strips shrunk too much to hold them).
pub(crate) const MIN_FONT: f64 = 6.0;

// The palette.
pub(crate) const BACKGROUND: RGBColor = RGBColor(255, 255, 255);
pub(crate) const TEXT: RGBColor = RGBColor(20, 20, 20);
pub(crate) const SOFT_TEXT: RGBColor = RGBColor(90, 90, 90);
/// Plot boxes, axes and tick marks.
pub(crate) const BORDER: RGBColor = RGBColor(150, 150, 150);
pub(crate) const GRID: RGBColor = RGBColor(232, 232, 232);
/// The activation threshold (dashed) and a lane's zero line.
pub(crate) const THRESHOLD: RGBColor = RGBColor(185, 185, 185);
/// The line between two sections.
pub(crate) const SEPARATOR: RGBColor = RGBColor(205, 205, 205);
/// Stimulation while the connection is the one selected at its port.
pub(crate) const SELECTED: RGBColor = RGBColor(0, 150, 0);
/// Stimulation while another connection (or none) is selected.
pub(crate) const NOT_SELECTED: RGBColor = RGBColor(255, 140, 0);
/// Alternate shades of consecutive intervals: phases, installed schemas.
pub(crate) const SHADES: [RGBColor; 2] = [RGBColor(228, 228, 228), RGBColor(196, 196, 196)];
/// A gate while it is open: in a dynamics lane and in a gate's strip.
pub(crate) const GATE: RGBColor = RGBColor(196, 232, 196);
/// A special connection's window: suppress, inhibit and write-inhibit hold others back.
pub(crate) const WINDOW: RGBColor = RGBColor(240, 200, 200);
/// An override's window: it subsumes the layers below it.
pub(crate) const OVERRIDE: RGBColor = RGBColor(200, 215, 240);
/// A step lane's value (HBBA's strategies and pass rates).
pub(crate) const FILL: RGBColor = RGBColor(150, 185, 235);
/// Something that went wrong: a safety recovery.
pub(crate) const ALERT: RGBColor = RGBColor(245, 190, 190);
/// Lines of values, in the order a chart takes them: n, ρ, m in a dynamics lane; the measured,
/// attractor, y and force lines in the schema plot.
pub(crate) const LINES: [RGBColor; 4] = [
    RGBColor(25, 80, 200),
    RGBColor(225, 110, 0),
    RGBColor(150, 50, 160),
    RGBColor(190, 30, 45),
];

/// The font family: the embedded DejaVu Sans, registered under this name; an SVG asks its
/// viewer for DejaVu Sans, else any sans-serif font.
const FAMILY: &str = "DejaVu Sans, sans-serif";

/// `size` rounded down to a whole even number of pixels (see the module's documentation).
pub(crate) fn snap(size: f64) -> f64 {
    if size.is_finite() {
        (size / 2.0).floor() * 2.0
    } else {
        0.0
    }
}

/// The plot font at `size` (snapped), bold or not, as measured. Draw texts with
/// [`Canvas::font`], which sizes it for the backend.
pub(crate) fn font(size: f64, bold: bool) -> TextStyle<'static> {
    let style = if bold {
        FontStyle::Bold
    } else {
        FontStyle::Normal
    };
    TextStyle::from(FontDesc::new(FontFamily::Name(FAMILY), snap(size), style))
}

/// A drawing backend the plots draw on: the same drawing code for every format, with what
/// differs in how each places text.
pub(crate) trait Canvas: DrawingBackend {
    /// How far above the wanted centre of the capitals a text's top anchor goes, in font sizes.
    const TEXT_RAISE: f64;
    /// The size to ask the backend for, so that its text has the size measured.
    const TEXT_SCALE: f64;

    /// The plot font at `size`, bold or not, for this backend.
    fn font(size: f64, bold: bool) -> TextStyle<'static> {
        let measured = font(size, bold);
        let style = if bold {
            FontStyle::Bold
        } else {
            FontStyle::Normal
        };
        let size = measured.font.get_size() * Self::TEXT_SCALE;
        TextStyle::from(FontDesc::new(FontFamily::Name(FAMILY), size, style))
    }
}

impl Canvas for BitMapBackend<'_> {
    // The glyph rasteriser puts the baseline half a size below the top anchor; DejaVu Sans'
    // capitals are 0.63 sizes high.
    const TEXT_RAISE: f64 = 0.19;
    const TEXT_SCALE: f64 = 1.0;
}

impl Canvas for SVGBackend<'_> {
    // plotters writes `font-size` = size / 1.24 and puts the baseline 0.76 em below the top
    // anchor; the rasteriser's size is DejaVu Sans' ascent plus descent, 1.164 em. Scaled so
    // that the em is the rasteriser's, the capitals' centre is 0.34 sizes below the anchor.
    const TEXT_RAISE: f64 = 0.34;
    const TEXT_SCALE: f64 = 1.24 / 1.164;
}

/// What the plots draw on.
pub(crate) type Area<DB> = DrawingArea<DB, Shift>;

/// The image formats a plot is drawn in, by the file name's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `.png`: a bitmap.
    Png,
    /// `.svg`: a vector image whose texts are text.
    Svg,
}

impl Format {
    /// The format of a file named `path` (`.png` or `.svg`, any case), if it is one.
    pub fn of(path: &Path) -> Option<Format> {
        let extension = path.extension()?.to_str()?;
        if extension.eq_ignore_ascii_case("png") {
            Some(Format::Png)
        } else if extension.eq_ignore_ascii_case("svg") {
            Some(Format::Svg)
        } else {
            None
        }
    }
}

/// What the error messages say the file name must end in.
pub const EXTENSIONS: &str = ".png or .svg";

/// A picture to draw: its size and how to draw it on any canvas.
pub(crate) trait Picture {
    /// Width and height, pixels.
    fn size(&self) -> (u32, u32);
    /// Draws it on `root`, which has [`Picture::size`].
    fn draw<DB: Canvas>(&self, root: &Area<DB>) -> anyhow::Result<()>;
}

/// Draws `picture` into `path`, as PNG or SVG after its extension; anything else is refused
/// before a file is created.
pub(crate) fn render(picture: &impl Picture, path: &Path) -> anyhow::Result<()> {
    let format = Format::of(path).ok_or_else(|| {
        anyhow!(
            "cannot plot into {}: the file name must end in {EXTENSIONS}",
            path.display()
        )
    })?;
    register_fonts()?;
    let size = picture.size();
    let written =
        |e: &dyn std::fmt::Display| anyhow!("cannot write the plot to {}: {e}", path.display());
    match format {
        Format::Png => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            picture.draw(&root)?;
            root.present().map_err(|e| written(&e))
        }
        Format::Svg => {
            let mut svg = String::new();
            {
                let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
                picture.draw(&root)?;
                root.present().map_err(|e| written(&e))?;
            }
            std::fs::write(path, svg).map_err(|e| written(&e))
        }
    }
}

/// Registers the embedded DejaVu Sans under the plots' family name, so that the plots do not
/// depend on the fonts of the machine (and the widths measured are the font's).
pub(crate) fn register_fonts() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && register_font(FAMILY, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    ensure!(ok, "cannot load the embedded DejaVu Sans font");
    Ok(())
}

/// A drawing error as a plot's error.
pub(crate) fn draw_error(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("cannot draw the plot: {e}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_are_whole_and_even() {
        assert_eq!(snap(13.0), 12.0);
        assert_eq!(snap(14.0), 14.0);
        assert_eq!(snap(9.1), 8.0);
        assert_eq!(snap(f64::NAN), 0.0);
        for size in [
            TITLE_SIZE,
            HEADER_SIZE,
            LABEL_SIZE,
            LEGEND_SIZE,
            TICK_SIZE,
            VALUE_SIZE,
        ] {
            assert_eq!(snap(size), size);
        }
    }

    #[test]
    fn formats_follow_the_extension() {
        assert_eq!(Format::of(Path::new("a/b.png")), Some(Format::Png));
        assert_eq!(Format::of(Path::new("b.SVG")), Some(Format::Svg));
        assert_eq!(Format::of(Path::new("b.pdf")), None);
        assert_eq!(Format::of(Path::new("png")), None);
    }
}
