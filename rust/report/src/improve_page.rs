//! `boxpose improve`'s rounds: one CSV row and one HTML table row per round, each round's failure
//! rate before and after on the common evaluation inputs with its interval, the fixed and new
//! failures, McNemar's p and the held-out pairings; with a control arm, the loop's networks
//! against the control's.

use std::fmt::Write as _;
use std::path::Path;

use boxpose_search::compare::{BoxKey, PairedComparison, Rate};

use crate::html::escape;

/// One round of the loop as the pages show it.
pub struct Round {
    pub round: usize,
    /// Failures of the round's search (what the round could learn from).
    pub search_failures: usize,
    /// Whether the round fine-tuned (a search without failure leaves the networks).
    pub fine_tuned: bool,
    /// The round's networks before and after, paired sample by sample on the evaluation inputs.
    pub evaluation: PairedComparison,
    /// The same, box by box on each held-out dataset (its name first).
    pub held_out: Vec<(String, PairedComparison<BoxKey>)>,
    /// With a control arm: its networks (before) against the loop's (after) after this round.
    pub against_control: Option<AgainstControl>,
}

/// The equal-budget control's networks ("before") paired with the loop's ("after") of a round:
/// on the evaluation inputs, and box by box on each held-out dataset.
pub struct AgainstControl {
    pub evaluation: PairedComparison,
    pub held_out: Vec<(String, PairedComparison<BoxKey>)>,
}

/// What the loop ran, for the page's opening sentence.
pub struct LoopSettings<'a> {
    pub space: &'a str,
    pub model: &'a Path,
    /// The segmenter and whether the loop fine-tunes it too.
    pub segmenter: Option<(&'a Path, bool)>,
    pub fit: &'a str,
    pub crops: &'a str,
    pub fail_when: &'a str,
    pub evaluation_samples: usize,
    pub evaluation_seed: u64,
    /// Whether an equal-budget control arm ran beside the loop.
    pub control: bool,
}

/// `rounds.csv`: one row per round, what it learnt from and its paired evaluation, and with a
/// control arm the control's failures on the same pairs and the loop's fixed / new against it
/// (empty without one).
pub fn write_rounds_csv(path: &Path, rounds: &[Round]) -> anyhow::Result<()> {
    let mut text = String::from(
        "round,search_failures,fine_tuned,pairs,failures_before,p_before,p_before_lo,p_before_hi,\
         failures_after,p_after,p_after_lo,p_after_hi,fixed,new,mcnemar_p,control_pairs,\
         control_failures,control_p,control_p_lo,control_p_hi,fixed_against_control,\
         new_against_control,control_mcnemar_p\n",
    );
    for r in rounds {
        let c = &r.evaluation;
        let control = r.against_control.as_ref().map_or(",,,,,,,".into(), |a| {
            let c = &a.evaluation;
            format!(
                "{},{},{},{},{}",
                c.pairs,
                rate_fields(&c.before),
                c.fixed.len(),
                c.new.len(),
                csv_real(c.mcnemar_p)
            )
        });
        writeln!(
            text,
            "{},{},{},{},{},{},{},{},{},{control}",
            r.round,
            r.search_failures,
            r.fine_tuned,
            c.pairs,
            rate_fields(&c.before),
            rate_fields(&c.after),
            c.fixed.len(),
            c.new.len(),
            csv_real(c.mcnemar_p),
        )?;
    }
    Ok(boxpose_data::write_file_atomically(path, text.as_bytes())?)
}

/// A rate's four CSV fields: failures, p̂ and its 95 % interval.
fn rate_fields(rate: &Rate) -> String {
    format!(
        "{},{},{},{}",
        rate.failures,
        csv_real(rate.p_hat),
        csv_real(rate.ci95.0),
        csv_real(rate.ci95.1)
    )
}

