//! Pictures a person would rather look at than read: the paper's Fig. 6 (error histogram) and
//! Fig. 5 (a frame with true corners white, NMS peaks black, fitted corners grey).

use std::path::Path;

use anyhow::Context;
use boxpose_data::{Frame, Intrinsics, Visibility};
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

/// The colours of one box's three sets of corners, the same in every picture (the report's
/// frames, its 3D views and `boxpose view`): the true box, the network's NMS peaks, the fit.
pub const TRUTH_COLOR: RGBColor = RGBColor(44, 160, 44);
pub const PEAKS_COLOR: RGBColor = RGBColor(214, 39, 40);
pub const FITTED_COLOR: RGBColor = RGBColor(31, 119, 180);

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
    let (lo, hi) = decades_spanned(&all, log_threshold);
    let counts: Vec<Vec<f64>> = logs
        .iter()
        .map(|values| binned(values.iter().map(|v| (*v, 1.0)), lo, hi))
        .collect();
    let max_count = counts.iter().flatten().copied().fold(1.0, f64::max);

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
        let width = 1.0 / BINS_PER_DECADE / series.len() as f64;
        for (k, ((name, _), c)) in series.iter().zip(&counts).enumerate() {
            let color = SERIES_COLORS[k % SERIES_COLORS.len()];
            chart
                .draw_series(
                    c.iter()
                        .enumerate()
                        .filter(|(_, n)| **n > 0.0)
                        .map(|(b, n)| {
                            let x0 = lo + b as f64 / BINS_PER_DECADE + k as f64 * width;
                            Rectangle::new([(x0, 0.8), (x0 + width, *n)], color.filled())
                        }),
                )?
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

/// The error histogram's bins per decade of log10(error).
const BINS_PER_DECADE: f64 = 8.0;

/// The whole decades [lo, hi] that hold every value and the threshold (at least one decade).
fn decades_spanned(values: &[f64], threshold: f64) -> (f64, f64) {
    let lo = values.iter().copied().fold(threshold, f64::min).floor();
    let hi = values
        .iter()
        .copied()
        .fold(threshold, f64::max)
        .ceil()
        .max(lo + 1.0);
    (lo, hi)
}

/// The summed weights of `(value, weight)` pairs in [`BINS_PER_DECADE`] bins per decade from
/// `lo` to `hi` (the last bin takes the upper edge).
fn binned(values: impl IntoIterator<Item = (f64, f64)>, lo: f64, hi: f64) -> Vec<f64> {
    let bins = ((hi - lo) * BINS_PER_DECADE) as usize;
    let mut mass = vec![0.0; bins];
    for (v, w) in values {
        mass[(((v - lo) * BINS_PER_DECADE) as usize).min(bins - 1)] += w;
    }
    mass
}

/// One box on the overlay: any of its true corners, NMS peaks and fitted corners.
pub struct OverlayBox {
    pub truth: Option<[Point3<f64>; 8]>,
    pub peaks: Vec<Point3<f64>>,
    pub fitted: Option<[Point3<f64>; 8]>,
}

/// The frame with, per box, the true box ([`TRUTH_COLOR`]), the NMS peaks ([`PEAKS_COLOR`]) and
/// the fitted box ([`FITTED_COLOR`]) (the paper's Fig. 5), as PNG.
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
        draw_overlay(&root, k, boxes)?;
        root.present()?;
    }
    save_png(path, &buffer, width as u32, height as u32)
}

/// Pixel of a camera-frame point.
fn project(k: &Intrinsics, p: &Point3<f64>) -> (i32, i32) {
    (
        (k.fx * p.x / p.z + k.cx).round() as i32,
        (k.fy * p.y / p.z + k.cy).round() as i32,
    )
}

/// The twelve edges of a box (corner bit 0 → x, 1 → y, 2 → z), as pairs of corner indices.
fn box_edges() -> impl Iterator<Item = (usize, usize)> {
    (0..8usize).flat_map(|a| {
        [1usize, 2, 4]
            .into_iter()
            .filter(move |bit| a & bit == 0)
            .map(move |bit| (a, a | bit))
    })
}

