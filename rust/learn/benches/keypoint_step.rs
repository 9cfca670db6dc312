//! Training-step and per-crop inference time of the keypoint network on one backend, printed as
//! one JSON line. `scripts/bench_learn.py` runs it beside a PyTorch implementation of the same
//! architecture and prints the ratios (`make bench-learn`).
//!
//! cargo bench -p boxpose-learn --bench keypoint_step -- [--backbone slim] [--batch 8] [--size 128]
//!     [--depth-bins 48] [--steps 10] [--backend flex]

use std::time::Instant;

use boxpose_learn::backend::BackendKind;
use boxpose_learn::config::{Backbone, NetworkConfig};
use boxpose_learn::model::KeypointNet;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use burn::tensor::Distribution;

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(|v| {
            v.parse()
                .unwrap_or_else(|_| panic!("bad value for {name}: {v}"))
        })
        .unwrap_or(default)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let backbone: String = arg(&args, "--backbone", "slim".to_string());
    let backbone: Backbone = toml::Value::String(backbone.clone())
        .try_into()
        .unwrap_or_else(|_| panic!("unknown backbone {backbone}"));
    let (batch, size, depth_bins, steps) = (
        arg(&args, "--batch", 8usize),
        arg(&args, "--size", 128usize),
        arg(&args, "--depth-bins", 48usize),
        arg(&args, "--steps", 10usize),
    );
    let backend = match arg(&args, "--backend", "flex".to_string()).as_str() {
        "flex" => BackendKind::Flex,
        "wgpu" => BackendKind::Wgpu,
        "cuda" => BackendKind::Cuda,
        "tch" => BackendKind::Tch,
        other => panic!("unknown backend {other}"),
    };
    let config = NetworkConfig {
        backbone,
        input_size: size,
        depth_bins,
        depth_range_m: [-0.12, 0.24],
        sigma_voxels: 1.0,
        crop_margin: 1.25,
        depth_scale_crop_m: None,
        peak_refine_radius: 1,
    };
    let device = backend.device().expect("backend available").autodiff();
    device.seed(0);
    let mut net = KeypointNet::keypoints(&config, &device);
    let mut optimizer = AdamConfig::new().init();
    let n = size / 4;
    let mut step_ms = Vec::new();
    for i in 0..steps + 2 {
        let input = Tensor::<4>::random(
            [batch, 4, size, size],
            Distribution::Normal(0.0, 1.0),
            &device,
        );
        let target = Tensor::<4>::random(
            [batch, depth_bins, n, n],
            Distribution::Uniform(0.0, 1.0),
            &device,
        );
        let start = Instant::now();
        let loss = (net.forward(input) - target).powi_scalar(2).mean();
        let _ = loss.clone().into_scalar::<f32>();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        net = optimizer.step(1e-3, net, grads);
        let _ = device.sync();
        if i >= 2 {
            step_ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    let inference = net.valid();
    let plain = device.clone().inner();
    let per_crop = |crops: usize, repeats: usize| -> f64 {
        let mut times = Vec::new();
        for i in 0..repeats + 1 {
            let input = Tensor::<4>::random(
                [crops, 4, size, size],
                Distribution::Normal(0.0, 1.0),
                &plain,
            );
            let start = Instant::now();
            let _ = inference.forward(input).into_data();
            if i >= 1 {
                times.push(start.elapsed().as_secs_f64() * 1e3 / crops as f64);
            }
        }
        median(times)
    };
    let crop_ms_batch1 = per_crop(1, 10);
    let crop_ms_batch16 = per_crop(16, 3);
    println!(
        "{{\"implementation\": \"burn-{}\", \"backbone\": \"{:?}\", \"batch\": {batch}, \"size\": {size}, \"depth_bins\": {depth_bins}, \"train_step_ms\": {:.1}, \"crop_ms_batch1\": {:.2}, \"crop_ms_batch16\": {:.2}}}",
        backend.name(),
        backbone,
        median(step_ms),
        crop_ms_batch1,
        crop_ms_batch16
    );
}
