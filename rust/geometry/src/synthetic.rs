//! The heatmap a perfect keypoint network would output for a box — a Gaussian at each (noisy)
//! true corner in a crop around it, optionally with confident spurious peaks — and every pose fit
//! of its peaks: the heatmap → pose stage isolated from the network (`boxpose eval-geometry`).
//! What fails here fails with any network.

use nalgebra::{Isometry3, Point3};

use crate::BoxModel;
use crate::heatmap::{
    self, CropTransform, DepthBins, HeatmapDims, NmsParams, PinholeIntrinsics, VoxelCoord,
    VoxelGrid,
};
use crate::pipeline::{FitOutcome, Method, fit_and_score};

/// Gaussian width of the drawn peaks and of the NMS kernel, in voxels.
const PEAK_SIGMA_VOXELS: f64 = 1.5;
/// Crop and depth range extend this far beyond the box's projected corners / diameter.
const CROP_MARGIN: f64 = 1.2;
/// Score of a true corner's peak; outliers get 1.0, so they rank first, as in the paper's failures.
const CORNER_PEAK_SCORE: f32 = 0.8;

/// Crop (square, around the projected corners `corners_px`) and depth range (around the box
/// centre's depth `z_ref`) of a `resolution`³ heatmap, as the keypoint network's input crop would
/// be; `intrinsics` = fx, fy, cx, cy.
pub fn crop_grid(
    intrinsics: [f64; 4],
    corners_px: &[[f64; 2]],
    z_ref: f64,
    diameter: f64,
    resolution: usize,
) -> VoxelGrid {
    let [fx, fy, cx, cy] = intrinsics;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in corners_px {
        for a in 0..2 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let half = (hi[0] - lo[0]).max(hi[1] - lo[1]) / 2.0 * CROP_MARGIN + 1.0;
    let scale = 2.0 * half / resolution as f64;
    let depth_half = diameter / 2.0 * CROP_MARGIN;
    VoxelGrid {
        intrinsics: PinholeIntrinsics { fx, fy, cx, cy },
        crop: CropTransform {
            x0: (lo[0] + hi[0]) / 2.0 - half + 0.5,
            y0: (lo[1] + hi[1]) / 2.0 - half + 0.5,
            sx: scale,
            sy: scale,
        },
        depth: DepthBins {
            z_ref,
            z_min: -depth_half,
            bin_size: 2.0 * depth_half / resolution as f64,
        },
    }
}

/// Draws the heatmap of `corners` (camera frame, noise already added) and `outliers` (voxel
/// coordinates, score 1 above the corners' 0.8) on `grid` with `resolution`³ voxels, takes its 8
/// NMS peaks, back-projects them and runs every pose fit of `model`, scored against `truth`. No
/// image here, so no depth check of mirror ties.
pub fn fit_synthetic_heatmap(
    model: &BoxModel,
    truth: &Isometry3<f64>,
    grid: &VoxelGrid,
    resolution: usize,
    corners: &[Point3<f64>],
    outliers: &[VoxelCoord],
) -> crate::Result<Vec<(Method, FitOutcome)>> {
    let dims = HeatmapDims {
        depth: resolution,
        height: resolution,
        width: resolution,
    };
    let corners = corners
        .iter()
        .map(|c| grid.project(c))
        .collect::<Result<Vec<_>, _>>()?;
    let mut volume = heatmap::render_target_heatmap(dims, &corners, PEAK_SIGMA_VOXELS)?;
    volume.iter_mut().for_each(|v| *v *= CORNER_PEAK_SCORE);
    if !outliers.is_empty() {
        let spurious = heatmap::render_target_heatmap(dims, outliers, PEAK_SIGMA_VOXELS)?;
        volume
            .iter_mut()
            .zip(spurious)
            .for_each(|(v, s)| *v = v.max(s));
    }
    let peaks = heatmap::non_maximum_suppression(
        &volume,
        dims,
        &NmsParams {
            count: 8,
            sigma: PEAK_SIGMA_VOXELS,
            refine_radius: 1,
        },
    )?;
    let points = peaks
        .iter()
        .map(|p| grid.back_project(&p.coord))
        .collect::<Result<Vec<_>, _>>()?;
    let scores: Vec<f64> = peaks.iter().map(|p| p.score as f64).collect();
    Ok(fit_and_score(model, truth, &points, &scores, None))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn exact_corners_give_the_true_pose_and_outliers_do_not_fool_the_robust_fit() {
        let model = BoxModel::new(Vector3::new(0.3, 0.2, 0.1)).unwrap();
        let truth = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 1.2),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 0.7),
        );
        let corners: Vec<Point3<f64>> = model.corners().iter().map(|c| truth * c).collect();
        let intrinsics = [600.0, 600.0, 320.0, 240.0];
        let corners_px: Vec<[f64; 2]> = corners
            .iter()
            .map(|p| [600.0 * p.x / p.z + 320.0, 600.0 * p.y / p.z + 240.0])
            .collect();
        let grid = crop_grid(intrinsics, &corners_px, 1.2, model.diameter(), 64);
        let robust_error = |outliers: &[VoxelCoord]| {
            let fits =
                fit_synthetic_heatmap(&model, &truth, &grid, 64, &corners, outliers).unwrap();
            let (_, outcome) = fits.iter().find(|(m, _)| *m == Method::Robust).unwrap();
            outcome.scores().expect("a pose").cube_mssd_m
        };
        assert!(robust_error(&[]) < 0.01 * model.diameter());
        let spurious = [
            VoxelCoord {
                z_bin: 5.0,
                v: 5.0,
                u: 5.0,
            },
            VoxelCoord {
                z_bin: 58.0,
                v: 10.0,
                u: 50.0,
            },
        ];
        assert!(robust_error(&spurious) < 0.05 * model.diameter());
    }
}
