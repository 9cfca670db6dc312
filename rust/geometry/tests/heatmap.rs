mod common;

use boxpose_geometry::heatmap::*;
use boxpose_geometry::{BoxModel, GeometryError};
use common::true_corners;
use nalgebra::{Isometry3, Point3, Vector3};

fn grid() -> VoxelGrid {
    VoxelGrid {
        intrinsics: PinholeIntrinsics {
            fx: 600.0,
            fy: 610.0,
            cx: 320.0,
            cy: 240.0,
        },
        // A 256-pixel crop around the box, with margin, seen as 64 heatmap pixels.
        crop: CropTransform {
            x0: 222.0,
            y0: 100.0,
            sx: 4.0,
            sy: 4.0,
        },
        depth: DepthBins {
            z_ref: 1.0,
            z_min: -0.2,
            bin_size: 0.4 / 64.0,
        },
    }
}

const DIMS: HeatmapDims = HeatmapDims {
    depth: 64,
    height: 64,
    width: 64,
};

fn voxel_distance(a: &VoxelCoord, b: &VoxelCoord) -> [f64; 3] {
    [
        (a.z_bin - b.z_bin).abs(),
        (a.v - b.v).abs(),
        (a.u - b.u).abs(),
    ]
}

/// Target rendering, NMS and back-projection undo each other: from the 8 corners of a box, the
/// rendered target's peaks come back within half a voxel of every corner, one peak per corner.
#[test]
fn target_nms_back_projection_recovers_the_corners() {
    let model = BoxModel::new(Vector3::new(0.25, 0.18, 0.12)).unwrap();
    let sigma = 1.5;
    let mut refined_total = 0.0;
    let mut voxel_total = 0.0;
    for k in 0..6 {
        let angle = 0.4 + k as f64;
        let pose = Isometry3::new(
            Vector3::new(0.05, -0.02, 1.0),
            Vector3::new(0.3 * angle, angle.sin(), 0.7),
        );
        let corners = true_corners(&model, &pose);
        let targets: Vec<VoxelCoord> = corners.iter().map(|c| grid().project(c).unwrap()).collect();
        let volume = render_target_heatmap(DIMS, &targets, sigma).unwrap();
        for refine_radius in [0, 2] {
            let params = NmsParams {
                count: 8,
                sigma,
                refine_radius,
            };
            let peaks = non_maximum_suppression(&volume, DIMS, &params).unwrap();
            assert_eq!(peaks.len(), 8);
            let mut claimed = [false; 8];
            for target in &targets {
                let (index, peak) = peaks
                    .iter()
                    .enumerate()
                    .min_by(|a, b| {
                        let da: f64 = voxel_distance(&a.1.coord, target).iter().sum();
                        let db: f64 = voxel_distance(&b.1.coord, target).iter().sum();
                        da.total_cmp(&db)
                    })
                    .unwrap();
                assert!(!claimed[index], "two corners share one peak");
                claimed[index] = true;
                let back = grid().back_project(&peak.coord).unwrap();
                let error = voxel_distance(&grid().project(&back).unwrap(), target);
                assert!(
                    error.iter().all(|&e| e <= 0.5 + 1e-9),
                    "{error:?} voxels off (pose {k}, refine radius {refine_radius})"
                );
                let total: f64 = error.iter().sum();
                if refine_radius == 0 {
                    voxel_total += total
                } else {
                    refined_total += total
                }
            }
        }
    }
    assert!(
        refined_total < 0.8 * voxel_total,
        "refinement {refined_total} vs voxel centres {voxel_total}"
    );
}

#[test]
fn scores_never_increase_and_peaks_are_found_in_order() {
    let targets = [
        VoxelCoord {
            z_bin: 10.0,
            v: 10.0,
            u: 10.0,
        },
        VoxelCoord {
            z_bin: 30.0,
            v: 40.0,
            u: 20.0,
        },
    ];
    let mut volume = render_target_heatmap(DIMS, &targets, 2.0).unwrap();
    // Make the second target the stronger one.
    for x in volume.iter_mut().skip(DIMS.height * DIMS.width * 20) {
        *x *= 2.0;
    }
    let peaks = non_maximum_suppression(
        &volume,
        DIMS,
        &NmsParams {
            count: 5,
            sigma: 2.0,
            refine_radius: 0,
        },
    )
    .unwrap();
    assert_eq!(peaks[0].voxel, [30, 40, 20]);
    assert_eq!(peaks[1].voxel, [10, 10, 10]);
    assert!((peaks[0].score - 2.0).abs() < 1e-6);
    assert!(peaks.windows(2).all(|w| w[1].score <= w[0].score));
}

#[test]
fn stops_when_nothing_positive_is_left() {
    let mut volume = vec![0.0f32; DIMS.voxel_count().unwrap()];
    volume[(5 * 64 + 6) * 64 + 7] = 1.0;
    let peaks = non_maximum_suppression(&volume, DIMS, &NmsParams::default()).unwrap();
    assert_eq!(peaks.len(), 1);
    assert_eq!(peaks[0].voxel, [5, 6, 7]);
    assert_eq!(
        peaks[0].coord,
        VoxelCoord {
            z_bin: 5.0,
            v: 6.0,
            u: 7.0
        }
    );
}

