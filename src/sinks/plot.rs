//! Plots as SVG or PNG (chosen by the file's extension, [`ImageFormat`]),
//! drawn with plotters: its SVG backend, or its bitmap backend into a
//! buffer encoded by `png`. Text is laid out (and, in PNG, drawn) with
//! DejaVu Sans embedded in the binary, so no system font or library is
//! needed.
//!
//! Two levels:
//! - a small plotting API for any line data: [`Figure`] (panels stacked
//!   vertically) of [`Panel`]s (axes, optional log-y) of [`Series`] (named
//!   polylines, optionally broken into pieces, with markers or dashed
//!   connectors). Paper reproductions use it for sweeps and error norms:
//!
//!   ```
//!   use hybsim::sinks::plot::{Figure, Panel, Series};
//!   let e: Vec<(f64, f64)> = (0..50).map(|k| (k as f64 * 0.1, (-(k as f64) * 0.1).exp())).collect();
//!   let svg = Figure::new()
//!       .panel(Panel::new("|e| over t").x_label("t").y_label("|e|").log_y(true)
//!           .series(Series::line("|e|", e)))
//!       .to_svg_string()
//!       .unwrap();
//!   assert!(svg.starts_with("<svg"));
//!   ```
//! - [`PlotSink`], an [`ArcSink`] that keeps the selected states/outputs of
//!   a run and draws one panel per model entry against t, each flow
//!   interval a solid piece and each jump a dashed vertical segment (or
//!   another of HyEQ's plots, [`PlotKind`]). `hybsim plot run.mcap` feeds
//!   the same sink from a logged file ([`PlotSink::for_log`],
//!   [`super::mcap_read::RunLog`]), so a plot from a file is the plot of
//!   the run.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::FontStyle;

use super::{Decimation, Decimator, OutputFn, RunInfo, SinkError, entry_names};
use crate::arc::{ArcSink, HybridTime, SampleKind};
use crate::atomic_file;
use crate::layout::{Entry, Field, Layout, Shape};

/// Colours of successive series (a colour-blind-friendly palette).
const COLORS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// At most this many series are drawn (and listed) in one panel.
pub const MAX_SERIES_PER_PANEL: usize = 10;

/// Above this many jumps in one series, jumps are drawn solid in one
/// polyline instead of as separate dashed segments (see [`Series::hybrid_points`]).
pub const MAX_DASHED_JUMPS: usize = 400;

/// Width in pixels of the legend column right of each panel's axes.
const LEGEND_WIDTH: u32 = 190;

/// One named line: polyline pieces, optional dashed connectors between
/// points (jumps), optional markers at the points.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Solid polylines; each piece is drawn separately (no line between pieces).
    pub pieces: Vec<Vec<(f64, f64)>>,
    /// Dashed segments, e.g. a jump from `(t, pre)` to `(t, post)`.
    pub connectors: Vec<[(f64, f64); 2]>,
    /// Draw a marker at every point of the pieces.
    pub markers: bool,
}

impl Series {
    /// One polyline through `points`.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.into(),
            pieces: vec![points],
            ..Self::default()
        }
    }

    /// Markers only (no line), e.g. for a parameter sweep.
    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Self {
            markers: true,
            ..Self::line(name, points).lines(false)
        }
    }

    /// A hybrid arc of one scalar: `samples[k] = ((t, j), value)` in domain
    /// order. Each flow interval (constant j) is one piece; consecutive
    /// pieces are joined by a dashed segment (the jump).
    pub fn hybrid(name: impl Into<String>, samples: &[(HybridTime, f64)]) -> Self {
        let points: Vec<(HybridTime, (f64, f64))> =
            samples.iter().map(|&(at, v)| (at, (at.t, v))).collect();
        Self::hybrid_points(name, &points)
    }

    /// A hybrid arc drawn in any plane: `points[k] = ((t, j), (x, y))` in
    /// domain order. Each flow interval is one piece, each jump a dashed
    /// segment from its pre- to its post-jump point. Above
    /// [`MAX_DASHED_JUMPS`] jumps the dashes would only blacken the plot and
    /// bloat the file: the pieces are then joined into one polyline (the
    /// jumps drawn solid).
    pub fn hybrid_points(name: impl Into<String>, points: &[(HybridTime, (f64, f64))]) -> Self {
        let (pieces, connectors) = split_at_jumps(points);
        Self {
            name: name.into(),
            pieces,
            connectors,
            markers: false,
        }
    }

    /// Draw markers at the points.
    pub fn markers(self, markers: bool) -> Self {
        Self { markers, ..self }
    }

    /// `false` keeps only the markers (the pieces are not joined by lines).
    fn lines(self, lines: bool) -> Self {
        if lines {
            self
        } else {
            Self {
                pieces: self.pieces.into_iter().flatten().map(|p| vec![p]).collect(),
                ..self
            }
        }
    }

    fn all_points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.pieces
            .iter()
            .flatten()
            .copied()
            .chain(self.connectors.iter().flatten().copied())
    }
}

/// Splits points in domain order into flow pieces (constant j) and jump
/// connectors (from a pre- to its post-jump point). Above
/// [`MAX_DASHED_JUMPS`] jumps the dashes would only blacken the plot and
/// bloat the file: the pieces are then joined into one polyline (the jumps
/// drawn solid).
#[allow(clippy::type_complexity)] // (pieces, connectors)
fn split_at_jumps<P: Copy>(points: &[(HybridTime, P)]) -> (Vec<Vec<P>>, Vec<[P; 2]>) {
    let mut pieces: Vec<Vec<P>> = Vec::new();
    let mut connectors = Vec::new();
    let mut last: Option<(HybridTime, P)> = None;
    for &(at, p) in points {
        match last {
            Some((prev, _)) if prev.j == at.j => pieces.last_mut().expect("a piece exists").push(p),
            Some((_, pp)) => {
                connectors.push([pp, p]);
                pieces.push(vec![p]);
            }
            None => pieces.push(vec![p]),
        }
        last = Some((at, p));
    }
    if connectors.len() > MAX_DASHED_JUMPS {
        pieces = vec![points.iter().map(|&(_, p)| p).collect()];
        connectors.clear();
    }
    (pieces, connectors)
}

