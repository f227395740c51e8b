//! Minimal SVG charts for reports: line series on linear or logarithmic axes, with
//! ticks, grid and legend. Self-contained (no font or drawing dependencies): the text is
//! SVG `<text>` rendered by whatever displays the file.

use std::fmt::Write as _;

/// Colours for successive series.
pub const PALETTE: [&str; 8] =
    ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"];

/// One line (and/or markers).
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Abscissae.
    pub x: Vec<f64>,
    /// Ordinates.
    pub y: Vec<f64>,
    /// Stroke colour.
    pub color: String,
    /// Dashed line.
    pub dashed: bool,
    /// Draw a marker at each point.
    pub markers: bool,
    /// Draw the line.
    pub line: bool,
}

impl Series {
    /// A solid line in the `i`-th palette colour.
    pub fn line(label: impl Into<String>, x: Vec<f64>, y: Vec<f64>, i: usize) -> Self {
        Self {
            label: label.into(),
            x,
            y,
            color: PALETTE[i % PALETTE.len()].into(),
            dashed: false,
            markers: false,
            line: true,
        }
    }

    /// Line with markers.
    pub fn points(mut self) -> Self {
        self.markers = true;
        self
    }

    /// Dashed.
    pub fn dashed(mut self) -> Self {
        self.dashed = true;
        self
    }

    /// Markers only.
    pub fn scatter(mut self) -> Self {
        self.markers = true;
        self.line = false;
        self
    }
}

/// A chart.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Title above the plot.
    pub title: String,
    /// X-axis label.
    pub x_label: String,
    /// Y-axis label.
    pub y_label: String,
    /// The series.
    pub series: Vec<Series>,
    /// Logarithmic y axis (non-positive values are left out).
    pub log_y: bool,
    /// Fixed x range.
    pub x_range: Option<(f64, f64)>,
    /// Fixed y range.
    pub y_range: Option<(f64, f64)>,
    /// Size in pixels.
    pub size: (f64, f64),
}