/// A real number as a CSV field that reads back exactly: Rust's shortest round-trip digits, with
/// an exponent for very small values (a McNemar p of 1e-100 would otherwise be written as a
/// hundred zeros and its digits).
fn csv_real(x: f64) -> String {
    if x == 0.0 || (1e-4..1e16).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// `report.html`: the rounds at a glance, and a link to each network's evaluation report (its
/// worst remaining counterexamples, drawn) under `eval/model-N/report/`.
pub fn write_rounds_page(
    path: &Path,
    settings: &LoopSettings,
    rounds: &[Round],
) -> anyhow::Result<()> {
    let mut h = String::new();
    writeln!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>boxpose improve: {space}</title>\
         <style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}</style></head><body>\
         <h1>The loop on <code>{space}</code></h1><p>From <code>{model}</code>{segmenter}, fit {fit}, {crops} crops; a sample \
         fails when {fail}. Each round is judged on the same {n} evaluation samples (seed {seed}), never searched.</p>",
        space = escape(settings.space),
        model = escape(&settings.model.display().to_string()),
        segmenter = match settings.segmenter {
            Some((s, true)) => format!(
                " and the segmenter <code>{}</code>, both fine-tuned in every round that learns",
                escape(&s.display().to_string())
            ),
            Some((s, false)) => format!(
                " with the segmenter <code>{}</code> (not fine-tuned)",
                escape(&s.display().to_string())
            ),
            None => String::new(),
        },
        fit = escape(settings.fit),
        crops = escape(settings.crops),
        fail = escape(settings.fail_when),
        n = settings.evaluation_samples,
        seed = settings.evaluation_seed,
    )?;
    writeln!(
        h,
        "<table><tr><th>round</th><th>search failures</th><th>fine-tuned</th><th>p̂ before</th>\
         <th>p̂ after</th><th>fixed</th><th>new</th><th>McNemar p</th><th>held out: success before → after (fixed / new, p)</th>{}</tr>",
        if settings.control {
            "<th>the equal-budget control: its p̂; the loop's fixed / new against it, p; held out</th>"
        } else {
            ""
        }
    )?;
    for r in rounds {
        let c = &r.evaluation;
        writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.3e}</td><td>{}</td>{}</tr>",
            r.round,
            r.search_failures,
            if r.fine_tuned { "yes" } else { "no failure" },
            percent(&c.before),
            percent(&c.after),
            c.fixed.len(),
            c.new.len(),
            c.mcnemar_p,
            held_out_cell(&r.held_out),
            r.against_control
                .as_ref()
                .map_or(String::new(), control_cell),
        )?;
    }
    writeln!(h, "</table><h2>Each network's evaluation</h2><ul>")?;
    for network in 0..=rounds.len() {
        writeln!(
            h,
            "<li>network {network}: <a href=\"eval/model-{network}/report/index.html\">its evaluation report</a> \
             (the worst remaining counterexamples, drawn)</li>"
        )?;
    }
    writeln!(h, "</ul></body></html>")?;
    Ok(boxpose_data::write_file_atomically(path, h.as_bytes())?)
}

/// The control's cell of a round: its failure rate on the pairs, the loop's fixed / new against
/// it with McNemar's p, and the held-out pairings against it.
fn control_cell(a: &AgainstControl) -> String {
    let c = &a.evaluation;
    format!(
        "<td>{}; {} / {}, {:.2e}<br>{}</td>",
        percent(&c.before),
        c.fixed.len(),
        c.new.len(),
        c.mcnemar_p,
        held_out_cell(&a.held_out)
    )
}

/// A failure rate as the rounds page shows it: percent with its interval and counts.
fn percent(r: &Rate) -> String {
    format!(
        "{:.2} % [{:.2}, {:.2}] ({} of {})",
        100.0 * r.p_hat,
        100.0 * r.ci95.0,
        100.0 * r.ci95.1,
        r.failures,
        r.samples
    )
}

/// One round's held-out pairings: each set's success before → after, fixed / new, McNemar's p.
fn held_out_cell(held: &[(String, PairedComparison<BoxKey>)]) -> String {
    held.iter()
        .map(|(name, c)| {
            format!(
                "{}: {:.1} → {:.1} % ({} / {}, {:.2e})",
                escape(name),
                success_percent(&c.before),
                success_percent(&c.after),
                c.fixed.len(),
                c.new.len(),
                c.mcnemar_p
            )
        })
        .collect::<Vec<_>>()
        .join("<br>")
}