fn draw_overlay<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    k: &Intrinsics,
    boxes: &[OverlayBox],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let draw_box = |corners: &[Point3<f64>; 8], color: RGBColor| -> anyhow::Result<()> {
        for (a, b) in box_edges() {
            area.draw(&PathElement::new(
                vec![project(k, &corners[a]), project(k, &corners[b])],
                color.stroke_width(1),
            ))?;
        }
        for corner in corners {
            area.draw(&Circle::new(project(k, corner), 3, color.filled()))?;
        }
        Ok(())
    };
    for b in boxes {
        if let Some(truth) = &b.truth {
            draw_box(truth, TRUTH_COLOR)?;
        }
        if let Some(fitted) = &b.fitted {
            draw_box(fitted, FITTED_COLOR)?;
        }
        for p in &b.peaks {
            area.draw(&Circle::new(project(k, p), 3, PEAKS_COLOR.filled()))?;
        }
    }
    Ok(())
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
    let (lo, hi) = decades_spanned(&values.iter().map(|v| v.0).collect::<Vec<_>>(), threshold);
    let mass = binned(values.iter().copied(), lo, hi);
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
            .y_label_formatter(&|y| tick_label(*y))
            .draw()?;
        let color = SERIES_COLORS[1];
        chart.draw_series(
            mass.iter()
                .enumerate()
                .filter(|(_, m)| **m > 0.0)
                .map(|(b, m)| {
                    let x0 = lo + b as f64 / BINS_PER_DECADE;
                    Rectangle::new(
                        [(x0, floor), (x0 + 1.0 / BINS_PER_DECADE, *m)],
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

/// A tick label with the digits its value needs, for linear and log axes alike: 20 → "20",
/// 2.5 → "2.5", 3 → "3", 0.05 → "0.05", 0.0043 → "0.0043".
fn tick_label(y: f64) -> String {
    if !(y.is_finite() && y > 0.0) || y >= 10.0 {
        return format!("{y:.0}");
    }
    let decimals = (1 - y.log10().floor() as i32).max(0) as usize;
    let text = format!("{y:.decimals$}");
    match text.contains('.') {
        true => text.trim_end_matches('0').trim_end_matches('.').to_string(),
        false => text,
    }
}

/// The estimate against samples spent: `(spent, p̂, low, high)` points, the interval shaded.
pub fn estimate_curve(
    path: &Path,
    title: &str,
    points: &[(f64, f64, f64, f64)],
) -> anyhow::Result<()> {
    register_font();
    // a little room to the right, so that the last tick's label is not cut at the edge
    let x_max = points.iter().map(|p| p.0).fold(1.0, f64::max) * 1.04;
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
            .x_label_formatter(&|x| tick_label(*x))
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
                .x_label_area_size(34)
                .y_label_area_size(44)
                .build_cartesian_2d(0.0..1.0, -3.0..3.2)?;
            chart
                .configure_mesh()
                .x_labels(3)
                .y_labels(4)
                .x_desc("nominal quantile")
                .y_desc("failure score")
                .axis_desc_style(("sans-serif", 12))
                .draw()?;
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

/// A 3D view of one box in the camera frame, in the frames' colours (the true box
/// [`TRUTH_COLOR`], the NMS peaks [`PEAKS_COLOR`], the fitted box [`FITTED_COLOR`]): where the
/// peaks lie that the frame cannot show (depth).
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
            box_edges()
                .map(|(a, b)| {
                    vec![
                        (corners[a].x, corners[a].y, corners[a].z),
                        (corners[b].x, corners[b].y, corners[b].z),
                    ]
                })
                .collect()
        };
        for edge in edges(truth) {
            chart.draw_series(LineSeries::new(edge, TRUTH_COLOR.stroke_width(2)))?;
        }
        if let Some(fitted) = fitted {
            for edge in edges(fitted) {
                chart.draw_series(LineSeries::new(edge, FITTED_COLOR.stroke_width(1)))?;
            }
        }
        chart.draw_series(
            peaks
                .iter()
                .map(|p| Circle::new((p.x, p.y, p.z), 4, PEAKS_COLOR.filled())),
        )?;
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// The corner colours of `boxpose view` by visibility (`instances.corner_visibility`).
pub const VISIBILITY_COLORS: [(Visibility, RGBColor, &str); 4] = [
    (Visibility::Visible, TRUTH_COLOR, "visible"),
    (
        Visibility::OccludedByOther,
        RGBColor(255, 127, 14),
        "occluded by another box",
    ),
    (
        Visibility::SelfOccluded,
        RGBColor(148, 103, 189),
        "self-occluded",
    ),
    (
        Visibility::OutsideImage,
        RGBColor(127, 127, 127),
        "outside the image",
    ),
];

/// What `boxpose view` shows beside a frame: a title line, and for a search sample the network's
/// peaks and fit of the target box and the sample's parameters.
pub struct SheetExtras {
    pub title: String,
    pub overlay: Option<OverlayBox>,
    pub text: Vec<String>,
}

/// One frame as a sheet of three panels: the RGB image with every box's true edges and its
/// corners coloured by visibility (and a search sample's peaks and fit), the depth (near bright,
/// no surface black) and the instance masks (a colour per box, its object_id at its centre); a
/// legend above, `extras.text` on the right.
pub fn frame_sheet(path: &Path, frame: &Frame, extras: &SheetExtras) -> anyhow::Result<()> {
    register_font();
    let (w, h) = (frame.width as u32, frame.height as u32);
    let header = 56u32;
    let gap = 8u32;
    let text_width = if extras.text.is_empty() { 0 } else { 320 };
    let legend = sheet_legend(extras.overlay.is_some());
    let legend_width = 6 + legend
        .iter()
        .map(|(_, name)| legend_step(name))
        .sum::<i32>() as u32;
    let width = (3 * w + 2 * gap + text_width).max(legend_width).max(560);
    let height = (h + header).max(header + 16 * extras.text.len() as u32 + 8);
    let mut buffer = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let font = ("sans-serif", 14).into_font();
        root.draw(&Text::new(extras.title.clone(), (6, 4), font.clone()))?;
        let mut x = 6;
        for (color, name) in legend {
            root.draw(&Circle::new((x + 5, 32), 5, color.filled()))?;
            root.draw(&Text::new(name, (x + 14, 25), font.clone()))?;
            x += legend_step(name);
        }
        let panels = root.margin(header, 0, 0, 0);
        let panel = |i: u32| {
            let x0 = (i * (w + gap)) as i32;
            panels.clone().shrink((x0, 0), (w, h))
        };
        draw_truth_panel(&panel(0), frame, extras.overlay.as_ref())?;
        draw_depth_panel(&panel(1), frame, &font)?;
        draw_mask_panel(&panel(2), frame, &font)?;
        let text_x = (3 * w + 2 * gap + 10) as i32;
        for (line, text) in extras.text.iter().enumerate() {
            root.draw(&Text::new(
                text.clone(),
                (text_x, header as i32 + 16 * line as i32),
                ("sans-serif", 12).into_font(),
            ))?;
        }
        root.present()?;
    }
    save_png(path, &buffer, width, height)
}

/// The sheet's legend entries: the visibility states, and a sample's peaks and fit.
fn sheet_legend(overlay: bool) -> Vec<(RGBColor, &'static str)> {
    let mut legend: Vec<_> = VISIBILITY_COLORS.iter().map(|(_, c, n)| (*c, *n)).collect();
    if overlay {
        legend.extend([(PEAKS_COLOR, "NMS peaks"), (FITTED_COLOR, "fitted box")]);
    }
    legend
}

/// The width in pixels one legend entry takes (its dot, its name at 14 px, a space).
fn legend_step(name: &str) -> i32 {
    24 + 8 * name.len() as i32
}

type Panel<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Paints every pixel of the frame-sized `panel` with `colour(pixel index)`.
fn fill_panel(
    panel: &Panel,
    frame: &Frame,
    colour: impl Fn(usize) -> RGBColor,
) -> anyhow::Result<()> {
    for i in 0..frame.width * frame.height {
        let xy = ((i % frame.width) as i32, (i / frame.width) as i32);
        panel.draw_pixel(xy, &colour(i))?;
    }
    Ok(())
}

/// The RGB image, every box's true edges, its corners coloured by visibility, and a search
/// sample's peaks and fitted box.
fn draw_truth_panel(
    panel: &Panel,
    frame: &Frame,
    overlay: Option<&OverlayBox>,
) -> anyhow::Result<()> {
    fill_panel(panel, frame, |i| {
        RGBColor(frame.rgb[3 * i], frame.rgb[3 * i + 1], frame.rgb[3 * i + 2])
    })?;
    let px = |c: [f64; 2]| (c[0].round() as i32, c[1].round() as i32);
    for instance in &frame.instances {
        for (a, b) in box_edges() {
            panel.draw(&PathElement::new(
                vec![px(instance.corners_px[a]), px(instance.corners_px[b])],
                WHITE.mix(0.6).stroke_width(1),
            ))?;
        }
        for (corner, visibility) in instance.corners_px.iter().zip(instance.visibility) {
            let color = VISIBILITY_COLORS
                .iter()
                .find(|(v, _, _)| *v == visibility)
                .map_or(BLACK, |(_, c, _)| *c);
            panel.draw(&Circle::new(px(*corner), 3, color.filled()))?;
        }
    }
    if let Some(overlay) = overlay {
        let only_fit = OverlayBox {
            truth: None,
            peaks: overlay.peaks.clone(),
            fitted: overlay.fitted,
        };
        draw_overlay(panel, &frame.intrinsics, std::slice::from_ref(&only_fit))?;
    }
    Ok(())
}

/// The depth, near bright and no surface black, scaled between the 2nd and 98th percentile of
/// the surfaces' depths: a far floor or wall does not flatten the boxes into one grey.
fn draw_depth_panel(panel: &Panel, frame: &Frame, font: &FontDesc) -> anyhow::Result<()> {
    let mut surfaces: Vec<f32> = frame.depth.iter().copied().filter(|d| *d > 0.0).collect();
    surfaces.sort_by(f32::total_cmp);
    let percentile = |q: f64| surfaces[((surfaces.len() - 1) as f64 * q).round() as usize];
    let (near, far) = if surfaces.is_empty() {
        (0.0, 0.0)
    } else {
        (percentile(0.02), percentile(0.98))
    };
    fill_panel(panel, frame, |i| {
        let d = frame.depth[i];
        if d <= 0.0 {
            return BLACK;
        }
        let t = if far > near {
            ((far - d) / (far - near)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let v = (40.0 + 215.0 * t) as u8;
        RGBColor(v, v, v)
    })?;
    if !surfaces.is_empty() {
        panel.draw(&Text::new(
            format!("depth {near:.2}–{far:.2} m"),
            (4, 4),
            font.clone().color(&RED),
        ))?;
    }
    Ok(())
}

/// The instance masks, a colour per box (golden-angle hues: neighbouring ids far apart), each
/// box's object_id at the centre of its visible bounding box.
fn draw_mask_panel(panel: &Panel, frame: &Frame, font: &FontDesc) -> anyhow::Result<()> {
    fill_panel(panel, frame, |i| match frame.instance_mask[i] {
        0 => BLACK,
        label => {
            let hue = (f64::from(label) * 0.618_034).fract();
            let (r, g, b) = hsl_to_rgb(hue, 0.65, 0.55);
            RGBColor(r, g, b)
        }
    })?;
    for instance in &frame.instances {
        if let Some([x0, y0, x1, y1]) = instance.visible_bbox {
            panel.draw(&Text::new(
                instance.object_id.to_string(),
                ((x0 + x1) / 2 - 4, (y0 + y1) / 2 - 7),
                font.clone().color(&WHITE),
            ))?;
        }
    }
    Ok(())
}

/// RGB bytes of a hue, saturation and lightness in [0, 1].
fn hsl_to_rgb(h: f64, s: f64, l: f64) -> (u8, u8, u8) {
    let c = (1.0 - (2.0 * l - 1.0).abs()) * s;
    let x = c * (1.0 - ((h * 6.0) % 2.0 - 1.0).abs());
    let (r, g, b) = match (h * 6.0) as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = l - c / 2.0;
    let byte = |v: f64| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8;
    (byte(r), byte(g), byte(b))
}

#[cfg(test)]
mod tests {
    use super::tick_label;

    #[test]
    fn tick_labels_carry_the_digits_their_value_needs() {
        let cases = [
            (2000.0, "2000"),
            (20.0, "20"),
            (3.0, "3"),
            (2.5, "2.5"),
            (0.5, "0.5"),
            (0.05, "0.05"),
            (0.0043, "0.0043"),
            (0.0, "0"),
        ];
        for (value, label) in cases {
            assert_eq!(tick_label(value), label, "{value}");
        }
    }
}
