//! Pictures a person would rather look at than read: the paper's Fig. 6 (error histogram) and
//! Fig. 5 (a frame with true corners white, NMS peaks black, fitted corners grey).

use std::path::Path;

use anyhow::Context;
use boxpose_data::Intrinsics;
use nalgebra::Point3;
use plotters::prelude::*;
use plotters::style::FontStyle;

/// DejaVu Sans (its licence is beside it), so that labels render without system fonts.
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .unwrap_or_else(|_| panic!("the bundled font parses"));
    });
}

const SERIES_COLORS: [RGBColor; 3] = [
    RGBColor(214, 39, 40),
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
];

/// Histogram of `log10(error)` per series, counts on a log scale (the paper's Fig. 6), the errors
/// normalised by the box's d²/3 and a dashed line at the counterexample `threshold`.
pub fn error_histogram(
    path: &Path,
    title: &str,
    series: &[(&str, Vec<f64>)],
    threshold: f64,
) -> anyhow::Result<()> {
    register_font();
    let logs: Vec<Vec<f64>> = series
        .iter()
        .map(|(_, v)| v.iter().filter(|e| **e > 0.0).map(|e| e.log10()).collect())
        .collect();
    let all: Vec<f64> = logs.iter().flatten().copied().collect();
    anyhow::ensure!(
        !all.is_empty(),
        "no positive error to plot in {}",
        path.display()
    );
    let log_threshold = threshold.log10();
    let lo = all.iter().copied().fold(log_threshold, f64::min).floor();
    let hi = all
        .iter()
        .copied()
        .fold(log_threshold, f64::max)
        .ceil()
        .max(lo + 1.0);
    let bins_per_decade = 8.0;
    let bins = ((hi - lo) * bins_per_decade) as usize;
    let counts: Vec<Vec<usize>> = logs
        .iter()
        .map(|values| {
            let mut c = vec![0usize; bins];
            for v in values {
                c[(((v - lo) * bins_per_decade) as usize).min(bins - 1)] += 1;
            }
            c
        })
        .collect();
    let max_count = counts.iter().flatten().copied().max().unwrap_or(1).max(1) as f64;

    let (width, height) = (900u32, 540u32);
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(56)
            .build_cartesian_2d(lo..hi, (0.8..max_count * 1.5).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("log10(paper's error / (d²/3)),  d the box's diagonal")
            .y_desc("instances")
            .y_label_formatter(&|y| format!("{y:.0}"))
            .draw()?;
        let width = 1.0 / bins_per_decade / series.len() as f64;
        for (k, ((name, _), c)) in series.iter().zip(&counts).enumerate() {
            let color = SERIES_COLORS[k % SERIES_COLORS.len()];
            chart
                .draw_series(c.iter().enumerate().filter(|(_, n)| **n > 0).map(|(b, n)| {
                    let x0 = lo + b as f64 / bins_per_decade + k as f64 * width;
                    Rectangle::new([(x0, 0.8), (x0 + width, *n as f64)], color.filled())
                }))?
                .label(format!("{name} ({})", logs[k].len()))
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 12, y + 5)], color.filled())
                });
        }
        chart
            .draw_series(DashedLineSeries::new(
                vec![(log_threshold, 0.8), (log_threshold, max_count * 1.5)],
                6,
                4,
                BLACK.stroke_width(2),
            ))?
            .label(format!("counterexample above {threshold}"))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 12, y)], BLACK.stroke_width(2)));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// One box on the overlay: any of its true corners, NMS peaks and fitted corners.
pub struct OverlayBox {
    pub truth: Option<[Point3<f64>; 8]>,
    pub peaks: Vec<Point3<f64>>,
    pub fitted: Option<[Point3<f64>; 8]>,
}

