//! Labelled PNG charts for the reports (`cloudscape loadtest --plot`, `cloudscape bench
//! --plots`): panels of line or point series on linear or log axes.
//!
//! Drawn with `plotters` into an RGB buffer and encoded with the same PNG encoder as the
//! products. Text uses DejaVu Sans Mono, embedded (assets/fonts/, Bitstream Vera
//! licence), through plotters' `ab_glyph` backend, so nothing depends on the system's
//! font libraries.

use std::sync::Once;

use plotters::prelude::*;
use plotters::style::FontStyle;

use cloudscape_core::render::image::{PngSpace, encode_png};

const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSansMono.ttf");
const FONT_NAME: &str = "sans-serif";

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    Line,
    Points,
}

/// One named series of (x, y) points.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub colour: (u8, u8, u8),
    pub mark: Mark,
}

/// One chart: axes, labels and the series drawn on them.
#[derive(Clone, Debug, Default)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Base-10 logarithmic axes (non-positive values are dropped).
    pub x_log: bool,
    pub y_log: bool,
    pub series: Vec<Series>,
}

/// Distinct colours for series, in order.
pub const PALETTE: [(u8, u8, u8); 6] = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (255, 127, 14),
    (148, 103, 189),
    (0, 0, 0),
];

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT).is_err() {
            panic!("the embedded font is not a valid TrueType font");
        }
    });
}

