//! The report's PNG charts (plotters, bitmap backend, the Hack font from
//! `epaint_default_fonts` so no system font is needed).

use std::path::Path;
use std::sync::Once;

use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;

use super::Res;

const FONT: &str = "sans-serif";

fn register_font() -> Res<()> {
    static ONCE: Once = Once::new();
    let mut result = Ok(());
    ONCE.call_once(|| {
        result = plotters::style::register_font(
            FONT,
            FontStyle::Normal,
            epaint_default_fonts::HACK_REGULAR,
        )
        .map_err(|_| "the bundled Hack font could not be read");
    });
    Ok(result?)
}

/// A named series of points, drawn as a line, as markers, or both.
pub(super) struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub line: bool,
    pub markers: bool,
}

/// An axis: its description and whether it is logarithmic.
pub(super) struct Axis<'a> {
    pub desc: &'a str,
    pub log: bool,
}

/// A compact tick label: no more digits than the value's size needs.
fn tick(v: &f64) -> String {
    let a = v.abs();
    if a >= 100.0 || a == 0.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.1}")
    } else if a >= 0.01 {
        format!("{v:.2}")
    } else {
        format!("{v:.1e}")
    }
}

fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { (0.1, 10.0) } else { (0.0, 1.0) };
    }
    if log {
        (lo / 1.5, hi * 1.5)
    } else {
        let pad = 0.05 * (hi - lo).max(hi.abs() * 0.1).max(1e-12);
        (if lo >= 0.0 { 0.0 } else { lo - pad }, hi + pad)
    }
}

/// Draws `series` into a PNG at `path` (900 x 600).
pub(super) fn chart(
    path: &Path,
    title: &str,
    x: Axis<'_>,
    y: Axis<'_>,
    series: &[Series],
) -> Res<()> {
    register_font()?;
    let xs = range(
        series.iter().flat_map(|s| s.points.iter().map(|p| p.0)),
        x.log,
    );
    let ys = range(
        series.iter().flat_map(|s| s.points.iter().map(|p| p.1)),
        y.log,
    );
    match (x.log, y.log) {
        (false, false) => draw(path, title, &x, &y, xs.0..xs.1, ys.0..ys.1, series),
        (true, false) => draw(
            path,
            title,
            &x,
            &y,
            (xs.0..xs.1).log_scale(),
            ys.0..ys.1,
            series,
        ),
        (false, true) => draw(
            path,
            title,
            &x,
            &y,
            xs.0..xs.1,
            (ys.0..ys.1).log_scale(),
            series,
        ),
        (true, true) => draw(
            path,
            title,
            &x,
            &y,
            (xs.0..xs.1).log_scale(),
            (ys.0..ys.1).log_scale(),
            series,
        ),
    }
}

fn draw<X, Y>(
    path: &Path,
    title: &str,
    x: &Axis<'_>,
    y: &Axis<'_>,
    xr: X,
    yr: Y,
    series: &[Series],
) -> Res<()>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let root = BitMapBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut c = ChartBuilder::on(&root)
        .caption(title, (FONT, 22))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(xr, yr)
        .map_err(|e| err(&e))?;
    c.configure_mesh()
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .x_desc(x.desc)
        .y_desc(y.desc)
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 16))
        .draw()
        .map_err(|e| err(&e))?;
    for (i, s) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|(a, b)| {
                a.is_finite() && b.is_finite() && (!x.log || *a > 0.0) && (!y.log || *b > 0.0)
            })
            .collect();
        if s.line {
            c.draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label(&s.name)
                .legend(move |(a, b)| {
                    PathElement::new(vec![(a, b), (a + 20, b)], color.stroke_width(2))
                });
        }
        if s.markers {
            let drawn = c
                .draw_series(pts.iter().map(|&p| Circle::new(p, 5, color.filled())))
                .map_err(|e| err(&e))?;
            if !s.line {
                drawn
                    .label(&s.name)
                    .legend(move |(a, b)| Circle::new((a + 10, b), 5, color.filled()));
            }
        }
    }
    c.configure_series_labels()
        .label_font((FONT, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