/// A point of a 3-D panel: (t, j, value).
pub type Point3 = (f64, f64, f64);

/// One named line over the hybrid time domain, drawn in a 3-D panel (HyEQ's
/// `plotHybrid`): each flow interval a solid piece in its plane j, each
/// jump a dashed segment from (t, j, pre) to (t, j + 1, post).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series3 {
    /// Legend text.
    pub name: String,
    /// Solid polylines of (t, j, value).
    pub pieces: Vec<Vec<Point3>>,
    /// Dashed segments (the jumps).
    pub connectors: Vec<[Point3; 2]>,
}

impl Series3 {
    /// A hybrid arc of one scalar: `samples[k] = ((t, j), value)` in domain
    /// order.
    pub fn hybrid(name: impl Into<String>, samples: &[(HybridTime, f64)]) -> Self {
        let points: Vec<(HybridTime, Point3)> = samples
            .iter()
            .map(|&(at, v)| (at, (at.t, at.j as f64, v)))
            .collect();
        Self::hybrid_points(name, &points)
    }

    /// A hybrid arc drawn in any 3-D space: `points[k] = ((t, j), (x, y,
    /// z))` in domain order, x to the right, y into the depth, z up (a
    /// phase plot of three components). Each flow interval is one piece,
    /// each jump a dashed segment.
    pub fn hybrid_points(name: impl Into<String>, points: &[(HybridTime, Point3)]) -> Self {
        let (pieces, connectors) = split_at_jumps(points);
        Self {
            name: name.into(),
            pieces,
            connectors,
        }
    }

    fn all_points(&self) -> impl Iterator<Item = Point3> + '_ {
        self.pieces
            .iter()
            .flatten()
            .copied()
            .chain(self.connectors.iter().flatten().copied())
    }
}

/// One set of axes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Panel {
    /// Caption above the axes.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label (in a 3-D panel: the depth axis, j).
    pub y_label: String,
    /// Vertical axis label of a 3-D panel (the value).
    pub z_label: String,
    /// The lines.
    pub series: Vec<Series>,
    /// Logarithmic y axis; points with y ≤ 0 are left out (breaking the line).
    pub log_y: bool,
    /// Lines over the hybrid time domain: a panel with any is drawn as 3-D
    /// axes t, j and `y_label` (its 2-D `series` are then not drawn).
    pub series_3d: Vec<Series3>,
    /// The x axis counts (the jump count j): whole-number tick labels only.
    pub x_integers: bool,
    /// The y axis (a 3-D panel's depth axis) counts: whole-number tick labels only.
    pub y_integers: bool,
}

impl Panel {
    /// An empty panel with a caption.
    pub fn new(title: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            ..Self::default()
        }
    }

    /// Sets the x label.
    pub fn x_label(self, x_label: impl Into<String>) -> Self {
        Self {
            x_label: x_label.into(),
            ..self
        }
    }

    /// Sets the y label.
    pub fn y_label(self, y_label: impl Into<String>) -> Self {
        Self {
            y_label: y_label.into(),
            ..self
        }
    }

    /// Sets the vertical axis label of a 3-D panel.
    pub fn z_label(self, z_label: impl Into<String>) -> Self {
        Self {
            z_label: z_label.into(),
            ..self
        }
    }

    /// Logarithmic y axis.
    pub fn log_y(self, log_y: bool) -> Self {
        Self { log_y, ..self }
    }

    /// The x axis counts (j): its tick labels are whole numbers (`5`, not `5.0`), and
    /// ticks between them have none.
    pub fn x_integers(self, x_integers: bool) -> Self {
        Self { x_integers, ..self }
    }

    /// As [`x_integers`](Self::x_integers) for the y axis.
    pub fn y_integers(self, y_integers: bool) -> Self {
        Self { y_integers, ..self }
    }

    /// Adds a series.
    pub fn series(mut self, series: Series) -> Self {
        self.series.push(series);
        self
    }

    /// Adds a line over the hybrid time domain (the panel becomes 3-D).
    pub fn series_3d(mut self, series: Series3) -> Self {
        self.series_3d.push(series);
        self
    }
}

/// Panels stacked vertically, sharing the width.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// The panels, top to bottom.
    pub panels: Vec<Panel>,
    /// Width in pixels. Default 900.
    pub width: u32,
    /// Height of each panel in pixels. Default 260.
    pub panel_height: u32,
}

impl Default for Figure {
    fn default() -> Self {
        Self {
            panels: Vec::new(),
            width: 900,
            panel_height: 260,
        }
    }
}

/// The tick label of an axis that counts (the jump count j): `5` at a whole number, nothing
/// between two (plotters places ticks at 2.5 on a short range).
fn integer_label(v: &f64) -> String {
    let k = v.round();
    if (v - k).abs() <= 1e-9 * k.abs().max(1.0) {
        format!("{k:.0}")
    } else {
        String::new()
    }
}

/// A tick of a linear axis as plotters writes it, but a zero without its sign: the ticks are
/// `start + k·step` in floating point, so the one at 0 can be -3e-17, which was shown as "-0.0".
fn decimal_label(v: &f64) -> String {
    let s = <RangedCoordf64 as ValueFormatter<f64>>::format(v);
    match s.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_string(),
        _ => s,
    }
}

/// Finite, non-degenerate bounds of `values`, padded by 5 %.
fn bounds(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return if log { (0.1, 10.0) } else { (-1.0, 1.0) };
    }
    if log {
        if hi / lo < 1.0 + 1e-9 {
            return (lo / 2.0, hi * 2.0);
        }
        let r = (hi / lo).powf(0.05);
        return (lo / r, hi * r);
    }
    if hi - lo <= f64::EPSILON * hi.abs().max(lo.abs()).max(1e-300) {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        return (lo - d, hi + d);
    }
    let pad = (hi - lo) * 0.05;
    (lo - pad, hi + pad)
}