/// Draws `panels` side by side (at most `columns` per row), each `panel_size` pixels,
/// and returns the PNG bytes.
pub fn render(panels: &[Panel], columns: usize, panel_size: (u32, u32)) -> Result<Vec<u8>, String> {
    register_font();
    let columns = columns.clamp(1, panels.len().max(1));
    let rows = panels.len().div_ceil(columns).max(1);
    let (w, h) = (panel_size.0 * columns as u32, panel_size.1 * rows as u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let areas = root.split_evenly((rows, columns));
        for (panel, area) in panels.iter().zip(areas.iter()) {
            draw_panel(panel, area).map_err(|e| format!("cannot draw chart `{}`: {e}", panel.title))?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(encode_png(
        w as usize,
        h as usize,
        png::ColorType::Rgb,
        PngSpace::Srgb,
        &buf,
    ))
}

/// Axis range of `values` (already transformed), padded; a degenerate range is widened.
fn range(values: impl Iterator<Item = f64>, log: bool, from_zero: bool) -> (f64, f64) {
    let (mut lo, mut hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    if from_zero && !log {
        lo = lo.min(0.0);
    }
    if hi - lo < 1e-12 {
        let d = if log { 0.5 } else { hi.abs().max(1.0) * 0.1 };
        lo -= d;
        hi += d;
    }
    let pad = (hi - lo) * 0.05;
    (if from_zero && !log && lo >= 0.0 { lo } else { lo - pad }, hi + pad)
}

fn transform(v: f64, log: bool) -> Option<f64> {
    if !v.is_finite() {
        return None;
    }
    if log { (v > 0.0).then(|| v.log10()) } else { Some(v) }
}

/// A tick label: the value itself, or 10^v on a log axis.
fn tick(v: f64, log: bool) -> String {
    let v = if log {
        // Two significant digits: 3.2, 32, 320.
        let p = 10f64.powf(v);
        let scale = 10f64.powf(p.abs().log10().floor() - 1.0);
        (p / scale).round() * scale
    } else {
        v
    };
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.3}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    } else {
        format!("{v:.4}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    }
}

fn draw_panel(panel: &Panel, area: &DrawingArea<BitMapBackend, plotters::coord::Shift>) -> Result<(), String> {
    let series: Vec<(&Series, Vec<(f64, f64)>)> = panel
        .series
        .iter()
        .map(|s| {
            let pts = s
                .points
                .iter()
                .filter_map(|&(x, y)| Some((transform(x, panel.x_log)?, transform(y, panel.y_log)?)))
                .collect();
            (s, pts)
        })
        .collect();
    let xs = series.iter().flat_map(|(_, p)| p.iter().map(|q| q.0));
    let ys = series.iter().flat_map(|(_, p)| p.iter().map(|q| q.1));
    let (x0, x1) = range(xs, panel.x_log, false);
    let (y0, y1) = range(ys, panel.y_log, true);
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FONT_NAME, 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    let (xl, yl) = (panel.x_log, panel.y_log);
    let x_fmt = move |v: &f64| tick(*v, xl);
    let y_fmt = move |v: &f64| tick(*v, yl);
    chart
        .configure_mesh()
        .x_desc(&panel.x_label)
        .y_desc(&panel.y_label)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FONT_NAME, 12))
        .axis_desc_style((FONT_NAME, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(e)?;
    for (s, pts) in &series {
        let c = RGBColor(s.colour.0, s.colour.1, s.colour.2);
        let drawn = match s.mark {
            Mark::Line => chart
                .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
                .map_err(e)?,
            Mark::Points => chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled())))
                .map_err(e)?,
        };
        if !s.name.is_empty() {
            drawn
                .label(s.name.clone())
                .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 14, y + 4)], c.filled()));
        }
    }
    if series.iter().any(|(s, _)| !s.name.is_empty()) {
        chart
            .configure_series_labels()
            .label_font((FONT_NAME, 12))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// Layout of [`contact_sheet`]: the label column on the left, in pixels.
pub const CONTACT_LABEL_WIDTH: usize = 150;
/// Layout of [`contact_sheet`]: the header row of column titles, in pixels.
pub const CONTACT_HEADER_HEIGHT: usize = 24;
/// Layout of [`contact_sheet`]: the caption strip under every cell, in pixels.
pub const CONTACT_CAPTION_HEIGHT: usize = 18;

/// One picture of a contact sheet: 8-bit RGB, row-major, and the caption under it.
pub struct SheetCell {
    pub rgb: Vec<u8>,
    pub caption: String,
}

/// A labelled grid of equally sized pictures (`cell` = width, height in pixels):
/// `rows × columns` cells in row-major order, a title over every column and a label
/// left of every row. The PNG is `CONTACT_LABEL_WIDTH + columns · width` wide and
/// `CONTACT_HEADER_HEIGHT + rows · (height + CONTACT_CAPTION_HEIGHT)` high.
pub fn contact_sheet(
    row_labels: &[&str],
    column_titles: &[&str],
    cells: &[SheetCell],
    cell: (usize, usize),
) -> Result<Vec<u8>, String> {
    register_font();
    let (cw, ch) = cell;
    let (rows, cols) = (row_labels.len(), column_titles.len());
    if cells.len() != rows * cols || cells.iter().any(|c| c.rgb.len() != cw * ch * 3) {
        return Err("a contact sheet needs one picture of the cell size per row and column".into());
    }
    let (w, h) = (
        CONTACT_LABEL_WIDTH + cols * cw,
        CONTACT_HEADER_HEIGHT + rows * (ch + CONTACT_CAPTION_HEIGHT),
    );
    let mut buf = vec![255u8; w * h * 3];
    for (i, c) in cells.iter().enumerate() {
        let (x0, y0) = (
            CONTACT_LABEL_WIDTH + (i % cols) * cw,
            CONTACT_HEADER_HEIGHT + (i / cols) * (ch + CONTACT_CAPTION_HEIGHT),
        );
        for y in 0..ch {
            let dst = ((y0 + y) * w + x0) * 3;
            buf[dst..dst + cw * 3].copy_from_slice(&c.rgb[y * cw * 3..(y + 1) * cw * 3]);
        }
    }
    {
        let e = |err: DrawingAreaErrorKind<_>| err.to_string();
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let big = TextStyle::from((FONT_NAME, 16).into_font()).color(&BLACK);
        let small = TextStyle::from((FONT_NAME, 12).into_font()).color(&BLACK);
        for (j, t) in column_titles.iter().enumerate() {
            let x = (CONTACT_LABEL_WIDTH + j * cw + 4) as i32;
            root.draw(&Text::new(t.to_string(), (x, 4), big.clone())).map_err(e)?;
        }
        for (i, l) in row_labels.iter().enumerate() {
            let y = (CONTACT_HEADER_HEIGHT + i * (ch + CONTACT_CAPTION_HEIGHT) + ch / 2) as i32 - 8;
            root.draw(&Text::new(l.to_string(), (6, y), big.clone())).map_err(e)?;
        }
        for (i, c) in cells.iter().enumerate() {
            let x = (CONTACT_LABEL_WIDTH + (i % cols) * cw + 4) as i32;
            let y = (CONTACT_HEADER_HEIGHT + (i / cols) * (ch + CONTACT_CAPTION_HEIGHT) + ch + 2) as i32;
            root.draw(&Text::new(c.caption.clone(), (x, y), small.clone()))
                .map_err(e)?;
        }
        root.present().map_err(e)?;
    }
    Ok(encode_png(w, h, png::ColorType::Rgb, PngSpace::Srgb, &buf))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_a_decodable_png_with_log_axes_and_empty_series() {
        let panels = vec![
            Panel {
                title: "latency".into(),
                x_label: "s".into(),
                y_label: "ms".into(),
                y_log: true,
                series: vec![Series {
                    name: "p50".into(),
                    points: vec![(0.0, 1.0), (1.0, 10.0), (2.0, 0.0)],
                    colour: PALETTE[0],
                    mark: Mark::Line,
                }],
                ..Panel::default()
            },
            Panel {
                title: "nothing".into(),
                ..Panel::default()
            },
        ];
        let png = render(&panels, 2, (320, 240)).unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(png));
        let info = decoder.read_info().unwrap();
        assert_eq!((info.info().width, info.info().height), (640, 240));
    }

    #[test]
    fn tick_labels_read_as_numbers() {
        assert_eq!(tick(2.0, true), "100");
        assert_eq!(tick(0.25, false), "0.25");
        assert_eq!(tick(0.0, false), "0");
    }

    #[test]
    fn contact_sheet_places_cells_under_their_titles() {
        let (cw, ch) = (40, 20);
        let cells: Vec<SheetCell> = (0..6)
            .map(|i| SheetCell {
                rgb: vec![(i * 40) as u8; cw * ch * 3],
                caption: format!("cell {i}"),
            })
            .collect();
        let png = contact_sheet(&["a", "b"], &["x", "y", "z"], &cells, (cw, ch)).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        let (w, h) = (info.width as usize, info.height as usize);
        assert_eq!(w, CONTACT_LABEL_WIDTH + 3 * cw);
        assert_eq!(h, CONTACT_HEADER_HEIGHT + 2 * (ch + CONTACT_CAPTION_HEIGHT));
        // The middle of every cell holds that cell's colour (text lies outside them).
        for i in 0..6 {
            let x = CONTACT_LABEL_WIDTH + (i % 3) * cw + cw / 2;
            let y = CONTACT_HEADER_HEIGHT + (i / 3) * (ch + CONTACT_CAPTION_HEIGHT) + ch / 2;
            assert_eq!(buf[(y * w + x) * 3], (i * 40) as u8, "cell {i}");
        }
        // Labels were drawn: the label column is not all white.
        assert!((0..h).any(|y| (0..CONTACT_LABEL_WIDTH).any(|x| buf[(y * w + x) * 3] < 128)));
        assert!(contact_sheet(&["a"], &["x"], &cells[..2], (cw, ch)).is_err());
    }
}
