//! Criterion benches: the paper's brute-force search, the exact branch and bound and the robust
//! fit on the same scenes (figures per box via the element throughput), the pose-and-size fit,
//! and NMS of 8 peaks from a 64³ heatmap.
//!
//! cargo bench -p boxpose-geometry --bench geometry

mod common;

use std::hint::black_box;

use boxpose_geometry::correspondence::{PAPER_PEAKS_USED, fast_exact_search, paper_exact_search};
use boxpose_geometry::heatmap::{
    HeatmapDims, NmsParams, VoxelCoord, non_maximum_suppression, render_target_heatmap,
};
use boxpose_geometry::robust::{RobustParams, robust_fit};
use boxpose_geometry::size_fit::{SizeFitParams, fit_pose_and_size};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SCENES: usize = 16;

fn correspondence(c: &mut Criterion) {
    for (name, outliers) in [("clean", 0..=0), ("outliers_1_to_2", 1..=2)] {
        let scenes = common::scenes(SCENES, 2024, outliers);
        let mut group = c.benchmark_group(format!("pose_from_8_peaks_{name}"));
        group.throughput(Throughput::Elements(SCENES as u64));
        group.sample_size(10);
        group.bench_function("paper_exact_m5", |b| {
            b.iter(|| {
                for s in &scenes {
                    black_box(
                        paper_exact_search(
                            &s.model,
                            black_box(&s.points),
                            &s.scores,
                            PAPER_PEAKS_USED,
                        )
                        .unwrap(),
                    );
                }
            })
        });
        group.sample_size(50);
        group.bench_function("fast_exact_m5", |b| {
            b.iter(|| {
                for s in &scenes {
                    black_box(
                        fast_exact_search(
                            &s.model,
                            black_box(&s.points),
                            &s.scores,
                            PAPER_PEAKS_USED,
                        )
                        .unwrap(),
                    );
                }
            })
        });
        group.bench_function("robust_fit", |b| {
            b.iter(|| {
                for s in &scenes {
                    black_box(
                        robust_fit(
                            &s.model,
                            black_box(&s.points),
                            &RobustParams::for_box(&s.model),
                        )
                        .unwrap(),
                    );
                }
            })
        });
        group.bench_function("pose_and_size_fit", |b| {
            b.iter(|| {
                for s in &scenes {
                    black_box(
                        fit_pose_and_size(black_box(&s.points), &SizeFitParams::default()).unwrap(),
                    );
                }
            })
        });
        group.finish();
    }
}

fn nms(c: &mut Criterion) {
    let dims = HeatmapDims {
        depth: 64,
        height: 64,
        width: 64,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let corners: Vec<VoxelCoord> = (0..8)
        .map(|_| VoxelCoord {
            z_bin: rng.random_range(8.0..56.0),
            v: rng.random_range(8.0..56.0),
            u: rng.random_range(8.0..56.0),
        })
        .collect();
    let mut volume = render_target_heatmap(dims, &corners, 2.0).unwrap();
    // A network's output is never clean: add low-level clutter everywhere.
    for x in volume.iter_mut() {
        *x += rng.random_range(0.0..0.05f32);
    }
    let params = NmsParams {
        count: 8,
        sigma: 2.0,
        refine_radius: 0,
    };
    c.bench_function("nms_64x64x64_8_peaks", |b| {
        b.iter(|| black_box(non_maximum_suppression(black_box(&volume), dims, &params).unwrap()))
    });
    let refined = NmsParams {
        refine_radius: 1,
        ..params
    };
    c.bench_function("nms_64x64x64_8_peaks_refined", |b| {
        b.iter(|| black_box(non_maximum_suppression(black_box(&volume), dims, &refined).unwrap()))
    });
}

criterion_group!(benches, correspondence, nms);
criterion_main!(benches);