/// Splits a piece where a point cannot be drawn (non-finite, or y ≤ 0 on a log axis).
fn drawable_runs(piece: &[(f64, f64)], log: bool) -> Vec<Vec<(f64, f64)>> {
    let mut runs = vec![Vec::new()];
    for &(x, y) in piece {
        if x.is_finite() && y.is_finite() && (!log || y > 0.0) {
            runs.last_mut().expect("a run exists").push((x, y));
        } else if !runs.last().expect("a run exists").is_empty() {
            runs.push(Vec::new());
        }
    }
    runs.retain(|r| !r.is_empty());
    runs
}

/// Plotters failed to draw (its message).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PlotError(pub String);

type DrawResult<T> = Result<T, PlotError>;

fn err(e: &dyn std::fmt::Display) -> PlotError {
    PlotError(e.to_string())
}

/// The image format of a plot file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// Scalable vector graphics (text stays text).
    Svg,
    /// A bitmap (8-bit RGB PNG) of the same pixel size.
    Png,
}

impl ImageFormat {
    /// The format of `path` by its extension: `.png` is PNG, `.svg`, no
    /// extension and `-` (standard output) are SVG; anything else is an
    /// error.
    pub fn of(path: &Path) -> Result<Self, SinkError> {
        match path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
        {
            Some(e) if e == "png" => Ok(ImageFormat::Png),
            Some(e) if e == "svg" => Ok(ImageFormat::Svg),
            None => Ok(ImageFormat::Svg),
            Some(e) => Err(SinkError::ImageFormat {
                path: path.to_path_buf(),
                extension: e,
            }),
        }
    }
}

/// DejaVu Sans as plotters' `sans-serif` (every text of the plots uses it),
/// registered once per process before anything is drawn.
fn register_fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font is a valid TrueType file; a failure would show
        // as a drawing error naming the missing font.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Something drawn on one canvas: a [`Figure`] or a [`BarChart`].
trait Drawing {
    /// Width and height in pixels.
    fn pixels(&self) -> (u32, u32);

    /// Draws on `root` (white, of [`pixels`](Self::pixels)).
    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<()>;

    fn svg(&self) -> DrawResult<String> {
        register_fonts();
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, self.pixels()).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(&e))?;
            self.draw_on(&root)?;
            root.present().map_err(|e| err(&e))?;
        }
        Ok(svg)
    }

    fn png(&self) -> DrawResult<Vec<u8>> {
        register_fonts();
        let (w, h) = self.pixels();
        let mut rgb = vec![0u8; w as usize * h as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(&e))?;
            self.draw_on(&root)?;
            root.present().map_err(|e| err(&e))?;
        }
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, w, h);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| err(&e))?;
        writer.write_image_data(&rgb).map_err(|e| err(&e))?;
        writer.finish().map_err(|e| err(&e))?;
        Ok(bytes)
    }

    /// Renders to `path` in the format of its extension (through a
    /// temporary file, renamed when complete).
    fn save_as(&self, path: &Path) -> Result<(), SinkError> {
        let plot_err = |e: PlotError| SinkError::Plot {
            path: path.to_path_buf(),
            message: e.0,
        };
        let bytes = match ImageFormat::of(path)? {
            ImageFormat::Svg => self.svg().map_err(plot_err)?.into_bytes(),
            ImageFormat::Png => self.png().map_err(plot_err)?,
        };
        atomic_file::write(path, &bytes).map_err(|e| SinkError::io(path, e))
    }
}

/// Splits `area` into the axes and, if there are series, a legend column
/// right of them, so that the legend never covers data.
fn with_legend_column<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    series: usize,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let (w, _) = area.dim_in_pixel();
    if series > 0 {
        area.split_horizontally(w.saturating_sub(LEGEND_WIDTH))
    } else {
        area.split_horizontally(w)
    }
}

/// Legend entry `k`: a line sample in its colour and the name.
fn draw_legend_entry<DB: DrawingBackend>(
    legend: &DrawingArea<DB, Shift>,
    k: usize,
    name: &str,
) -> DrawResult<()> {
    let color = COLORS[k % COLORS.len()];
    let y = 40 + 20 * k as i32;
    legend
        .draw(&PathElement::new(
            vec![(8, y), (30, y)],
            color.stroke_width(2),
        ))
        .map_err(|e| err(&e))?;
    legend
        .draw(&Text::new(
            name.to_string(),
            (36, y - 7),
            ("sans-serif", 13).into_font(),
        ))
        .map_err(|e| err(&e))?;
    Ok(())
}

fn draw_panel<DB: DrawingBackend, Y>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    x_range: (f64, f64),
    y_range: Y,
) -> DrawResult<()>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let shown = panel.series.len().min(MAX_SERIES_PER_PANEL);
    let (plot_area, legend_area) = with_legend_column(area, shown);
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(&panel.title, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(x_range.0..x_range.1, y_range)
        .map_err(|e| err(&e))?;
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .light_line_style(RGBColor(235, 235, 235));
    if panel.x_integers {
        mesh.x_label_formatter(&integer_label);
    } else {
        mesh.x_label_formatter(&decimal_label);
    }
    if panel.y_integers {
        mesh.y_label_formatter(&integer_label);
    } else if !panel.log_y {
        mesh.y_label_formatter(&decimal_label);
    }
    mesh.draw().map_err(|e| err(&e))?;
    for (k, s) in panel.series.iter().take(shown).enumerate() {
        let color = COLORS[k % COLORS.len()];
        let line = color.stroke_width(2);
        for piece in &s.pieces {
            for run in drawable_runs(piece, panel.log_y) {
                chart
                    .draw_series(LineSeries::new(run.iter().copied(), line))
                    .map_err(|e| err(&e))?;
                if s.markers {
                    chart
                        .draw_series(run.iter().map(|&p| Circle::new(p, 3, color.filled())))
                        .map_err(|e| err(&e))?;
                }
            }
        }
        let jumps = s
            .connectors
            .iter()
            .flat_map(|c| drawable_runs(c, panel.log_y))
            .filter(|r| r.len() == 2);
        chart
            .draw_series(
                jumps.map(|r| DashedPathElement::new(r, 4, 3, color.mix(0.7).stroke_width(1))),
            )
            .map_err(|e| err(&e))?;
        draw_legend_entry(&legend_area, k, &s.name)?;
    }
    Ok(())
}