#[test]
fn bad_heatmaps_are_errors() {
    let dims = HeatmapDims {
        depth: 2,
        height: 3,
        width: 4,
    };
    let params = NmsParams::default();
    assert_eq!(
        non_maximum_suppression(&[0.0; 24], dims, &params),
        Err(GeometryError::EmptyHeatmap)
    );
    assert_eq!(
        non_maximum_suppression(&[-1.0; 24], dims, &params),
        Err(GeometryError::EmptyHeatmap)
    );
    assert!(matches!(
        non_maximum_suppression(&[1.0; 23], dims, &params),
        Err(GeometryError::ShapeMismatch { .. })
    ));
    let mut nan = [1.0f32; 24];
    nan[17] = f32::NAN;
    assert!(matches!(
        non_maximum_suppression(&nan, dims, &params),
        Err(GeometryError::NonFinite { .. })
    ));
    nan[17] = f32::INFINITY;
    assert!(matches!(
        non_maximum_suppression(&nan, dims, &params),
        Err(GeometryError::NonFinite { .. })
    ));
    let empty = HeatmapDims {
        depth: 0,
        height: 3,
        width: 4,
    };
    assert!(matches!(
        non_maximum_suppression(&[], empty, &params),
        Err(GeometryError::InvalidParameter { .. })
    ));
    for bad in [
        NmsParams {
            sigma: 0.0,
            ..params
        },
        NmsParams {
            sigma: f64::NAN,
            ..params
        },
        NmsParams { count: 0, ..params },
    ] {
        assert!(matches!(
            non_maximum_suppression(&[1.0; 24], dims, &bad),
            Err(GeometryError::InvalidParameter { .. })
        ));
    }
    assert!(matches!(
        render_target_heatmap(
            dims,
            &[VoxelCoord {
                z_bin: f64::NAN,
                v: 0.0,
                u: 0.0
            }],
            1.0
        ),
        Err(GeometryError::NonFinite { .. })
    ));
}

/// Resource arguments are bounded: an absurd shape or count is an error, and a kernel or window
/// wider than the volume is cut at it, giving what the widest useful one gives.
#[test]
fn absurd_sizes_are_errors_or_clipped() {
    let dims = HeatmapDims {
        depth: 4,
        height: 4,
        width: 4,
    };
    let volume: Vec<f32> = (0..64).map(|i| i as f32).collect();
    let huge = HeatmapDims {
        depth: 1 << 20,
        height: 1 << 20,
        width: 1 << 20,
    };
    assert!(huge.voxel_count().is_err());
    assert!(render_target_heatmap(huge, &[], 2.0).is_err());
    let too_many = NmsParams {
        count: 65,
        ..NmsParams::default()
    };
    assert!(non_maximum_suppression(&volume, dims, &too_many).is_err());
    let peaks = |sigma: f64, refine_radius: usize| {
        let params = NmsParams {
            count: 8,
            sigma,
            refine_radius,
        };
        non_maximum_suppression(&volume, dims, &params).unwrap()
    };
    // A flat kernel over the whole volume subtracts the first peak's value everywhere.
    assert_eq!(peaks(1e300, 0).len(), 1);
    assert_eq!(peaks(2.0, usize::MAX), peaks(2.0, 4));
}

#[test]
fn crop_convention_maps_pixel_centres() {
    let g = VoxelGrid {
        intrinsics: PinholeIntrinsics {
            fx: 500.0,
            fy: 500.0,
            cx: 100.0,
            cy: 50.0,
        },
        crop: CropTransform {
            x0: 100.0,
            y0: 50.0,
            sx: 1.0,
            sy: 1.0,
        },
        depth: DepthBins {
            z_ref: 2.0,
            z_min: -0.5,
            bin_size: 0.1,
        },
    };
    // Heatmap pixel (0, 0) at scale 1 is image pixel (x0, y0), here the principal point; bin 0 is
    // centred half a bin past z_ref + z_min.
    let p = g
        .back_project(&VoxelCoord {
            z_bin: 0.0,
            v: 0.0,
            u: 0.0,
        })
        .unwrap();
    assert!((p - Point3::new(0.0, 0.0, 1.55)).norm() < 1e-12);
    // At scale 2, heatmap pixel 0 covers image pixels 100 and 101: its centre is at 100.5.
    let halved = VoxelGrid {
        crop: CropTransform {
            sx: 2.0,
            sy: 2.0,
            ..g.crop
        },
        ..g
    };
    let p = halved
        .back_project(&VoxelCoord {
            z_bin: 0.0,
            v: 0.0,
            u: 0.0,
        })
        .unwrap();
    assert!((p.x - 0.5 * 1.55 / 500.0).abs() < 1e-12);
}

#[test]
fn projection_and_back_projection_are_inverse() {
    for i in 0..20 {
        let t = i as f64;
        let p = Point3::new(0.2 * t.sin(), -0.1 * t.cos(), 0.9 + 0.01 * t);
        let back = grid().back_project(&grid().project(&p).unwrap()).unwrap();
        assert!((back - p).norm() < 1e-12);
    }
    assert!(matches!(
        grid().project(&Point3::new(0.0, 0.0, -1.0)),
        Err(GeometryError::InvalidParameter { .. })
    ));
    let broken = VoxelGrid {
        intrinsics: PinholeIntrinsics {
            fx: 0.0,
            ..grid().intrinsics
        },
        ..grid()
    };
    assert!(matches!(
        broken.project(&Point3::new(0.0, 0.0, 1.0)),
        Err(GeometryError::InvalidParameter { .. })
    ));
}