/// The frame with, per box, the true box white, the NMS peaks black and the fitted box grey
/// (the paper's Fig. 5), as PNG.
pub fn overlay(
    path: &Path,
    rgb: &[u8],
    width: usize,
    height: usize,
    k: &Intrinsics,
    boxes: &[OverlayBox],
) -> anyhow::Result<()> {
    let mut buffer = rgb.to_vec();
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width as u32, height as u32))
            .into_drawing_area();
        let project = |p: &Point3<f64>| -> (i32, i32) {
            (
                (k.fx * p.x / p.z + k.cx).round() as i32,
                (k.fy * p.y / p.z + k.cy).round() as i32,
            )
        };
        let grey = RGBColor(150, 150, 150);
        let draw_box = |corners: &[Point3<f64>; 8], color: RGBColor| -> anyhow::Result<()> {
            for a in 0..8usize {
                for bit in [1usize, 2, 4] {
                    let b = a | bit;
                    if b != a {
                        root.draw(&PathElement::new(
                            vec![project(&corners[a]), project(&corners[b])],
                            color.stroke_width(1),
                        ))?;
                    }
                }
                root.draw(&Circle::new(project(&corners[a]), 3, color.filled()))?;
            }
            Ok(())
        };
        for b in boxes {
            if let Some(truth) = &b.truth {
                draw_box(truth, WHITE)?;
            }
            if let Some(fitted) = &b.fitted {
                draw_box(fitted, grey)?;
            }
            for p in &b.peaks {
                root.draw(&Circle::new(project(p), 3, BLACK.filled()))?;
            }
        }
        root.present()?;
    }
    save_png(path, &buffer, width as u32, height as u32)
}

/// Writes 8-bit RGB pixels as a PNG, atomically (a kill never leaves half a picture).
fn save_png(path: &Path, rgb: &[u8], width: u32, height: u32) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer
        .write_image_data(rgb)
        .with_context(|| format!("cannot encode {}", path.display()))?;
    writer.finish()?;
    Ok(boxpose_data::write_file_atomically(path, &bytes)?)
}