/// Splits a 3-D piece where a point is not finite.
fn finite_runs_3d(piece: &[Point3]) -> Vec<Vec<Point3>> {
    let mut runs = vec![Vec::new()];
    for &p in piece {
        if p.0.is_finite() && p.1.is_finite() && p.2.is_finite() {
            runs.last_mut().expect("a run exists").push(p);
        } else if !runs.last().expect("a run exists").is_empty() {
            runs.push(Vec::new());
        }
    }
    runs.retain(|r| !r.is_empty());
    runs
}

/// A 3-D panel: t to the right, j into the depth, the value up (HyEQ's
/// `plotHybrid`), axis names written at the ends of the axes.
fn draw_panel_3d<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
) -> DrawResult<()> {
    let shown = &panel.series_3d[..panel.series_3d.len().min(MAX_SERIES_PER_PANEL)];
    let (plot_area, legend_area) = with_legend_column(area, shown.len());
    let points = || shown.iter().flat_map(|s| s.all_points());
    let t = bounds(points().map(|p| p.0), false);
    let j = bounds(points().map(|p| p.1), false);
    let v = bounds(points().map(|p| p.2), false);
    // plotters' 3-D axes: x to the right, y up, z into the depth.
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(&panel.title, ("sans-serif", 16))
        .margin(10)
        .build_cartesian_3d(t.0..t.1, v.0..v.1, j.0..j.1)
        .map_err(|e| err(&e))?;
    // Seen from the front left: t runs to the right along the front edge,
    // j into the depth along the left edge, the value up the right edge.
    chart.with_projection(|mut p| {
        p.yaw = -0.6;
        p.pitch = 0.25;
        p.scale = 0.8;
        p.into_matrix()
    });
    let mut axes = chart.configure_axes();
    axes.light_grid_style(RGBColor(235, 235, 235))
        .max_light_lines(4);
    axes.x_formatter(&decimal_label).y_formatter(&decimal_label);
    if panel.y_integers {
        // The depth axis is j.
        axes.z_formatter(&integer_label);
    }
    axes.draw().map_err(|e| err(&e))?;
    let font = ("sans-serif", 14).into_font();
    let mid = |r: (f64, f64)| (r.0 + r.1) / 2.0;
    // Axis names beside the middle of the edges that carry the tick labels.
    let names = [
        (panel.x_label.as_str(), (mid(t), v.0, j.1), (0, 28)),
        (panel.y_label.as_str(), (t.0, v.0, mid(j)), (-40, 12)),
        (panel.z_label_or_value(), (t.1, v.1, j.1), (8, -26)),
    ];
    for (name, at, offset) in names {
        chart
            .draw_series(std::iter::once(
                EmptyElement::at(at) + Text::new(name.to_string(), offset, font.clone()),
            ))
            .map_err(|e| err(&e))?;
    }
    for (k, s) in shown.iter().enumerate() {
        let color = COLORS[k % COLORS.len()];
        for piece in &s.pieces {
            for run in finite_runs_3d(piece) {
                chart
                    .draw_series(LineSeries::new(
                        run.iter().map(|&(t, j, v)| (t, v, j)),
                        color.stroke_width(2),
                    ))
                    .map_err(|e| err(&e))?;
            }
        }
        let jumps = s
            .connectors
            .iter()
            .flat_map(|c| finite_runs_3d(c))
            .filter(|r| r.len() == 2);
        chart
            .draw_series(jumps.map(|r| {
                DashedPathElement::new(
                    r.into_iter().map(|(t, j, v)| (t, v, j)),
                    4,
                    3,
                    color.mix(0.7).stroke_width(1),
                )
            }))
            .map_err(|e| err(&e))?;
        draw_legend_entry(&legend_area, k, &s.name)?;
    }
    Ok(())
}

impl Panel {
    /// The vertical axis's name of a 3-D panel.
    fn z_label_or_value(&self) -> &str {
        if self.z_label.is_empty() {
            "value"
        } else {
            &self.z_label
        }
    }
}

impl Drawing for Figure {
    fn pixels(&self) -> (u32, u32) {
        (
            self.width,
            self.panel_height * (self.panels.len().max(1) as u32),
        )
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<()> {
        let areas = root.split_evenly((self.panels.len().max(1), 1));
        for (panel, area) in self.panels.iter().zip(&areas) {
            if !panel.series_3d.is_empty() {
                draw_panel_3d(area, panel)?;
                continue;
            }
            let shown = &panel.series[..panel.series.len().min(MAX_SERIES_PER_PANEL)];
            let x_range = bounds(
                shown.iter().flat_map(|s| s.all_points().map(|p| p.0)),
                false,
            );
            let y_range = bounds(
                shown.iter().flat_map(|s| s.all_points().map(|p| p.1)),
                panel.log_y,
            );
            if panel.log_y {
                draw_panel(area, panel, x_range, (y_range.0..y_range.1).log_scale())?;
            } else {
                draw_panel(area, panel, x_range, y_range.0..y_range.1)?;
            }
        }
        Ok(())
    }
}

impl Figure {
    /// An empty figure.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a panel below the others.
    pub fn panel(mut self, panel: Panel) -> Self {
        self.panels.push(panel);
        self
    }

    /// Sets width and per-panel height in pixels.
    pub fn size(self, width: u32, panel_height: u32) -> Self {
        Self {
            width,
            panel_height,
            ..self
        }
    }

    /// Width and height of the whole figure in pixels.
    pub fn pixel_size(&self) -> (u32, u32) {
        self.pixels()
    }

    /// Renders the figure as an SVG document.
    pub fn to_svg_string(&self) -> Result<String, PlotError> {
        self.svg()
    }

