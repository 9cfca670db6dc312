//! The keypoint network's parts on the real flex backend: a training step, the target's round
//! trip through NMS and back-projection, and a saved model's identical outputs after loading.

use boxpose_data::Intrinsics;
use boxpose_geometry::BoxModel;
use boxpose_learn::config::{Backbone, NetworkConfig};
use boxpose_learn::data::{self, CropWindow};
use boxpose_learn::inference::{self, KeypointModel};
use boxpose_learn::model::KeypointNet;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use burn::tensor::Distribution;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

fn tiny_config() -> NetworkConfig {
    NetworkConfig {
        backbone: Backbone::Tiny,
        input_size: 64,
        depth_bins: 8,
        depth_range_m: [-0.12, 0.24],
        sigma_voxels: 1.0,
        crop_margin: 1.25,
        depth_scale_crop_m: None,
        peak_refine_radius: 1,
    }
}

#[test]
fn a_training_step_runs_forward_and_backward_and_lowers_the_loss() {
    let config = tiny_config();
    let device = Device::flex().autodiff();
    device.seed(1);
    let mut net = KeypointNet::keypoints(&config, &device);
    let input = Tensor::<4>::random([2, 4, 64, 64], Distribution::Normal(0.0, 1.0), &device);
    let target = Tensor::<4>::random([2, 8, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
    let output = net.forward(input.clone());
    assert_eq!(
        output.dims(),
        [2, 8, 16, 16],
        "one D×(S/4)×(S/4) heatmap per crop"
    );
    let mut optimizer = AdamConfig::new().init();
    let mut losses = Vec::new();
    for _ in 0..5 {
        let loss = (net.forward(input.clone()) - target.clone())
            .powi_scalar(2)
            .mean();
        losses.push(loss.clone().into_scalar::<f32>() as f64);
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        assert!(!grads.is_empty(), "every parameter gets a gradient");
        net = optimizer.step(1e-2, net, grads);
    }
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(
        losses[4] < losses[0],
        "five Adam steps on one batch lower its loss: {losses:?}"
    );
}

/// A box's 8 corners (camera frame), a crop's voxel grid around them and their target heatmap.
type BoxTarget = (
    [[f64; 3]; 8],
    boxpose_geometry::heatmap::VoxelGrid,
    Vec<f32>,
);

/// [`BoxTarget`] of one box at the shipped network's heatmap shape.
fn target_of_a_box(config: &NetworkConfig) -> BoxTarget {
    target_of_a_scaled_box(config, 1.0).unwrap()
}

/// [`target_of_a_box`] with the box and its distance `scale` times larger: the same image.
fn target_of_a_scaled_box(
    config: &NetworkConfig,
    scale: f64,
) -> Result<BoxTarget, boxpose_learn::LearnError> {
    let k = Intrinsics {
        fx: 600.0,
        fy: 600.0,
        cx: 320.0,
        cy: 240.0,
    };
    let model = BoxModel::new(Vector3::new(0.2, 0.16, 0.12) * scale).unwrap();
    let pose = Isometry3::from_parts(
        Translation3::new(0.03 * scale, -0.02 * scale, 1.2 * scale),
        UnitQuaternion::from_euler_angles(0.5, -0.3, 0.8),
    );
    let corners: [[f64; 3]; 8] = model.corners().map(|c| (pose * c).coords.into());
    let pixels: Vec<[f64; 2]> = corners.iter().map(|c| k.project(*c)).collect();
    let lo = pixels
        .iter()
        .fold([f64::MAX; 2], |a, p| [a[0].min(p[0]), a[1].min(p[1])]);
    let hi = pixels
        .iter()
        .fold([f64::MIN; 2], |a, p| [a[0].max(p[0]), a[1].max(p[1])]);
    let window = CropWindow::around(
        [
            lo[0] as i32,
            lo[1] as i32,
            hi[0] as i32 + 1,
            hi[1] as i32 + 1,
        ],
        1.3,
    );
    let grid = data::voxel_grid(config, &k, &window, 1.15 * scale);
    let target = data::target_heatmap(config, &grid, &corners)?;
    Ok((corners, grid, target))
}

/// Each true corner's offset (u, v, z-bin), in voxels, from the nearest decoded peak.
fn peak_offsets(config: &NetworkConfig) -> Vec<[f64; 3]> {
    let (corners, grid, target) = target_of_a_box(config);
    let (peaks, points) = inference::decode(config, &target, &grid).unwrap();
    assert_eq!(peaks.len(), 8);
    corners
        .iter()
        .map(|corner| {
            let truth = grid.project(&Point3::from(*corner)).unwrap();
            let offset = |c: &boxpose_geometry::heatmap::VoxelCoord| {
                [c.u - truth.u, c.v - truth.v, c.z_bin - truth.z_bin]
            };
            points
                .iter()
                .map(|p| offset(&grid.project(p).unwrap()))
                .min_by(|a, b| {
                    let squared = |o: &[f64; 3]| o.iter().map(|x| x * x).sum::<f64>();
                    squared(a).total_cmp(&squared(b))
                })
                .unwrap()
        })
        .collect()
}

fn shipped_shape() -> NetworkConfig {
    NetworkConfig {
        input_size: 128,
        depth_bins: 48,
        ..tiny_config()
    }
}

#[test]
fn the_target_heatmap_through_nms_and_back_projection_recovers_the_corners_within_half_a_voxel() {
    for (corner, offset) in peak_offsets(&shipped_shape()).iter().enumerate() {
        for (axis, error) in ["u", "v", "z"].iter().zip(offset) {
            assert!(
                error.abs() < 0.5,
                "corner {corner}: {axis} off by {error:.3} voxels"
            );
        }
    }
}

#[test]
fn the_peak_refine_radius_moves_peaks_off_the_voxel_centres_and_closer_to_the_corners() {
    let mean_distance = |offsets: &[[f64; 3]]| {
        offsets
            .iter()
            .map(|o| o.iter().map(|x| x * x).sum::<f64>().sqrt())
            .sum::<f64>()
            / offsets.len() as f64
    };
    let at_centres = peak_offsets(&NetworkConfig {
        peak_refine_radius: 0,
        ..shipped_shape()
    });
    let refined = peak_offsets(&shipped_shape());
    let (unrefined_error, refined_error) = (mean_distance(&at_centres), mean_distance(&refined));
    assert!(
        refined_error < 0.7 * unrefined_error,
        "radius 1: {refined_error:.3} voxels from the corners, radius 0: {unrefined_error:.3}"
    );
    // Radius 0 keeps voxel centres: the truth's fractional part is the whole offset.
    let (corners, grid, _) = target_of_a_box(&shipped_shape());
    for (corner, offset) in corners.iter().zip(&at_centres) {
        let truth = grid.project(&Point3::from(*corner)).unwrap();
        for (t, o) in [truth.u, truth.v, truth.z_bin].iter().zip(offset) {
            assert!(
                ((t + o) - (t + o).round()).abs() < 1e-9,
                "radius 0 put a peak off a voxel centre"
            );
        }
    }
}

/// The shipped shape with its depth axis scaled with the crop, the range it has at a 0.2 m crop.
fn crop_scaled_shape() -> NetworkConfig {
    NetworkConfig {
        depth_scale_crop_m: Some(0.2),
        ..shipped_shape()
    }
}

#[test]
fn a_crop_scaled_depth_axis_sees_a_five_times_larger_box_five_times_farther_as_the_same_box() {
    let config = crop_scaled_shape();
    let (_, grid, near) = target_of_a_scaled_box(&config, 1.0).unwrap();
    let (corners, far_grid, far) = target_of_a_scaled_box(&config, 5.0).unwrap();
    let largest = near
        .iter()
        .zip(&far)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(largest < 1e-4, "the targets differ by up to {largest}");
    assert!((far_grid.depth.bin_size / grid.depth.bin_size - 5.0).abs() < 1e-9);
    // And the 1 m box decodes back onto its corners, within half a voxel.
    let (_, points) = inference::decode(&config, &far, &far_grid).unwrap();
    let bin_m = far_grid.depth.bin_size;
    for corner in corners {
        let nearest = points
            .iter()
            .map(|p| (p.coords - Vector3::from(corner)).norm())
            .fold(f64::MAX, f64::min);
        assert!(
            nearest < bin_m,
            "a corner {nearest:.4} m from every peak (bin {bin_m:.4} m)"
        );
    }
    // A fixed range of 0.36 m cannot hold the 1 m box's corners at all.
    let fixed = target_of_a_scaled_box(&shipped_shape(), 5.0);
    let left_out = fixed.map_or(true, |(_, _, t)| {
        let total: f32 = t.iter().sum();
        total < 0.9 * near.iter().sum::<f32>()
    });
    assert!(left_out, "a fixed depth range held a 1 m box");
}

#[test]
fn a_crop_scaled_run_may_start_from_fixed_range_weights_but_not_the_reverse() {
    assert!(crop_scaled_shape().can_fine_tune_from(&shipped_shape()));
    assert!(!shipped_shape().can_fine_tune_from(&crop_scaled_shape()));
    let other_width = NetworkConfig {
        depth_scale_crop_m: Some(0.3),
        ..shipped_shape()
    };
    assert!(!other_width.can_fine_tune_from(&crop_scaled_shape()));
    let bad = NetworkConfig {
        depth_scale_crop_m: Some(0.0),
        ..shipped_shape()
    };
    assert!(bad.validate().is_err());
}

#[test]
fn a_network_toml_written_before_peak_refine_radius_existed_decodes_with_the_ablations_choice() {
    // The shipped keypoint-slim's network.toml as written on 2026-12-02, before the field.
    let text = "backbone = \"slim\"\ninput_size = 128\ndepth_bins = 48\n\
                depth_range_m = [-0.12, 0.24]\nsigma_voxels = 1.5\ncrop_margin = 1.25\n";
    let config: NetworkConfig = toml::from_str(text).unwrap();
    assert_eq!(config.peak_refine_radius, 2);
}

#[test]
fn fine_tuning_may_change_the_target_width_and_the_decoding_window_but_nothing_that_shapes_the_weights()
 {
    let trained = shipped_shape();
    let retargeted = NetworkConfig {
        sigma_voxels: 2.0,
        peak_refine_radius: 3,
        ..shipped_shape()
    };
    assert!(retargeted.can_fine_tune_from(&trained));
    let reshaped = [
        NetworkConfig {
            backbone: Backbone::Slim,
            ..shipped_shape()
        },
        NetworkConfig {
            input_size: 256,
            ..shipped_shape()
        },
        NetworkConfig {
            depth_bins: 32,
            ..shipped_shape()
        },
        NetworkConfig {
            depth_range_m: [-0.1, 0.2],
            ..shipped_shape()
        },
        NetworkConfig {
            crop_margin: 1.5,
            ..shipped_shape()
        },
    ];
    for other in reshaped {
        assert!(!other.can_fine_tune_from(&trained), "{other:?}");
    }
}

#[test]
fn a_saved_model_loads_with_identical_outputs() {
    let config = tiny_config();
    let device = Device::flex();
    device.seed(7);
    let net = KeypointNet::keypoints(&config, &device.clone().autodiff());
    // a few steps so that the batch-norm running statistics differ from their initial values
    let mut net = net;
    let mut optimizer = AdamConfig::new().init();
    let train_device = device.clone().autodiff();
    for _ in 0..2 {
        let input = Tensor::<4>::random(
            [2, 4, 64, 64],
            Distribution::Normal(0.5, 1.0),
            &train_device,
        );
        let loss = net.forward(input).powi_scalar(2).mean();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        net = optimizer.step(1e-2, net, grads);
    }
    let dir = std::env::temp_dir().join(format!("boxpose-learn-test-{}", std::process::id()));
    let model_dir = dir.join("model");
    KeypointModel::save(&config, &net.valid(), &model_dir).unwrap();
    let loaded = KeypointModel::load(&model_dir, device.clone()).unwrap();
    assert_eq!(loaded.config, config);
    let original = KeypointModel {
        config: config.clone(),
        net: net.valid(),
        device: device.clone(),
    };
    let inputs: Vec<Vec<f32>> = (0..3)
        .map(|i| {
            (0..4 * 64 * 64)
                .map(|j| ((i * 31 + j) % 97) as f32 / 50.0 - 1.0)
                .collect()
        })
        .collect();
    assert_eq!(
        original.heatmaps(&inputs, 2).unwrap(),
        loaded.heatmaps(&inputs, 2).unwrap()
    );

    // a missing or corrupt file names itself
    std::fs::write(model_dir.join("model.bpk"), b"junk").unwrap();
    let error = KeypointModel::load(&model_dir, device)
        .err()
        .expect("corrupt weights are refused")
        .to_string();
    assert!(error.contains("model.bpk"), "{error}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// A 64×48 frame with two rectangular boxes (object ids 0 and 3) on a background at 1 m.
fn two_box_frame() -> boxpose_data::Frame {
    let (width, height) = (64usize, 48usize);
    let mut mask = vec![0u16; width * height];
    let mut instances = Vec::new();
    for (object_id, [x0, y0, x1, y1]) in [(0i32, [4i32, 6, 24, 30]), (3, [34, 10, 58, 40])] {
        for y in y0..y1 {
            for x in x0..x1 {
                mask[y as usize * width + x as usize] = (object_id + 1) as u16;
            }
        }
        instances.push(boxpose_data::Instance {
            scene_id: 0,
            frame_id: 0,
            object_id,
            size: [0.1, 0.1, 0.1],
            camera_box: boxpose_data::Pose {
                quat_wxyz: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0, 0.0, 1.0],
            },
            corners_camera: [[0.0, 0.0, 1.0]; 8],
            corners_px: [[0.0, 0.0]; 8],
            visibility: [boxpose_data::Visibility::Visible; 8],
            label_keypoints_camera: None,
            label_keypoints_px: None,
            visible_bbox: Some([x0, y0, x1, y1]),
            visible_pixels: (x1 - x0) * (y1 - y0),
            visible_fraction: 1.0,
        });
    }
    boxpose_data::Frame {
        scene_id: 0,
        frame_id: 0,
        width,
        height,
        intrinsics: Intrinsics {
            fx: 60.0,
            fy: 60.0,
            cx: 32.0,
            cy: 24.0,
        },
        world_camera: boxpose_data::Pose {
            quat_wxyz: [1.0, 0.0, 0.0, 0.0],
            translation: [0.0; 3],
        },
        samples: 1,
        denoise: false,
        render_seed: 0,
        blender_version: String::new(),
        rgb: vec![128; width * height * 3],
        depth: mask
            .iter()
            .map(|&m| if m > 0 { 0.9 } else { 1.0 })
            .collect(),
        instance_mask: mask,
        sensor_depth: None,
        instances,
    }
}

/// A tiny segmenter's settings: 64×64 input, read at that size.
fn tiny_segmenter() -> boxpose_learn::segmentation::SegmenterConfig {
    boxpose_learn::segmentation::SegmenterConfig {
        backbone: Backbone::Tiny,
        input_width: 64,
        input_height: 64,
        centre_sigma: 1.5,
        centre_weight: 1.0,
        offset_weight: 1.0,
        foreground_threshold: 0.5,
        centre_threshold: 0.5,
        min_pixels: 2,
        inference_width: None,
        inference_height: None,
    }
}

#[test]
fn the_segmenter_targets_decode_back_into_the_true_instances() {
    use boxpose_learn::segmentation;
    let config = tiny_segmenter();
    let frame = two_box_frame();
    let target = segmentation::frame_targets(&config, &frame);
    let plane = 16 * 16;
    // a perfect output: confident foreground logits, the target centres and offsets
    let mut output = target[..4 * plane].to_vec();
    output[..plane]
        .iter_mut()
        .for_each(|v| *v = if *v > 0.5 { 10.0 } else { -10.0 });
    let detections = segmentation::decode(&config, &frame, &output);
    assert_eq!(detections.len(), 2, "one detection per box");
    let found = segmentation::match_detections(&frame, &detections, 0.7);
    assert!(
        found.iter().all(Option::is_some),
        "every box matched with mask IoU ≥ 0.7: {found:?}"
    );
    let scores = segmentation::score_detections(&[&frame], std::slice::from_ref(&detections));
    assert_eq!((scores.mask_ap50, scores.bbox_ap50), (1.0, 1.0));
    // a false positive with the best score lowers precision at every recall
    let mut noisy = detections;
    noisy.insert(
        0,
        segmentation::Detection {
            mask: vec![false; 64 * 48],
            bbox: [60, 0, 64, 4],
            score: 2.0,
        },
    );
    let scores = segmentation::score_detections(&[&frame], &[noisy]);
    assert!(
        scores.bbox_ap50 < 0.75 && scores.bbox_ap50 > 0.4,
        "{scores:?}"
    );
}

#[test]
fn a_detection_carried_to_the_same_view_at_twice_the_resolution_or_a_region_of_it_covers_the_same_pixels()
 {
    use boxpose_learn::segmentation::Detection;
    let small = two_box_frame();
    let label = 4u16; // object 3
    let detection = Detection {
        mask: small.instance_mask.iter().map(|&m| m == label).collect(),
        bbox: [34, 10, 58, 40],
        score: 0.9,
    };
    // the same view twice as large: pixel centres k ↦ 2k + 0.5, so edges e ↦ 2e
    let i = small.intrinsics;
    let mut large = two_box_frame();
    (large.width, large.height) = (128, 96);
    large.intrinsics = Intrinsics {
        fx: 2.0 * i.fx,
        fy: 2.0 * i.fy,
        cx: 2.0 * i.cx + 0.5,
        cy: 2.0 * i.cy + 0.5,
    };
    let carried = detection.carried_to(&small, &large);
    assert_eq!(carried.bbox, [68, 20, 116, 80]);
    assert_eq!(carried.score, 0.9);
    let count = |mask: &[bool]| mask.iter().filter(|&&m| m).count();
    assert_eq!(count(&carried.mask), 4 * count(&detection.mask));
    assert!(carried.mask[25 * 128 + 70] && !carried.mask[25 * 128 + 67]);

    // a region of it, [100, 30) × … : the box reaches past the region's right edge
    let mut region = large.clone();
    (region.width, region.height) = (40, 40);
    region.intrinsics.cx -= 80.0;
    region.intrinsics.cy -= 30.0;
    let in_region = detection.carried_to(&small, &region);
    assert_eq!(in_region.bbox, [-12, -10, 36, 50]);
    assert_eq!(in_region.mask.len(), 40 * 40);
    assert_eq!(
        count(&in_region.mask),
        36 * 40,
        "columns 80..116, rows 30..70"
    );

    // to its own frame: unchanged
    let same = detection.carried_to(&small, &small);
    assert_eq!((same.bbox, &same.mask), (detection.bbox, &detection.mask));
}

#[test]
fn a_segmenter_may_be_fine_tuned_with_other_loss_settings_and_thresholds_but_not_another_input() {
    use boxpose_learn::segmentation::SegmenterConfig;
    let trained = tiny_segmenter();
    let retuned = SegmenterConfig {
        centre_sigma: 2.0,
        centre_weight: 100.0,
        offset_weight: 0.05,
        foreground_threshold: 0.4,
        centre_threshold: 0.2,
        min_pixels: 4,
        ..trained.clone()
    };
    assert!(retuned.can_fine_tune_from(&trained));
    // reading frames at another size is inference's choice: the weights still fine-tune
    let read_larger = SegmenterConfig {
        inference_width: Some(96),
        inference_height: Some(64),
        ..trained.clone()
    };
    assert!(read_larger.can_fine_tune_from(&trained));
    assert!(trained.can_fine_tune_from(&read_larger));
    for other in [
        SegmenterConfig {
            backbone: Backbone::Slim,
            ..trained.clone()
        },
        SegmenterConfig {
            input_width: 96,
            ..trained.clone()
        },
        SegmenterConfig {
            input_height: 32,
            ..trained.clone()
        },
    ] {
        assert!(!other.can_fine_tune_from(&trained), "{other:?}");
    }
}

#[test]
fn every_shipped_segmenter_config_loads() {
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let mut loaded = Vec::new();
    for entry in std::fs::read_dir(&configs).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("segmenter") && name.ends_with(".toml") {
            boxpose_learn::segmentation::SegmenterTrainConfig::load(&path)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            loaded.push(name);
        }
    }
    assert!(
        loaded.contains(&"segmenter-wide.toml".to_string()),
        "{loaded:?}"
    );
}

#[test]
fn a_segmenter_reads_frames_at_its_inference_size_and_trains_at_its_input_size() {
    use boxpose_learn::segmentation::SegmenterConfig;
    let trained = SegmenterConfig {
        inference_width: Some(96),
        inference_height: Some(64),
        ..tiny_segmenter()
    };
    trained.validate().unwrap();
    let inference = trained.for_inference();
    assert_eq!((inference.input_width, inference.input_height), (96, 64));
    assert_eq!(inference.output_size(), [24, 16]);
    assert_eq!(trained.output_size(), [16, 16]);
    let unset = SegmenterConfig {
        inference_width: None,
        inference_height: None,
        ..trained.clone()
    };
    assert_eq!(unset.for_inference(), unset);
    for (w, h) in [(Some(96), None), (Some(100), Some(64)), (Some(0), Some(64))] {
        let bad = SegmenterConfig {
            inference_width: w,
            inference_height: h,
            ..trained.clone()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("inference_width"), "{err}");
    }
    // written only when set: model folders without it read as before
    let text = toml::to_string(&unset).unwrap();
    assert!(!text.contains("inference"), "{text}");
    let back: SegmenterConfig = toml::from_str(&toml::to_string(&trained).unwrap()).unwrap();
    assert_eq!(back, trained);
}
