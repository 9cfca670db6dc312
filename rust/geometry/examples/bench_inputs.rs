//! Times the paper's brute-force correspondence search and the exact branch and bound on the
//! benchmark scenes (0–2 outliers among the 8 peaks), and writes the scenes with both results as JSON for
//! `scripts/bench_geometry_numpy.py`, which times a batched NumPy brute force on the same inputs.
//!
//! cargo run --release -p boxpose-geometry --example bench_inputs -- OUT.json [SCENES]

#[path = "../benches/common/mod.rs"]
mod common;

use std::fmt::Write as _;
use std::hint::black_box;
use std::time::Instant;

use boxpose_geometry::correspondence::{PAPER_PEAKS_USED, fast_exact_search, paper_exact_search};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = args.next().ok_or("usage: bench_inputs OUT.json [SCENES]")?;
    let count: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(200);
    let scenes = common::scenes(count, 2024, 0..=2);
    let m = PAPER_PEAKS_USED;

    let started = Instant::now();
    let paper: Vec<_> = scenes
        .iter()
        .map(|s| paper_exact_search(&s.model, &s.points, &s.scores, m))
        .collect::<Result<_, _>>()?;
    let paper_seconds = started.elapsed().as_secs_f64() / count as f64;

    // The fast search takes microseconds: repeat it to get above the clock's resolution.
    let repeats = 200;
    let started = Instant::now();
    for _ in 0..repeats {
        for s in &scenes {
            black_box(fast_exact_search(
                &s.model,
                black_box(&s.points),
                &s.scores,
                m,
            )?);
        }
    }
    let fast_seconds = started.elapsed().as_secs_f64() / (count * repeats) as f64;
    let fast: Vec<_> = scenes
        .iter()
        .map(|s| fast_exact_search(&s.model, &s.points, &s.scores, m))
        .collect::<Result<_, _>>()?;

    let triple = |v: &[f64]| format!("[{:.17e},{:.17e},{:.17e}]", v[0], v[1], v[2]);
    let mut json = String::new();
    write!(
        json,
        "{{\"m\":{m},\"rust_paper_exact_seconds_per_box\":{paper_seconds:e},\"rust_fast_exact_seconds_per_box\":{fast_seconds:e},\"scenes\":["
    )?;
    for (i, (s, (p, f))) in scenes.iter().zip(paper.iter().zip(&fast)).enumerate() {
        let points: Vec<String> = s
            .points
            .iter()
            .map(|p| triple(p.coords.as_slice()))
            .collect();
        let scores: Vec<String> = s.scores.iter().map(|x| format!("{x:.17e}")).collect();
        write!(
            json,
            "{}{{\"size\":{},\"points\":[{}],\"scores\":[{}],\"paper_sse\":{:.17e},\"fast_sse\":{:.17e}}}",
            if i == 0 { "" } else { "," },
            triple(s.model.size().as_slice()),
            points.join(","),
            scores.join(","),
            p.sum_squared_error,
            f.sum_squared_error,
        )?;
    }
    json.push_str("]}\n");
    std::fs::write(&out, json)?;
    println!(
        "{count} boxes, m = {m}: paper-exact {:.1} µs/box, fast exact {:.2} µs/box ({:.0}× faster); wrote {out}",
        paper_seconds * 1e6,
        fast_seconds * 1e6,
        paper_seconds / fast_seconds
    );
    Ok(())
}