    /// Renders the figure as the bytes of a PNG file (8-bit RGB, of
    /// [`pixel_size`](Self::pixel_size)).
    pub fn to_png(&self) -> Result<Vec<u8>, PlotError> {
        self.png()
    }

    /// Renders the figure to `path`, SVG or PNG by its extension
    /// ([`ImageFormat::of`]), through a temporary file renamed when
    /// complete.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), SinkError> {
        self.save_as(path.as_ref())
    }
}

/// Which vector a plotted component comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Source {
    State,
    Output,
}

/// One panel of a [`PlotSink`]: a title and its (label, source, component) series.
#[derive(Debug, Clone)]
struct PanelSpec {
    title: String,
    series: Vec<(String, Source, usize)>,
    total: usize,
}

fn field_components(prefix: &str, f: &Field) -> Vec<(String, usize)> {
    match f.shape {
        Shape::Scalar => vec![(format!("{prefix}{}", f.name), f.offset)],
        Shape::Vector(n) => (0..n)
            .map(|i| (format!("{prefix}{}[{}]", f.name, i + 1), f.offset + i))
            .collect(),
        Shape::Matrix { rows, cols } => (0..rows * cols)
            .map(|k| {
                (
                    format!("{prefix}{}[{},{}]", f.name, k / cols + 1, k % cols + 1),
                    f.offset + k,
                )
            })
            .collect(),
    }
}

/// Panels for one layout entry: one for a field, one per member field for a family.
fn entry_panels(entry: &Entry, source: Source) -> Vec<PanelSpec> {
    let spec = |title: String, comps: Vec<(String, usize)>| PanelSpec {
        title,
        total: comps.len(),
        series: comps
            .into_iter()
            .take(MAX_SERIES_PER_PANEL)
            .map(|(n, k)| (n, source, k))
            .collect(),
    };
    match entry {
        Entry::Field(f) => vec![spec(f.name.clone(), field_components("", f))],
        Entry::Family {
            name,
            labels,
            members,
        } => {
            let fields = members.first().map(Vec::as_slice).unwrap_or(&[]);
            fields
                .iter()
                .enumerate()
                .map(|(k, field)| {
                    let comps = labels
                        .iter()
                        .zip(members)
                        .filter_map(|(label, m)| m.get(k).map(|f| (label, f)))
                        .flat_map(|(label, f)| {
                            field_components(&crate::layout::member_prefix(name, label, f), f)
                        })
                        .collect();
                    let title = if field.name.is_empty() {
                        format!("{name}[·]")
                    } else {
                        format!("{name}[·].{}", field.name)
                    };
                    spec(title, comps)
                })
                .collect()
        }
    }
}

/// The position and flat (CSV) name of the component of `layout` named
/// `name`, spaces ignored (`P[1, 2]` is `P[1,2]`).
fn component(layout: &Layout, name: &str) -> Option<(usize, String)> {
    let name: String = name.chars().filter(|c| !c.is_whitespace()).collect();
    layout.components().into_iter().find(|(_, n)| *n == name)
}

/// A panel of one component (`x[2]`, from [`component`]), titled by its name.
fn component_panel((k, name): (usize, String), source: Source) -> PanelSpec {
    PanelSpec {
        title: name.clone(),
        series: vec![(name, source, k)],
        total: 1,
    }
}

/// What a [`PlotSink`] draws: the plot kinds of the HyEQ Toolbox.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum PlotKind {
    /// Each component against t (`plotFlows`): flows solid, jumps dashed.
    #[default]
    Flows,
    /// Each component against j (`plotJumps`): the values of the flow at
    /// each j on the vertical through j, jumps dashed from j to j + 1.
    Jumps,
    /// A phase plot (`plotHarc`): of two selected components, the second
    /// against the first; of three or more, the first three in 3-D (the
    /// first to the right, the second into the depth, the third up). Flows
    /// solid, jumps dashed.
    Phase,
    /// The hybrid time domain: j against t, flows horizontal, jumps dashed.
    Domain,
    /// Each component over the hybrid time domain (`plotHybrid`): 3-D axes
    /// t, j and the value, one panel per entry, flows solid in their plane
    /// j, jumps dashed from (t, j) to (t, j + 1).
    Hybrid,
}

impl PlotKind {
    /// The kind's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            PlotKind::Flows => "flows",
            PlotKind::Jumps => "jumps",
            PlotKind::Phase => "phase",
            PlotKind::Domain => "domain",
            PlotKind::Hybrid => "hybrid",
        }
    }
}

/// [`PlotKind::Phase`] needs two components, the other kinds but
/// [`PlotKind::Domain`] one: without it they would draw an empty image.
fn check_kind(kind: PlotKind, components: usize) -> Result<(), SinkError> {
    let needed = match kind {
        PlotKind::Phase => (2, "two components"),
        PlotKind::Domain => (0, "no component"),
        PlotKind::Flows | PlotKind::Jumps | PlotKind::Hybrid => (1, "a component"),
    };
    if components < needed.0 {
        return Err(SinkError::TooFewComponents {
            kind: kind.name(),
            needed: needed.1,
            selected: components,
        });
    }
    Ok(())
}

/// The entries drawn when no selection is given: the first
/// [`MAX_DEFAULT_PANELS`] state entries or, of a log that holds no state
/// (`--log-vars energy`), of its outputs.
fn default_entries(info: &RunInfo, with_outputs: bool) -> Vec<(&Entry, Source)> {
    let (layout, source) = match info.state_layout.entries.is_empty() && with_outputs {
        false => (&info.state_layout, Source::State),
        true => (&info.output_layout, Source::Output),
    };
    let entries = layout.entries.iter().take(MAX_DEFAULT_PANELS);
    entries.map(|e| (e, source)).collect()
}