/// The share of a rate's samples that succeeded, in percent.
pub fn success_percent(r: &Rate) -> f64 {
    100.0 * (r.samples - r.failures) as f64 / r.samples.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loop_settings(space: &str, evaluation_samples: usize, control: bool) -> LoopSettings<'_> {
        LoopSettings {
            space,
            model: Path::new("m"),
            segmenter: None,
            fit: "paper",
            crops: "gt",
            fail_when: "paper",
            evaluation_samples,
            evaluation_seed: 1_000_000,
            control,
        }
    }

    #[test]
    fn the_pages_hold_one_row_per_round() {
        let dir = std::env::temp_dir().join(format!("boxpose-improve-page-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // 100 samples: 0..10 failed before, 7..11 after (7 fixed, 1 new)
        let before: Vec<(i64, bool)> = (0..100).map(|i| (i, i < 10)).collect();
        let after: Vec<(i64, bool)> = (0..100).map(|i| (i, (7..11).contains(&i))).collect();
        let evaluation = boxpose_search::compare::pair(&before, &after);
        let rounds = [Round {
            round: 0,
            search_failures: 12,
            fine_tuned: true,
            evaluation,
            held_out: Vec::new(),
            against_control: None,
        }];
        write_rounds_csv(&dir.join("rounds.csv"), &rounds).unwrap();
        let csv = std::fs::read_to_string(dir.join("rounds.csv")).unwrap();
        assert_eq!(csv.lines().count(), 2);
        assert!(
            csv.lines()
                .nth(1)
                .unwrap()
                .starts_with("0,12,true,100,10,0.1,")
        );
        let settings = loop_settings("a<b", 100, false);
        write_rounds_page(&dir.join("report.html"), &settings, &rounds).unwrap();
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        assert!(html.contains("a&lt;b"));
        assert!(html.contains("10.00 % [4.90, 17.62] (10 of 100)"), "{html}");
        assert!(html.contains("<td>7</td><td>1</td>"));
        assert!(html.contains("eval/model-1/report/index.html"));
        assert!(!html.contains("equal-budget control"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_control_arm_adds_its_columns_and_a_round_without_one_leaves_them_empty() {
        let dir = std::env::temp_dir().join(format!("boxpose-control-page-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let outcomes = |failing: std::ops::Range<i64>| -> Vec<(i64, bool)> {
            (0..50).map(|i| (i, failing.contains(&i))).collect()
        };
        let round = |round, against_control| Round {
            round,
            search_failures: 3,
            fine_tuned: true,
            evaluation: boxpose_search::compare::pair(&outcomes(0..10), &outcomes(0..2)),
            held_out: Vec::new(),
            against_control,
        };
        // the control fails 0..6, the loop 0..2: 4 fixed against it, none new
        let control = AgainstControl {
            evaluation: boxpose_search::compare::pair(&outcomes(0..6), &outcomes(0..2)),
            held_out: Vec::new(),
        };
        let rounds = [round(0, Some(control)), round(1, None)];
        write_rounds_csv(&dir.join("rounds.csv"), &rounds).unwrap();
        let csv = std::fs::read_to_string(dir.join("rounds.csv")).unwrap();
        let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
        let column = |name: &str| rows[0].iter().position(|c| *c == name).unwrap();
        assert!(rows.iter().all(|r| r.len() == rows[0].len()), "{csv}");
        assert_eq!(rows[1][column("control_failures")], "6");
        assert_eq!(rows[1][column("fixed_against_control")], "4");
        assert_eq!(rows[1][column("new_against_control")], "0");
        assert_eq!(rows[2][column("control_failures")], "");
        let settings = loop_settings("s", 50, true);
        write_rounds_page(&dir.join("report.html"), &settings, &rounds).unwrap();
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        assert!(html.contains("equal-budget control"));
        assert!(
            html.contains("12.00 % [4.53, 24.31] (6 of 50); 4 / 0"),
            "{html}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn csv_reals_read_back_exactly_and_tiny_p_values_are_short() {
        for x in [
            0.0,
            1.0,
            0.347,
            0.0022049824851509,
            1e-4,
            9.99e-5,
            3.839723267588848e-101,
        ] {
            let text = csv_real(x);
            assert_eq!(text.parse::<f64>().unwrap(), x, "{text}");
            assert!(text.len() <= 24, "{text}");
        }
        assert_eq!(csv_real(0.347), "0.347");
        assert_eq!(csv_real(3.84e-101), "3.84e-101");
    }
}
