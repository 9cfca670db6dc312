//! `boxpose search report RUN`: pictures of a search run and one offline HTML page linking them —
//! the paper's Fig. 6 (weighted for importance sampling), the estimate against samples spent,
//! where failures sit in parameter space, and the worst counterexamples drawn on their frames.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use boxpose_data::{Dataset, Frame};
use boxpose_search::run::{Run, RunSettings, SampleRow, Sampler, estimate};
use boxpose_search::sut::Predicate;
use boxpose_search_stats::stats::normal_cdf as standard_normal_cdf;
use nalgebra::Point3;

use crate::html::escape;
use crate::plots::{self, OverlayBox, SheetExtras};

/// Reads the predicate's metric off a sample (None where the sample has no such score).
type MetricOf = fn(&SampleRow) -> Option<f64>;

/// Points of the estimate-against-samples curve.
const CURVE_POINTS: usize = 60;

/// Draws the run's figures and its `worst` counterexamples and publishes them with the page as
/// `RUN/report/` in one step; returns the page's path.
pub fn write(run_dir: &Path, worst: usize) -> anyhow::Result<PathBuf> {
    let run = Run::open(run_dir)?;
    let (rows, _) = run.rows()?;
    anyhow::ensure!(!rows.is_empty(), "{}: no sample yet", run_dir.display());
    let out = run_dir.join("report");
    let tmp = run_dir.join(format!("report.tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| tmp.display().to_string())?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| tmp.display().to_string())?;

    let figures = draw_figures(&run, &rows, &tmp)?;
    let mut failing: Vec<&SampleRow> = rows.iter().filter(|r| r.failed).collect();
    failing.sort_by(|a, b| {
        b.level_score()
            .total_cmp(&a.level_score())
            .then(a.sample_id.cmp(&b.sample_id))
    });
    failing.truncate(worst);
    let mut drawn = draw_counterexamples(&run, run_dir, &failing, &tmp)?;
    drawn.sort_by_key(|(id, _, _)| failing.iter().position(|r| r.sample_id == *id));

    let html = page(&run, &rows, &figures, &failing, &drawn)?;
    std::fs::write(tmp.join("index.html"), html).with_context(|| tmp.display().to_string())?;
    // the old report stays readable until the new one replaces it in one step
    boxpose_data::publish_folder(&tmp, &out)?;
    Ok(out.join("index.html"))
}

/// The run's figures in `tmp`, each with its caption: the error histogram (weighted for
/// importance sampling), the estimate against samples spent, and the parameter map.
fn draw_figures(
    run: &Run,
    rows: &[SampleRow],
    tmp: &Path,
) -> anyhow::Result<Vec<(&'static str, &'static str)>> {
    let mut figures = Vec::new();
    figures.extend(draw_error_histogram(run, rows, tmp)?);
    let curve = estimate_curve(rows, run)?;
    if curve.len() >= 2 {
        plots::estimate_curve(
            &tmp.join("estimate.png"),
            "P(fail | valid) against samples spent (95% CI)",
            &curve,
        )?;
        figures.push(("estimate.png", "The estimate and its 95% interval as samples are spent (cross-entropy: tuning samples first, counted in the budget)."));
    }

    figures.extend(draw_parameter_map(run, rows, tmp)?);
    Ok(figures)
}

/// The error histogram of the samples that follow the nominal, weighted by p/q for importance
/// sampling, with the predicate's threshold; none when no sample has a positive error.
fn draw_error_histogram(
    run: &Run,
    rows: &[SampleRow],
    tmp: &Path,
) -> anyhow::Result<Option<(&'static str, &'static str)>> {
    let settings = &run.record.settings;
    // the samples that follow the nominal (Monte Carlo, splitting's first stage) or that the
    // weights bring back to it (the cross-entropy final stage)
    let estimating: Vec<&SampleRow> = rows
        .iter()
        .filter(|r| match settings.sampler {
            Sampler::Mc => r.stage == "mc",
            Sampler::Ce => r.stage == "final",
            Sampler::Splitting => r.iteration == 0,
        })
        .collect();
    let (metric_name, threshold, metric): (&str, f64, MetricOf) = match settings.predicate {
        Predicate::PaperError { threshold } => ("paper's error / (diag²/3)", threshold, |r| {
            r.paper_error_normalized
        }),
        Predicate::Mssd { fraction } => ("MSSD / diameter", fraction, |r| r.mssd_over_diameter),
        Predicate::CubeMssd { fraction } => ("cube MSSD / diameter", fraction, |r| {
            r.cube_mssd_over_diameter
        }),
    };
    let weighted: Vec<(f64, f64)> = estimating
        .iter()
        .filter_map(|r| {
            metric(r)
                .filter(|v| *v > 0.0)
                .map(|v| (v.log10(), r.log_weight.exp()))
        })
        .collect();
    if weighted.is_empty() {
        return Ok(None);
    }
    let title = match settings.sampler {
        Sampler::Mc => format!("{metric_name}, {} scored samples", weighted.len()),
        Sampler::Ce => format!("{metric_name}, {} samples weighted by p/q", weighted.len()),
        Sampler::Splitting => format!(
            "{metric_name}, {} first-stage (nominal) samples",
            weighted.len()
        ),
    };
    plots::weighted_histogram(
        &tmp.join("error_hist.png"),
        &title,
        &format!("log10({metric_name})"),
        &weighted,
        threshold.log10(),
    )?;
    Ok(Some((
        "error_hist.png",
        "Error histogram (the paper's Fig. 6), threshold dashed; importance-sampling runs weight each sample by p/q, so the bars estimate the nominal distribution.",
    )))
}

/// Each valid sample's failure score against each scalar parameter's nominal quantile.
fn draw_parameter_map(
    run: &Run,
    rows: &[SampleRow],
    tmp: &Path,
) -> anyhow::Result<Option<(&'static str, &'static str)>> {
    let names = &run.record.dimensions;
    let scalar: Vec<usize> = (0..names.len())
        .filter(|&d| !names[d].contains(".orientation."))
        .collect();
    let points: Vec<(Vec<f64>, f64, bool)> = rows
        .iter()
        .filter(|r| r.valid)
        .map(|r| {
            (
                scalar
                    .iter()
                    .map(|&d| standard_normal_cdf(r.z[d]))
                    .collect(),
                r.level_score(),
                r.failed,
            )
        })
        .collect();
    if points.is_empty() {
        return Ok(None);
    }
    let panel_names: Vec<&str> = scalar.iter().map(|&d| names[d].as_str()).collect();
    plots::parameter_map(&tmp.join("parameters.png"), &panel_names, &points)?;
    Ok(Some((
        "parameters.png",
        "Where failures sit: each valid sample's failure score (> 0 fails; nothing fitted at the top) against each parameter's nominal quantile Φ(z); failures red.",
    )))
}

/// Each failing sample whose frame the run kept, drawn in `tmp` (its overlay, ground-truth sheet
/// and 3D view), as (sample id, overlay file, re-render command).
fn draw_counterexamples(
    run: &Run,
    run_dir: &Path,
    failing: &[&SampleRow],
    tmp: &Path,
) -> anyhow::Result<Vec<(i64, String, String)>> {
    let counterexamples = run_dir.join("counterexamples");
    let mut drawn = Vec::new();
    if !failing.is_empty() && counterexamples.is_dir() {
        let dataset = Dataset::open(&counterexamples)?;
        let crops = render_crops(&dataset)?;
        for frame in dataset.frames()? {
            let frame = frame?;
            let Some(row) = failing.iter().find(|r| r.sample_id == frame.scene_id) else {
                continue;
            };
            let name = draw_sample(
                tmp,
                &frame,
                points(row.peaks_camera_m.as_deref().unwrap_or_default()),
                row,
                &format!("sample {} (camera frame, m)", row.sample_id),
            )?;
            let sheet = format!("sample-{}-sheet.png", row.sample_id);
            let extras = sample_sheet(
                run,
                row,
                format!("sample {} of {}", row.sample_id, run_dir.display()),
            );
            plots::frame_sheet(&tmp.join(&sheet), &frame, &extras)?;
            let crop = crops
                .get(&row.sample_id)
                .map_or(String::new(), |c| format!(" --crop {c}"));
            let command = format!(
                "boxpose render {} --scene {}{crop}",
                counterexamples.display(),
                row.sample_id
            );
            drawn.push((row.sample_id, name, command));
        }
    }
    Ok(drawn)
}

/// A sample's frame with its target drawn — true box, the network's `peaks`, the fitted box — as
/// `DIR/sample-N.png`, and when the frame shows the target its 3-D view `DIR/sample-N-3d.png`
/// titled `view_title`; returns the overlay's file name. The search report draws its
/// counterexamples with it, `boxpose search replay` its replayed sample.
pub fn draw_sample(
    dir: &Path,
    frame: &Frame,
    peaks: Vec<Point3<f64>>,
    row: &SampleRow,
    view_title: &str,
) -> anyhow::Result<String> {
    let truth = frame
        .instances
        .iter()
        .find(|i| i.object_id == boxpose_search::scene::TARGET_OBJECT_ID)
        .map(|i| i.corners_camera.map(Point3::from));
    let fitted = fitted_corners(row);
    let name = format!("sample-{}.png", row.sample_id);
    plots::overlay(
        &dir.join(&name),
        &frame.rgb,
        frame.width,
        frame.height,
        &frame.intrinsics,
        &[OverlayBox {
            truth,
            peaks: peaks.clone(),
            fitted,
        }],
    )?;
    if let Some(truth) = &truth {
        plots::view_3d(
            &dir.join(format!("sample-{}-3d.png", row.sample_id)),
            view_title,
            truth,
            &peaks,
            fitted.as_ref(),
        )?;
    }
    Ok(name)
}

/// Points of a flat x, y, z list (a sample row's peaks or corners).
fn points(values: &[f64]) -> Vec<Point3<f64>> {
    values
        .chunks(3)
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect()
}

/// The fitted box's corners of a sample row, when something was fitted.
fn fitted_corners(row: &SampleRow) -> Option<[Point3<f64>; 8]> {
    let corners = points(row.fitted_corners_camera_m.as_deref()?);
    <[Point3<f64>; 8]>::try_from(corners).ok()
}

/// (samples spent, p̂, CI low, CI high) at up to [`CURVE_POINTS`] prefixes of the estimating stage.
fn estimate_curve(rows: &[SampleRow], run: &Run) -> anyhow::Result<Vec<(f64, f64, f64, f64)>> {
    let sampler = run.record.settings.sampler;
    let stage = match sampler {
        Sampler::Mc => "mc",
        Sampler::Ce => "final",
        // its estimate is a product over stages, not a running mean: the levels table shows it
        Sampler::Splitting => return Ok(Vec::new()),
    };
    let before = rows.iter().filter(|r| r.stage != stage).count();
    let estimating: Vec<SampleRow> = rows.iter().filter(|r| r.stage == stage).cloned().collect();
    let mut curve = Vec::new();
    let step = estimating.len().div_ceil(CURVE_POINTS).max(1);
    for n in (step..=estimating.len()).step_by(step) {
        let prefix = &estimating[..n];
        // an early prefix may miss a stratum: no estimate there yet
        let Ok(e) = estimate(prefix, sampler, None) else {
            continue;
        };
        let (lo, hi) = e.ci95.unwrap_or((0.0, e.p_hat));
        curve.push(((before + n) as f64, e.p_hat, lo, hi));
    }
    Ok(curve)
}

/// Each counterexample frame's rendered region as `boxpose render --crop` takes it (`x0,y0,x1,y1`),
/// from its `render_settings`; frames rendered whole have none.
fn render_crops(dataset: &Dataset) -> anyhow::Result<std::collections::HashMap<i64, String>> {
    use boxpose_data::arrow::array::{AsArray, Int64Array};
    let mut crops = std::collections::HashMap::new();
    for shard in dataset.read_table(&boxpose_data::schema::FRAMES)? {
        let batch = &shard.batch;
        let (Some(ids), Some(settings)) = (
            batch.column_by_name("scene_id"),
            batch.column_by_name("render_settings"),
        ) else {
            continue;
        };
        let ids: &Int64Array = ids.as_primitive();
        let settings = settings.as_string::<i32>();
        for i in 0..batch.num_rows() {
            let crop = serde_json::from_str::<serde_json::Value>(settings.value(i))
                .ok()
                .and_then(|v| v.get("crop").and_then(|c| c.as_array()).cloned());
            if let Some(crop) = crop.filter(|c| c.len() == 4) {
                let values: Vec<String> = crop.iter().map(|x| x.to_string()).collect();
                crops.insert(ids.value(i), values.join(","));
            }
        }
    }
    Ok(crops)
}

/// The worst counterexamples' parameter values, one row per scalar parameter (orientation
/// blocks are raw normals, left out) and one column per sample: what each failure was.
fn parameter_table(h: &mut String, names: &[String], failing: &[&SampleRow]) -> anyhow::Result<()> {
    writeln!(
        h,
        "<h3>Their parameters</h3><table><tr><th>parameter</th>{}</tr>",
        failing
            .iter()
            .map(|r| format!("<th>sample {}</th>", r.sample_id))
            .collect::<String>()
    )?;
    for (d, name) in names.iter().enumerate() {
        if name.contains(".orientation.") {
            continue;
        }
        writeln!(
            h,
            "<tr><td style=\"text-align:left\"><code>{}</code></td>{}</tr>",
            escape(name),
            failing
                .iter()
                .map(|r| format!(
                    "<td>{}</td>",
                    r.params.get(d).map_or("–".into(), |v| format!("{v:.4}"))
                ))
                .collect::<String>()
        )?;
    }
    writeln!(h, "</table>")?;
    Ok(())
}

/// How many valid samples each predicate flags, whatever the run's: the paper's predicate
/// misses most quarter turns of near-square boxes that the MSSDs see, and the reverse.
fn predicate_counts(rows: &[SampleRow]) -> String {
    let failing = |predicate: &str| {
        let predicate = Predicate::parse(predicate).expect("a predicate at its default threshold");
        rows.iter().filter(|r| r.fails_under(&predicate)).count()
    };
    format!(
        "Of the {} valid samples, each predicate's failures (a box not found or not fitted counts in each): the paper's error &gt; 0.005: {}; cube-group corner MSSD &gt; 0.1 d (the primary metric): {}; exact MSSD &gt; 0.1 d (orientation-aware): {}.",
        rows.iter().filter(|r| r.valid).count(),
        failing("paper"),
        failing("cube-mssd"),
        failing("mssd"),
    )
}

/// What a sample's sheet adds to its frame's ground truth: the network's peaks and fitted box of
/// the target, and a text panel of the sample's errors and parameter values (`boxpose view
/// RUN --sample`, and each counterexample of the search report).
pub fn sample_sheet(run: &Run, row: &SampleRow, title: String) -> SheetExtras {
    let sample = row.sample_id;
    let overlay = OverlayBox {
        truth: None,
        peaks: row
            .peaks_camera_m
            .as_deref()
            .map(points)
            .unwrap_or_default(),
        fitted: fitted_corners(row),
    };
    let number = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
    let mut text = vec![
        format!(
            "sample {sample}: {} ({} stage, iteration {})",
            if row.failed { "failed" } else { "passed" },
            row.stage,
            row.iteration
        ),
        format!(
            "paper error / (d²/3) = {}",
            number(row.paper_error_normalized)
        ),
        format!("MSSD / d = {}", number(row.mssd_over_diameter)),
        format!("cube MSSD / d = {}", number(row.cube_mssd_over_diameter)),
        format!("rotation error = {} °", number(row.rotation_error_deg)),
        format!(
            "target {} ({} visible)",
            match row.detected {
                Some(true) => "found",
                Some(false) => "not found",
                None => "–",
            },
            number(row.target_visible_fraction.map(f64::from))
        ),
        String::new(),
    ];
    for (name, value) in run.record.dimensions.iter().zip(&row.params) {
        if !name.contains(".orientation.") {
            text.push(format!("{name} = {value:.4}"));
        }
    }
    SheetExtras {
        title,
        overlay: Some(overlay),
        text,
    }
}

/// What perceives the target in a run, for the page's opening sentence.
fn perception(s: &RunSettings) -> String {
    let mut text = match &s.sut {
        Some(spec) => format!("system under test <code>{}</code>", escape(spec)),
        None if s.refine_depth => format!(
            "fit <b>{}</b> laid on the depth image (<code>--refine-depth</code>)",
            escape(&s.fit)
        ),
        None => format!("fit <b>{}</b>", escape(&s.fit)),
    };
    if s.sensor_depth {
        text += ", perceiving the simulated sensor's depth (<code>--sensor-depth</code>)";
    }
    if s.two_resolutions {
        text += ", the segmenter's frame rendered at its input width and the keypoint network's \
                 window at full resolution";
    }
    text
}

fn page(
    run: &Run,
    rows: &[SampleRow],
    figures: &[(&str, &str)],
    failing: &[&SampleRow],
    drawn: &[(i64, String, String)],
) -> anyhow::Result<String> {
    let s = &run.record.settings;
    let mut h = String::new();
    let summary_path = run.dir.join("summary.json");
    let summary: Option<serde_json::Value> = std::fs::read_to_string(&summary_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>boxpose search: {}</title>",
        escape(&run.dir.display().to_string())
    )?;
    writeln!(
        h,
        "<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}img{{max-width:100%}}</style></head><body>"
    )?;
    writeln!(
        h,
        "<h1>Counterexample search</h1><p>Run <code>{}</code>: sampler <b>{}</b>, {} crops, {}; a sample fails when {}.</p>",
        escape(&run.dir.display().to_string()),
        s.sampler.name(),
        if s.crops == boxpose_search::sut::Crops::Gt {
            "ground-truth"
        } else {
            "segmenter"
        },
        perception(s),
        escape(&s.predicate.to_string())
    )?;
    estimate_section(&mut h, s, summary.as_ref(), rows)?;
    strata_section(&mut h, summary.as_ref())?;
    splitting_section(&mut h, summary.as_ref())?;
    for warning in summary
        .as_ref()
        .and_then(|v| v.get("warnings"))
        .and_then(|v| v.as_array())
        .into_iter()
        .flatten()
    {
        writeln!(
            h,
            "<p style=\"color:#b00\"><b>Warning:</b> {}</p>",
            escape(warning.as_str().unwrap_or_default())
        )?;
    }
    for (file, caption) in figures {
        writeln!(
            h,
            "<figure><img src=\"{file}\"><figcaption>{}</figcaption></figure>",
            escape(caption)
        )?;
    }
    counterexamples_section(&mut h, run, failing, drawn)?;
    writeln!(
        h,
        "<h2>Parameters</h2><p>z's dimensions, in order: {}.</p></body></html>",
        run.record
            .dimensions
            .iter()
            .map(|d| format!("<code>{}</code>", escape(d)))
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    Ok(h)
}

/// The estimate with its interval and weight diagnostics, or why there is none yet.
fn estimate_section(
    h: &mut String,
    s: &RunSettings,
    summary: Option<&serde_json::Value>,
    rows: &[SampleRow],
) -> anyhow::Result<()> {
    match summary.and_then(|v| v.get("estimate")) {
        Some(e) => {
            let f = |k: &str| e.get(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
            let ci = e.get("ci95").and_then(|v| v.as_array()).map_or(
                "none (no failure)".to_string(),
                |a| {
                    format!(
                        "[{:.3e}, {:.3e}]",
                        a[0].as_f64().unwrap_or(f64::NAN),
                        a[1].as_f64().unwrap_or(f64::NAN)
                    )
                },
            );
            // weight diagnostics mean something only where samples carry weights
            let weighted = s.sampler == Sampler::Ce;
            let diagnostics = |text: String| if weighted { text } else { "—".into() };
            writeln!(
                h,
                "<h2>Estimate</h2><table><tr><th>P(fail | valid)</th><th>95% CI</th><th>method</th><th>samples in estimate</th><th>valid</th><th>failing</th><th>spent in all</th><th>P(valid)</th><th>ESS</th><th>failure ESS</th><th>largest weight share</th></tr>\
                 <tr><td>{:.3e}</td><td>{ci}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
                f("p_hat"),
                e.get("ci_method").and_then(|v| v.as_str()).unwrap_or(""),
                f("samples"),
                f("valid"),
                f("failures"),
                rows.len(),
                if f("valid") == f("samples") {
                    1.0
                } else {
                    f("p_valid")
                },
                diagnostics(format!("{:.0}", f("kish_ess"))),
                diagnostics(format!("{:.1}", f("failure_ess"))),
                diagnostics(format!("{:.2}", f("max_weight_share"))),
            )?;
            writeln!(h, "<p>{}</p>", predicate_counts(rows))?;
        }
        None => writeln!(
            h,
            "<p>The run is not complete ({} samples so far): no estimate yet.</p>",
            rows.len()
        )?,
    }
    Ok(())
}

/// Each stratum's own estimate (clutter: one per number of neighbours), when there are several.
fn strata_section(h: &mut String, summary: Option<&serde_json::Value>) -> anyhow::Result<()> {
    let Some(strata) = summary
        .and_then(|v| v.get("strata"))
        .and_then(|v| v.as_array())
        .filter(|s| s.len() > 1)
    else {
        return Ok(());
    };
    writeln!(
        h,
        "<h2>Strata</h2><p>P(fail | valid) within each number of neighbours (each of equal nominal probability; the estimate above pools them).</p><table><tr><th>neighbours</th><th>samples</th><th>valid</th><th>failing</th><th>P(fail | valid)</th><th>95% CI</th></tr>"
    )?;
    for stratum in strata {
        let f = |k: &str| stratum.get(k).and_then(|v| v.as_f64());
        let ci = stratum
            .get("ci95")
            .and_then(|v| v.as_array())
            .map_or("—".to_string(), |a| {
                format!(
                    "[{:.3e}, {:.3e}]",
                    a[0].as_f64().unwrap_or(f64::NAN),
                    a[1].as_f64().unwrap_or(f64::NAN)
                )
            });
        writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{ci}</td></tr>",
            f("neighbours").unwrap_or(f64::NAN),
            f("samples").unwrap_or(f64::NAN),
            f("valid").unwrap_or(f64::NAN),
            f("failures").unwrap_or(f64::NAN),
            f("p_hat").map_or("—".to_string(), |p| format!("{p:.3e}")),
        )?;
    }
    writeln!(h, "</table>")?;
    Ok(())
}

/// Subset simulation's stages, when the run is one.
fn splitting_section(h: &mut String, summary: Option<&serde_json::Value>) -> anyhow::Result<()> {
    if let Some(levels) = summary
        .and_then(|v| v.pointer("/splitting/levels"))
        .and_then(|v| v.as_array())
    {
        writeln!(
            h,
            "<h2>Splitting stages</h2><p>Each stage's level (score = log10 of the metric over its threshold; the last is 0, failure), the share of its particles above it, its chains' correlation factor γ and the share of moves accepted while growing it.</p><table><tr><th>stage</th><th>level</th><th>share above</th><th>γ</th><th>chains</th><th>acceptance</th><th>evaluations</th></tr>"
        )?;
        for (i, l) in levels.iter().enumerate() {
            let f = |k: &str| l.get(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
            writeln!(
                h,
                "<tr><td>{i}</td><td>{:.4}</td><td>{:.4}</td><td>{:.2}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                f("threshold"),
                f("conditional_probability"),
                f("correlation_factor"),
                f("chains"),
                l.get("acceptance_rate")
                    .and_then(|v| v.as_f64())
                    .map_or("—".to_string(), |a| format!("{:.1}%", 100.0 * a)),
                f("evaluations"),
            )?;
        }
        writeln!(h, "</table>")?;
    }
    Ok(())
}

/// The worst counterexamples: their errors, parameter values and figures.
fn counterexamples_section(
    h: &mut String,
    run: &Run,
    failing: &[&SampleRow],
    drawn: &[(i64, String, String)],
) -> anyhow::Result<()> {
    writeln!(h, "<h2>Worst counterexamples</h2>")?;
    if failing.is_empty() {
        writeln!(h, "<p>No failing sample.</p>")?;
    } else {
        writeln!(
            h,
            "<p>Each is a scene of <code>counterexamples/</code> (scene_id = sample id): <code>boxpose render {0}/counterexamples --scene ID</code> re-renders it (each figure's caption has the command, with the <code>--crop</code> of a region render), <code>boxpose search replay {0} --sample ID</code> runs it again end to end. True box green, the network's NMS peaks red, the fitted box blue (as in the 3D views and <code>boxpose view</code>, which draws a sample's whole ground truth: <code>boxpose view {0} --sample ID</code>).</p>",
            escape(&run.dir.display().to_string())
        )?;
        writeln!(
            h,
            "<table><tr><th>sample</th><th>stage</th><th>score</th><th>paper err. (norm.)</th><th>cube MSSD/d</th><th>MSSD/d</th><th>rotation error</th><th>fit confidence</th><th>detected</th><th>fit error</th></tr>"
        )?;
        let opt = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.3e}"));
        for r in failing {
            writeln!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                r.sample_id,
                r.stage,
                r.score.map_or("∞".into(), |v| format!("{v:.2}")),
                opt(r.paper_error_normalized),
                opt(r.cube_mssd_over_diameter),
                opt(r.mssd_over_diameter),
                r.rotation_error_deg
                    .map_or("–".to_string(), |v| format!("{v:.1}°")),
                r.fit_confidence
                    .map_or("–".to_string(), |v| format!("{v:.2}")),
                r.detected.map_or("–", |d| if d { "yes" } else { "no" }),
                escape(r.fit_error.as_deref().unwrap_or(""))
            )?;
        }
        writeln!(h, "</table>")?;
        parameter_table(h, &run.record.dimensions, failing)?;
        for (id, file, command) in drawn {
            let view = file.replace(".png", "-3d.png");
            let sheet = file.replace(".png", "-sheet.png");
            writeln!(
                h,
                "<div><figure style=\"display:inline-block;width:48%\"><img src=\"{file}\" style=\"width:100%;image-rendering:pixelated\"><figcaption>sample {id}: <code>{}</code></figcaption></figure>\
                 <figure style=\"display:inline-block;width:48%\"><img src=\"{view}\"><figcaption>sample {id} in 3D (camera frame): true box green, NMS peaks red, fitted box blue</figcaption></figure>\
                 <figure><img src=\"{sheet}\" style=\"width:100%\"><figcaption>sample {id}'s ground truth (<code>boxpose view</code>): every box's corners by visibility, the depth, the instance masks, and the sample's errors and parameter values</figcaption></figure></div>",
                escape(command)
            )?;
        }
    }
    Ok(())
}