/// Keeps the selected states and outputs of a run and draws them (against
/// t by default, see [`PlotKind`]) when [`finish`](Self::finish)ed.
pub struct PlotSink<'a> {
    kind: PlotKind,
    path: PathBuf,
    /// Evaluates the outputs of a live run (`None` when fed from a log,
    /// whose samples carry their outputs).
    outputs: Option<OutputFn<'a>>,
    panels: Vec<PanelSpec>,
    model_name: String,
    decimator: Decimator,
    times: Vec<HybridTime>,
    /// Whether sample k may be thinned (a flow sample).
    thinnable: Vec<bool>,
    /// Row-major: one row per kept sample, one column per plotted component.
    values: Vec<f64>,
    columns: Vec<(Source, usize)>,
    y: Vec<f64>,
}

/// A [`PlotSink`] keeps between this many and twice this many samples: when
/// it holds twice as many, it drops every other flow sample (initial,
/// jump and final samples stay), so long runs draw in bounded memory and
/// the SVG stays small.
pub const MAX_PLOT_SAMPLES: usize = 4000;

/// At most this many panels are drawn when no selection is given.
pub const MAX_DEFAULT_PANELS: usize = 8;

impl<'a> PlotSink<'a> {
    /// A plot of the entries named in `select` (state or output entries, in
    /// that order of lookup), or of the first [`MAX_DEFAULT_PANELS`] state
    /// entries if `select` is empty (output entries if there is no state:
    /// a log may hold outputs only).
    pub fn new(
        path: impl AsRef<Path>,
        info: &RunInfo,
        outputs: Option<OutputFn<'a>>,
        select: &[String],
        decimation: Decimation,
    ) -> Result<Self, SinkError> {
        let with_outputs = outputs.is_some();
        Self::build(path, info, outputs, with_outputs, select, decimation)
    }