/// Histogram of `(value, weight)` pairs (values already on a log10 axis), with a dashed line at
/// `threshold`: the search's error histogram, weighted by p/q for importance sampling.
pub fn weighted_histogram(
    path: &Path,
    title: &str,
    x_desc: &str,
    values: &[(f64, f64)],
    threshold: f64,
) -> anyhow::Result<()> {
    register_font();
    anyhow::ensure!(!values.is_empty(), "no value to plot in {}", path.display());
    let lo = values.iter().map(|v| v.0).fold(threshold, f64::min).floor();
    let hi = values
        .iter()
        .map(|v| v.0)
        .fold(threshold, f64::max)
        .ceil()
        .max(lo + 1.0);
    let bins_per_decade = 8.0;
    let bins = ((hi - lo) * bins_per_decade) as usize;
    let mut mass = vec![0.0f64; bins];
    for (v, w) in values {
        mass[(((v - lo) * bins_per_decade) as usize).min(bins - 1)] += w;
    }
    let positive: Vec<f64> = mass.iter().copied().filter(|m| *m > 0.0).collect();
    let floor = positive.iter().copied().fold(f64::INFINITY, f64::min) * 0.5;
    let top = positive.iter().copied().fold(0.0, f64::max) * 2.0;
    let (width, height) = (900u32, 540u32);
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(64)
            .build_cartesian_2d(lo..hi, (floor..top).log_scale())?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc("samples (weighted)")
            .y_label_formatter(&|y| format!("{y:.2}"))
            .draw()?;
        let color = SERIES_COLORS[1];
        chart.draw_series(
            mass.iter()
                .enumerate()
                .filter(|(_, m)| **m > 0.0)
                .map(|(b, m)| {
                    let x0 = lo + b as f64 / bins_per_decade;
                    Rectangle::new(
                        [(x0, floor), (x0 + 1.0 / bins_per_decade, *m)],
                        color.filled(),
                    )
                }),
        )?;
        chart.draw_series(DashedLineSeries::new(
            vec![(threshold, floor), (threshold, top)],
            6,
            4,
            SERIES_COLORS[0].stroke_width(2),
        ))?;
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// The estimate against samples spent: `(spent, p̂, low, high)` points, the interval shaded.
pub fn estimate_curve(
    path: &Path,
    title: &str,
    points: &[(f64, f64, f64, f64)],
) -> anyhow::Result<()> {
    register_font();
    let x_max = points.iter().map(|p| p.0).fold(1.0, f64::max);
    let y_max = points.iter().map(|p| p.3).fold(0.0, f64::max).max(1e-6) * 1.1;
    let (width, height) = (900u32, 480u32);
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..x_max, 0.0..y_max)?;
        chart
            .configure_mesh()
            .x_desc("samples spent")
            .y_desc("P(fail | valid)")
            .y_label_formatter(&|y| format!("{y:.1e}"))
            .draw()?;
        let band: Vec<(f64, f64)> = points
            .iter()
            .map(|p| (p.0, p.3))
            .chain(points.iter().rev().map(|p| (p.0, p.2)))
            .collect();
        chart.draw_series(std::iter::once(Polygon::new(
            band,
            SERIES_COLORS[1].mix(0.25).filled(),
        )))?;
        chart.draw_series(LineSeries::new(
            points.iter().map(|p| (p.0, p.1)),
            SERIES_COLORS[1].stroke_width(2),
        ))?;
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// Small multiples: each sample's failure score (clamped to [−3, 3]; +∞ drawn at the top)
/// against each parameter's nominal quantile, failures red.
pub fn parameter_map(
    path: &Path,
    names: &[&str],
    points: &[(Vec<f64>, f64, bool)],
) -> anyhow::Result<()> {
    register_font();
    let columns = 4usize;
    let rows = names.len().div_ceil(columns).max(1);
    let (width, height) = (1200u32, 240 * rows as u32);
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        for (panel, (area, name)) in root
            .split_evenly((rows, columns))
            .iter()
            .zip(names)
            .enumerate()
        {
            let mut chart = ChartBuilder::on(area)
                .caption(*name, ("sans-serif", 15))
                .margin(6)
                .x_label_area_size(22)
                .y_label_area_size(32)
                .build_cartesian_2d(0.0..1.0, -3.0..3.2)?;
            chart.configure_mesh().x_labels(3).y_labels(4).draw()?;
            chart.draw_series(DashedLineSeries::new(
                vec![(0.0, 0.0), (1.0, 0.0)],
                4,
                3,
                BLACK.stroke_width(1),
            ))?;
            for failed in [false, true] {
                let color = if failed {
                    SERIES_COLORS[0].mix(1.0)
                } else {
                    SERIES_COLORS[1].mix(0.5)
                };
                chart.draw_series(points.iter().filter(|p| p.2 == failed).map(
                    |(x, score, _)| {
                        Circle::new((x[panel], score.clamp(-3.0, 3.1)), 2, color.filled())
                    },
                ))?;
            }
        }
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// A 3D view of one box in the camera frame: true corners and edges white-on-dark as black, the
/// NMS peaks red, the fitted box grey — where the peaks lie that the frame cannot show (depth).
pub fn view_3d(
    path: &Path,
    title: &str,
    truth: &[Point3<f64>; 8],
    peaks: &[Point3<f64>],
    fitted: Option<&[Point3<f64>; 8]>,
) -> anyhow::Result<()> {
    register_font();
    let all: Vec<&Point3<f64>> = truth
        .iter()
        .chain(peaks)
        .chain(fitted.into_iter().flatten())
        .collect();
    let range = |k: usize| {
        let (lo, hi) = all
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p[k]), hi.max(p[k]))
            });
        let pad = (hi - lo).max(1e-3) * 0.1;
        (lo - pad)..(hi + pad)
    };
    let (width, height) = (520u32, 480u32);
    let mut buffer = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        // camera frame: x right, y down, z forward; drawn with z as depth away from the viewer
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .build_cartesian_3d(range(0), range(1), range(2))?;
        chart.with_projection(|mut p| {
            p.pitch = 0.5;
            p.yaw = 0.6;
            p.scale = 0.8;
            p.into_matrix()
        });
        chart.configure_axes().draw()?;
        let edges = |corners: &[Point3<f64>; 8]| -> Vec<Vec<(f64, f64, f64)>> {
            let mut out = Vec::new();
            for a in 0..8usize {
                for bit in [1usize, 2, 4] {
                    if a & bit == 0 {
                        let b = a | bit;
                        out.push(vec![
                            (corners[a].x, corners[a].y, corners[a].z),
                            (corners[b].x, corners[b].y, corners[b].z),
                        ]);
                    }
                }
            }
            out
        };
        for edge in edges(truth) {
            chart.draw_series(LineSeries::new(edge, BLACK.stroke_width(2)))?;
        }
        if let Some(fitted) = fitted {
            for edge in edges(fitted) {
                chart.draw_series(LineSeries::new(
                    edge,
                    RGBColor(150, 150, 150).stroke_width(1),
                ))?;
            }
        }
        chart.draw_series(
            peaks
                .iter()
                .map(|p| Circle::new((p.x, p.y, p.z), 4, SERIES_COLORS[0].filled())),
        )?;
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}
