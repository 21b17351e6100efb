//! Inline SVG bar charts (histograms against a law's density, coverage bands), drawn by the
//! `chart.svg` template: plain shapes and text, no script, so the page works anywhere.

use askama::Template;

const WIDTH: f64 = 420.0;
const HEIGHT: f64 = 230.0;
const LEFT: f64 = 52.0;
const RIGHT: f64 = 12.0;
const TOP: f64 = 8.0;
const BOTTOM: f64 = 38.0;

/// Two decimals are plenty for SVG coordinates and keep the page small.
fn r2(v: f64) -> f64 {
    (v * 100.0).round() / 100.0
}

/// A short label for an axis value.
pub fn short(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-4..1e5).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 10.0 {
        format!("{v:.0}")
    } else {
        // Two significant digits.
        let decimals = (1.0 - a.log10().floor()).max(0.0) as usize;
        format!("{v:.decimals$}")
    }
}

pub struct Bar {
    pub x: f64,
    pub y: f64,
    pub w: f64,
    pub h: f64,
    pub fill: &'static str,
    pub label: String,
}

pub struct Tick {
    pub pos: f64,
    pub label: String,
}

#[derive(Template)]
#[template(path = "chart.svg", escape = "html")]
pub struct BarChart {
    width: f64,
    height: f64,
    left: f64,
    top: f64,
    plot_w: f64,
    plot_h: f64,
    axis_y: f64,
    title: String,
    x_label: String,
    legend: String,
    bars: Vec<Bar>,
    curve: String,
    x_ticks: Vec<Tick>,
    y_ticks: Vec<Tick>,
    x_range: (f64, f64),
    y_max: f64,
}

impl BarChart {
    /// An empty chart over `x_range` with values up to `y_max`.
    pub fn new(title: &str, x_label: &str, x_range: (f64, f64), y_max: f64) -> Self {
        let (plot_w, plot_h) = (WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM);
        let y_max = if y_max > 0.0 && y_max.is_finite() {
            y_max * 1.05
        } else {
            1.0
        };
        let mut chart = Self {
            width: WIDTH,
            height: HEIGHT,
            left: LEFT,
            top: TOP,
            plot_w,
            plot_h,
            axis_y: TOP + plot_h,
            title: title.into(),
            x_label: x_label.into(),
            legend: String::new(),
            bars: Vec::new(),
            curve: String::new(),
            x_ticks: Vec::new(),
            y_ticks: Vec::new(),
            x_range,
            y_max,
        };
        for k in 0..=4 {
            let f = k as f64 / 4.0;
            let xv = x_range.0 + f * (x_range.1 - x_range.0);
            chart.x_ticks.push(Tick {
                pos: r2(chart.px(xv)),
                label: short(xv),
            });
            chart.y_ticks.push(Tick {
                pos: r2(chart.py(f * y_max)),
                label: short(f * y_max),
            });
        }
        chart
    }

    fn px(&self, x: f64) -> f64 {
        let (a, b) = self.x_range;
        let f = if b > a { (x - a) / (b - a) } else { 0.0 };
        self.left + f.clamp(0.0, 1.0) * self.plot_w
    }

    fn py(&self, y: f64) -> f64 {
        self.top + self.plot_h * (1.0 - (y / self.y_max).clamp(0.0, 1.0))
    }

    /// A bar over [x0, x1] up to `y`.
    pub fn bar(&mut self, x0: f64, x1: f64, y: f64, fill: &'static str, label: String) {
        let (a, b, top) = (self.px(x0), self.px(x1), self.py(y));
        self.bars.push(Bar {
            x: r2(a),
            y: r2(top),
            w: r2((b - a).max(0.5)),
            h: r2(self.axis_y - top),
            fill,
            label,
        });
    }

    /// A curve through `points` (x, y), named in the legend.
    pub fn curve(&mut self, points: &[(f64, f64)], legend: &str) {
        self.curve = points
            .iter()
            .map(|&(x, y)| format!("{},{}", r2(self.px(x)), r2(self.py(y))))
            .collect::<Vec<_>>()
            .join(" ");
        self.legend = legend.into();
    }

    /// The SVG element.
    pub fn svg(&self) -> String {
        self.render().unwrap_or_else(|e| {
            format!(
                "<p class=\"problem\">chart {:?} could not be drawn: {e}</p>",
                self.title
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_labels_are_short_and_distinct() {
        assert_eq!(
            [
                short(0.0),
                short(0.0124),
                short(0.0093),
                short(0.5),
                short(2.5),
                short(120.0),
                short(2e6)
            ],
            ["0", "0.012", "0.0093", "0.50", "2.5", "120", "2.0e6"]
        );
    }

    #[test]
    fn bars_and_curve_land_inside_the_plot() {
        let mut c = BarChart::new("t", "x", (0.0, 10.0), 2.0);
        c.bar(0.0, 5.0, 2.0, "#000", "a".into());
        c.bar(5.0, 10.0, 99.0, "#000", "clipped".into());
        c.curve(&[(0.0, 1.0), (10.0, 1.0)], "law");
        let svg = c.svg();
        assert_eq!(svg.matches("<rect").count(), 3, "{svg}");
        assert!(
            svg.contains("<polyline") && svg.contains("law") && svg.starts_with("<svg"),
            "{svg}"
        );
        assert!(
            c.bars
                .iter()
                .all(|b| b.y >= TOP && b.y + b.h <= TOP + c.plot_h + 1e-9)
        );
    }
}