    /// A plot fed from a logged run ([`push_logged`](Self::push_logged),
    /// e.g. by [`super::mcap_read::RunLog::replay`]): `info` describes the
    /// log (its layouts are those of the logged states and outputs), each
    /// sample comes with its outputs, and every sample is kept (the log was
    /// decimated when it was written). Selection as in [`new`](Self::new).
    pub fn for_log(
        path: impl AsRef<Path>,
        info: &RunInfo,
        select: &[String],
    ) -> Result<PlotSink<'static>, SinkError> {
        PlotSink::build(path, info, None, true, select, Decimation::all())
    }

    fn build(
        path: impl AsRef<Path>,
        info: &RunInfo,
        outputs: Option<OutputFn<'a>>,
        with_outputs: bool,
        select: &[String],
        decimation: Decimation,
    ) -> Result<Self, SinkError> {
        ImageFormat::of(path.as_ref())?;
        info.validate()?;
        decimation.validate()?;
        let mut panels = Vec::new();
        let outputs_known = info.output_dim > 0 && with_outputs;
        if select.is_empty() {
            for (e, source) in default_entries(info, outputs_known) {
                panels.extend(entry_panels(e, source));
            }
        }
        for name in select {
            // An entry, or all of a subsystem instance's (states, then outputs).
            let states = info.state_layout.find_all(name);
            let outputs = match outputs_known {
                true => info.output_layout.find_all(name),
                false => Vec::new(),
            };
            if !states.is_empty() || !outputs.is_empty() {
                for e in &states {
                    panels.extend(entry_panels(e, Source::State));
                }
                for e in &outputs {
                    panels.extend(entry_panels(e, Source::Output));
                }
            } else if let Some(c) = component(&info.state_layout, name) {
                panels.push(component_panel(c, Source::State));
            } else if let (Some(c), true) = (component(&info.output_layout, name), outputs_known) {
                panels.push(component_panel(c, Source::Output));
            } else {
                let mut known = entry_names(&info.state_layout);
                known.extend(entry_names(&info.output_layout));
                return Err(SinkError::UnknownSignal {
                    name: name.clone(),
                    known: known.join(", "),
                });
            }
        }
        let columns = panels
            .iter()
            .flat_map(|p| p.series.iter().map(|&(_, s, k)| (s, k)))
            .collect();
        Ok(Self {
            kind: PlotKind::Flows,
            path: path.as_ref().to_path_buf(),
            outputs,
            panels,
            model_name: info.model_name.clone(),
            decimator: Decimator::new(decimation),
            times: Vec::new(),
            thinnable: Vec::new(),
            values: Vec::new(),
            columns,
            y: vec![0.0; info.output_dim],
        })
    }

    /// Draws `kind` instead of flows. [`PlotKind::Phase`] needs two
    /// selected components (the first two are drawn).
    pub fn kind(mut self, kind: PlotKind) -> Result<Self, SinkError> {
        check_kind(kind, self.columns.len())?;
        self.kind = kind;
        Ok(self)
    }

    /// Whether `kind` can draw the selection `select` of a run described by
    /// `info` (as [`PlotSink::new`] would select), before anything runs.
    pub fn check_selection(
        info: &RunInfo,
        select: &[String],
        kind: PlotKind,
    ) -> Result<(), SinkError> {
        let count = |e: &Entry| -> usize {
            entry_panels(e, Source::State)
                .iter()
                .map(|p| p.series.len())
                .sum()
        };
        let components: usize = if select.is_empty() {
            let entries = default_entries(info, info.output_dim > 0);
            entries.into_iter().map(|(e, _)| count(e)).sum()
        } else {
            select
                .iter()
                .map(|n| {
                    let mut entries = info.state_layout.find_all(n);
                    entries.extend(info.output_layout.find_all(n));
                    match entries.is_empty() {
                        false => entries.iter().map(count).sum(),
                        true => usize::from(PlotSink::selects(info, n)),
                    }
                })
                .sum()
        };
        check_kind(kind, components)
    }

    /// Whether `name` selects something to draw of a run described by
    /// `info`: a state or output entry, a family member (`xh[2]`), or one
    /// component named as in CSV (`x[2]`, `P[1,2]`, `xh[2][1]`,
    /// `agent[3].xhat[1]`).
    pub fn selects(info: &RunInfo, name: &str) -> bool {
        [&info.state_layout, &info.output_layout]
            .iter()
            .any(|l| !l.find_all(name).is_empty() || component(l, name).is_some())
    }

    /// Keeps one sample: `x` the state, `y` the outputs (read only if an
    /// output is plotted).
    fn store(&mut self, at: HybridTime, kind: SampleKind, x: &[f64], y: &[f64]) {
        if self.times.len() >= 2 * MAX_PLOT_SAMPLES {
            self.thin();
        }
        self.times.push(at);
        self.thinnable.push(kind == SampleKind::Flow);
        for &(source, k) in &self.columns {
            self.values.push(match source {
                Source::State => x[k],
                Source::Output => y[k],
            });
        }
    }

    /// A logged sample: state `x` and outputs `y` (as long as the log's
    /// state and output dimensions) at `at`, of kind `kind`.
    pub fn push_logged(&mut self, at: HybridTime, kind: SampleKind, x: &[f64], y: &[f64]) {
        if self.decimator.keep(at, kind) {
            self.store(at, kind, x, y);
        }
    }

    /// Drops every other flow sample; when jump samples are most of what is
    /// kept (a discrete-time system), every other sample of any kind but the
    /// first, so that drawing stays bounded for any number of jumps.
    fn thin(&mut self) {
        let ncols = self.columns.len();
        let flows = self.thinnable.iter().filter(|&&f| f).count();
        let any_kind = flows < self.times.len() / 2;
        let mut keep_flow = false;
        let mut w = 0;
        for r in 0..self.times.len() {
            let keep = if r > 0 && (any_kind || self.thinnable[r]) {
                keep_flow = !keep_flow;
                keep_flow
            } else {
                true
            };
            if keep {
                self.times[w] = self.times[r];
                self.thinnable[w] = self.thinnable[r];
                self.values
                    .copy_within(r * ncols..(r + 1) * ncols, w * ncols);
                w += 1;
            }
        }
        self.times.truncate(w);
        self.thinnable.truncate(w);
        self.values.truncate(w * ncols);
    }

    /// Number of samples held.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether no sample is held.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }

    /// The values kept of plotted column `col`, with their hybrid times.
    fn column(&self, col: usize) -> impl Iterator<Item = (HybridTime, f64)> + '_ {
        let ncols = self.columns.len();
        self.times
            .iter()
            .enumerate()
            .map(move |(r, &at)| (at, self.values[r * ncols + col]))
    }

    /// The figure of what was kept so far.
    pub fn figure(&self) -> Figure {
        match self.kind {
            PlotKind::Flows | PlotKind::Jumps => self.component_figure(),
            PlotKind::Hybrid => self.hybrid_figure(),
            PlotKind::Phase => {
                let labels: Vec<&String> = self
                    .panels
                    .iter()
                    .flat_map(|p| p.series.iter().map(|(l, _, _)| l))
                    .collect();
                if labels.len() >= 3 {
                    let points: Vec<(HybridTime, Point3)> = self
                        .column(0)
                        .zip(self.column(1))
                        .zip(self.column(2))
                        .map(|(((at, a), (_, b)), (_, c))| (at, (a, b, c)))
                        .collect();
                    let name = format!("({}, {}, {})", labels[0], labels[1], labels[2]);
                    return Figure::new().size(900, 600).panel(
                        Panel::new(format!("{}: {name}", self.model_name))
                            .x_label(labels[0].as_str())
                            .y_label(labels[1].as_str())
                            .z_label(labels[2].as_str())
                            .series_3d(Series3::hybrid_points(name, &points)),
                    );
                }
                let points: Vec<(HybridTime, (f64, f64))> = self
                    .column(0)
                    .zip(self.column(1))
                    .map(|((at, a), (_, b))| (at, (a, b)))
                    .collect();
                let name = format!("{} vs {}", labels[1], labels[0]);
                Figure::new().size(900, 600).panel(
                    Panel::new(format!("{}: {name}", self.model_name))
                        .x_label(labels[0].as_str())
                        .y_label(labels[1].as_str())
                        .series(Series::hybrid_points(name, &points)),
                )
            }
            PlotKind::Domain => {
                let points: Vec<(HybridTime, (f64, f64))> = self
                    .times
                    .iter()
                    .map(|&at| (at, (at.t, at.j as f64)))
                    .collect();
                Figure::new().panel(
                    Panel::new(format!("{}: hybrid time domain", self.model_name))
                        .x_label("t")
                        .y_label("j")
                        .y_integers(true)
                        .series(Series::hybrid_points("(t, j)", &points)),
                )
            }
        }
    }

    /// One panel per selected entry, each component against t or j.
    fn component_figure(&self) -> Figure {
        let over_j = self.kind == PlotKind::Jumps;
        let mut col = 0;
        let mut figure = Figure::new();
        for spec in &self.panels {
            let mut title = format!("{}: {}", self.model_name, spec.title);
            if spec.total > spec.series.len() {
                title.push_str(&format!(
                    " (first {} of {} components)",
                    spec.series.len(),
                    spec.total
                ));
            }
            let mut panel = Panel::new(title)
                .x_label(if over_j { "j" } else { "t" })
                .x_integers(over_j);
            for (label, _, _) in &spec.series {
                let points: Vec<(HybridTime, (f64, f64))> = self
                    .column(col)
                    .map(|(at, v)| (at, (if over_j { at.j as f64 } else { at.t }, v)))
                    .collect();
                let series = Series::hybrid_points(label.clone(), &points);
                // HyEQ marks the values at each j; only while that stays legible.
                let markers = over_j && points.len() <= 2 * MAX_DASHED_JUMPS;
                panel = panel.series(series.markers(markers));
                col += 1;
            }
            figure = figure.panel(panel);
        }
        figure
    }

    /// One 3-D panel per selected entry, each component over (t, j).
    fn hybrid_figure(&self) -> Figure {
        let mut col = 0;
        let mut figure = Figure::new().size(900, 460);
        for spec in &self.panels {
            let mut panel = Panel::new(format!("{}: {}", self.model_name, spec.title))
                .x_label("t")
                .y_label("j")
                .y_integers(true)
                .z_label(spec.title.as_str());
            for (label, _, _) in &spec.series {
                let samples: Vec<(HybridTime, f64)> = self.column(col).collect();
                panel = panel.series_3d(Series3::hybrid(label.clone(), &samples));
                col += 1;
            }
            figure = figure.panel(panel);
        }
        figure
    }

    /// Draws the figure to the file.
    pub fn finish(self) -> Result<PathBuf, SinkError> {
        self.figure().save(&self.path)?;
        Ok(self.path)
    }
}