impl Chart {
    /// An empty chart.
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            series: vec![],
            log_y: false,
            x_range: None,
            y_range: None,
            size: (760.0, 420.0),
        }
    }

    /// Adds a series.
    pub fn with(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }

    /// Logarithmic y axis.
    pub fn log_y(mut self) -> Self {
        self.log_y = true;
        self
    }

    fn ty(&self, v: f64) -> Option<f64> {
        if !v.is_finite() {
            return None;
        }
        if self.log_y { if v > 0.0 { Some(v.log10()) } else { None } } else { Some(v) }
    }

    /// The chart as an SVG document.
    pub fn to_svg(&self) -> String {
        let (w, h) = self.size;
        let (ml, mr, mt, mb) = (72.0, 20.0, 36.0, 52.0);
        let (pw, ph) = (w - ml - mr, h - mt - mb);
        let mut xs = vec![];
        let mut ys = vec![];
        for s in &self.series {
            for (&x, &y) in s.x.iter().zip(&s.y) {
                if let (true, Some(ty)) = (x.is_finite(), self.ty(y)) {
                    xs.push(x);
                    ys.push(ty);
                }
            }
        }
        let span = |v: &[f64]| {
            let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            if !lo.is_finite() {
                (0.0, 1.0)
            } else if hi - lo <= 0.0 {
                (lo - 0.5, hi + 0.5)
            } else {
                (lo, hi)
            }
        };
        let (x0, x1) = self.x_range.unwrap_or_else(|| span(&xs));
        let (y0, y1) = match self.y_range {
            Some((a, b)) if self.log_y => (a.max(1e-300).log10(), b.max(1e-300).log10()),
            Some(r) => r,
            None => {
                let (a, b) = span(&ys);
                if self.log_y {
                    (a.floor(), b.ceil())
                } else {
                    let m = 0.05 * (b - a);
                    (a - m, b + m)
                }
            }
        };
        let px = |x: f64| ml + (x - x0) / (x1 - x0) * pw;
        let py = |y: f64| mt + ph - (y - y0) / (y1 - y0) * ph;
        let mut out = String::new();
        let _ = write!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
        );
        let _ = write!(out, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        let _ = write!(
            out,
            r#"<text x="{}" y="22" text-anchor="middle" font-size="14">{}</text>"#,
            w / 2.0,
            esc(&self.title)
        );
        // Grid and ticks.
        for t in nice_ticks(x0, x1, 8) {
            let x = px(t);
            let _ = write!(
                out,
                r##"<line x1="{x:.1}" y1="{mt}" x2="{x:.1}" y2="{:.1}" stroke="#e5e5e5"/>"##,
                mt + ph
            );
            let _ = write!(
                out,
                r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
                mt + ph + 16.0,
                fmt_tick(t)
            );
        }
        let yticks = if self.log_y {
            (y0.ceil() as i64..=y1.floor() as i64).map(|e| e as f64).collect()
        } else {
            nice_ticks(y0, y1, 6)
        };
        for t in yticks {
            let y = py(t);
            let _ = write!(
                out,
                r##"<line x1="{ml}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#e5e5e5"/>"##,
                ml + pw
            );
            let label = if self.log_y { format!("1e{}", t as i64) } else { fmt_tick(t) };
            let _ = write!(
                out,
                r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{label}</text>"#,
                ml - 6.0,
                y + 4.0
            );
        }
        let _ = write!(
            out,
            r##"<rect x="{ml}" y="{mt}" width="{pw}" height="{ph}" fill="none" stroke="#333"/>"##
        );
        let _ = write!(
            out,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            ml + pw / 2.0,
            h - 12.0,
            esc(&self.x_label)
        );
        let _ = write!(
            out,
            r#"<text x="16" y="{:.1}" text-anchor="middle" transform="rotate(-90 16 {:.1})">{}</text>"#,
            mt + ph / 2.0,
            mt + ph / 2.0,
            esc(&self.y_label)
        );
        let _ = write!(
            out,
            r#"<clipPath id="plot"><rect x="{ml}" y="{mt}" width="{pw}" height="{ph}"/></clipPath><g clip-path="url(#plot)">"#
        );
        for s in &self.series {
            // Invalid points (NaN, or ≤ 0 on a log axis) break the line.
            let pts: Vec<Option<(f64, f64)>> =
                s.x.iter()
                    .zip(&s.y)
                    .map(|(&x, &y)| if x.is_finite() { self.ty(y).map(|ty| (px(x), py(ty))) } else { None })
                    .collect();
            if s.line {
                let mut d = String::with_capacity(pts.len() * 14);
                let mut pen_down = false;
                for p in &pts {
                    match p {
                        Some((x, y)) => {
                            let _ = write!(d, "{}{x:.1},{y:.1}", if pen_down { "L" } else { "M" });
                            pen_down = true;
                        }
                        None => pen_down = false,
                    }
                }
                if d.contains('L') {
                    let dash = if s.dashed { r#" stroke-dasharray="6,4""# } else { "" };
                    let _ = write!(
                        out,
                        r#"<path d="{d}" fill="none" stroke="{}" stroke-width="1.4"{dash}/>"#,
                        s.color
                    );
                }
            }
            if s.markers {
                for (x, y) in pts.iter().flatten() {
                    let _ = write!(out, r#"<circle cx="{x:.1}" cy="{y:.1}" r="2.6" fill="{}"/>"#, s.color);
                }
            }
        }
        out.push_str("</g>");
        // Legend.
        let mut ly = mt + 14.0;
        for s in self.series.iter().filter(|s| !s.label.is_empty()) {
            let lx = ml + pw - 190.0;
            let dash = if s.dashed { r#" stroke-dasharray="6,4""# } else { "" };
            let _ = write!(
                out,
                r#"<line x1="{lx}" y1="{:.1}" x2="{}" y2="{:.1}" stroke="{}" stroke-width="2"{dash}/>"#,
                ly - 4.0,
                lx + 22.0,
                ly - 4.0,
                s.color
            );
            let _ = write!(out, r#"<text x="{}" y="{ly:.1}">{}</text>"#, lx + 28.0, esc(&s.label));
            ly += 16.0;
        }
        out.push_str("</svg>\n");
        out
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

fn fmt_tick(t: f64) -> String {
    if t == 0.0 {
        "0".into()
    } else if t.abs() >= 1e4 || t.abs() < 1e-3 {
        format!("{t:.1e}")
    } else {
        let s = format!("{t:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Round tick values spanning `[lo, hi]`, about `n` of them.
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !lo.is_finite() || !hi.is_finite() || hi <= lo {
        return vec![];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|i| i as f64 * step).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(nice_ticks(0.0, 50.0, 5), vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0]);
        let t = nice_ticks(-0.37, 0.42, 6);
        assert!(t.iter().all(|v| ((v * 10.0).round() - v * 10.0).abs() < 1e-9));
        assert!(nice_ticks(1.0, 1.0, 5).is_empty());
    }

    #[test]
    fn svg_has_every_series_and_skips_bad_points() {
        let c = Chart::new("t <x>", "f (Hz)", "rms (µm)")
            .with(Series::line("a", vec![1.0, 2.0, 3.0, 4.0], vec![1.0, f64::NAN, 3.0, 4.0], 0))
            .with(Series::line("b", vec![1.0, 2.0], vec![0.0, 2.0], 1).dashed().points())
            .log_y();
        let svg = c.to_svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("t &lt;x&gt;"));
        // a breaks at its NaN: one path with two pen-down moves; b has one valid point: no line.
        assert_eq!(svg.matches("<path").count(), 1);
        let path = &svg[svg.find("<path d=\"").unwrap()..];
        let d = &path[9..path[9..].find('"').unwrap() + 9];
        assert_eq!(d.matches('M').count(), 2, "{d}");
        // b's zero is left out on the log axis: one marker.
        assert_eq!(svg.matches("<circle").count(), 1);
        assert!(!svg.contains("NaN"));
    }
}