impl ArcSink for PlotSink<'_> {
    fn sample(&mut self, at: HybridTime, x: &[f64], kind: SampleKind) -> ControlFlow<()> {
        if !self.decimator.keep(at, kind) {
            return ControlFlow::Continue(());
        }
        let mut y = std::mem::take(&mut self.y);
        if let Some(outputs) = self.outputs
            && self.columns.iter().any(|c| c.0 == Source::Output)
        {
            outputs.eval(at, x, &mut y);
        }
        self.store(at, kind, x, &y);
        self.y = y;
        ControlFlow::Continue(())
    }

    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }
}

/// One bar of a [`BarChart`]: a category, its value and an optional error
/// half-width (drawn as `value ± error`; 0 draws no error bar).
#[derive(Debug, Clone, PartialEq)]
pub struct Bar {
    /// Category label under the bar.
    pub label: String,
    /// Height of the bar.
    pub value: f64,
    /// Half-width of the error bar (e.g. a standard deviation).
    pub error: f64,
}

/// A bar chart with error bars, e.g. a statistic per agent with its spread
/// over seeds:
///
/// ```
/// use hybsim::sinks::plot::{Bar, BarChart};
/// let bars = (1..=5).map(|i| Bar { label: i.to_string(), value: 1.0 / i as f64, error: 0.05 }).collect();
/// let svg = BarChart::new("rate per agent", bars).y_label("rate").to_svg_string().unwrap();
/// assert!(svg.starts_with("<svg"));
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct BarChart {
    /// Caption above the axes.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// The bars, left to right.
    pub bars: Vec<Bar>,
    /// Width and height in pixels. Default 900 × 400.
    pub size: (u32, u32),
}

impl BarChart {
    /// A chart of `bars` with a caption.
    pub fn new(title: impl Into<String>, bars: Vec<Bar>) -> Self {
        Self {
            title: title.into(),
            x_label: String::new(),
            y_label: String::new(),
            bars,
            size: (900, 400),
        }
    }

    /// Sets the x label.
    pub fn x_label(self, x_label: impl Into<String>) -> Self {
        Self {
            x_label: x_label.into(),
            ..self
        }
    }

    /// Sets the y label.
    pub fn y_label(self, y_label: impl Into<String>) -> Self {
        Self {
            y_label: y_label.into(),
            ..self
        }
    }

    /// Renders the chart as an SVG document. Bars with a non-finite value
    /// are left out (their label stays).
    pub fn to_svg_string(&self) -> Result<String, PlotError> {
        self.svg()
    }

    /// Renders the chart as the bytes of a PNG file.
    pub fn to_png(&self) -> Result<Vec<u8>, PlotError> {
        self.png()
    }

    /// Renders the chart to `path`, SVG or PNG by its extension (through a
    /// temporary file).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), SinkError> {
        self.save_as(path.as_ref())
    }
}

impl Drawing for BarChart {
    fn pixels(&self) -> (u32, u32) {
        self.size
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<()> {
        let finite = |b: &&Bar| b.value.is_finite();
        let top = self
            .bars
            .iter()
            .filter(finite)
            .map(|b| b.value + b.error.max(0.0))
            .fold(0.0_f64, f64::max);
        let bottom = self
            .bars
            .iter()
            .filter(finite)
            .map(|b| b.value.min(b.value - b.error.max(0.0)))
            .fold(0.0_f64, f64::min);
        let (lo, hi) = bounds([bottom, top].into_iter(), false);
        // Bars at x = 1, 2, …, n; the y axis starts at 0 unless values are negative.
        let lo = if bottom >= 0.0 { 0.0 } else { lo };
        let n = self.bars.len();
        {
            let labels: Vec<String> = self.bars.iter().map(|b| b.label.clone()).collect();
            let label_of = move |x: &f64| {
                let k = x.round();
                if (x - k).abs() < 1e-6 && k >= 1.0 && k as usize <= labels.len() {
                    labels[k as usize - 1].clone()
                } else {
                    String::new()
                }
            };
            let mut chart = ChartBuilder::on(root)
                .caption(&self.title, ("sans-serif", 16))
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(70)
                .build_cartesian_2d(0.4..n as f64 + 0.6, lo..hi)
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc(self.x_label.as_str())
                .y_desc(self.y_label.as_str())
                .x_labels(n + 1)
                .x_label_formatter(&label_of)
                .disable_x_mesh()
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(|e| err(&e))?;
            let color = COLORS[0];
            let bars = self.bars.iter().enumerate().filter(|(_, b)| finite(b));
            chart
                .draw_series(bars.clone().map(|(i, b)| {
                    let x = (i + 1) as f64;
                    Rectangle::new([(x - 0.35, 0.0), (x + 0.35, b.value)], color.filled())
                }))
                .map_err(|e| err(&e))?;
            let whisker = BLACK.stroke_width(1);
            for (i, b) in bars.filter(|(_, b)| b.error > 0.0 && b.error.is_finite()) {
                let x = (i + 1) as f64;
                let (y0, y1) = (b.value - b.error, b.value + b.error);
                let paths = [
                    vec![(x, y0), (x, y1)],
                    vec![(x - 0.12, y0), (x + 0.12, y0)],
                    vec![(x - 0.12, y1), (x + 0.12, y1)],
                ];
                chart
                    .draw_series(paths.into_iter().map(|p| PathElement::new(p, whisker)))
                    .map_err(|e| err(&e))?;
            }
        }
        Ok(())
    }
}
