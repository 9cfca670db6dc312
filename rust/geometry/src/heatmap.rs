//! Step 5 of the paper: peaks of the network's 3D corner heatmap by non-maximum suppression, their
//! back-projection to the camera frame, and the inverse mapping used to render training targets.
//!
//! A heatmap is a flat `&[f32]` of dims (D, H, W) over (z-bin, v, u), row-major: voxel (z, v, u)
//! is at `(z·H + v)·W + u`. Continuous voxel coordinates put voxel centres at integers.

use nalgebra::Point3;

use crate::error::{GeometryError, Result, ensure_finite};

/// Gaussians are evaluated within this many sigmas of their centre; beyond it they are below 1.2 %
/// of their peak, and skipping them keeps suppression and target rendering local.
pub const GAUSSIAN_TRUNCATION_SIGMAS: f64 = 3.0;

/// Dimensions (depth = z-bins, height = v, width = u) of a heatmap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeatmapDims {
    pub depth: usize,
    pub height: usize,
    pub width: usize,
}

/// A continuous position in a heatmap, in voxels (integer values at voxel centres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelCoord {
    pub z_bin: f64,
    pub v: f64,
    pub u: f64,
}

/// One peak found by [`non_maximum_suppression`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// The arg-max voxel, as (z_bin, v, u) indices.
    pub voxel: [usize; 3],
    /// The voxel's centre, or the sub-voxel position when refinement was asked for.
    pub coord: VoxelCoord,
    /// The value at the voxel when it was taken, i.e. after the suppression of earlier peaks; it
    /// never increases from one peak to the next.
    pub score: f32,
}

/// Settings of [`non_maximum_suppression`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NmsParams {
    /// How many peaks to take (the paper takes 8, one per box corner).
    pub count: usize,
    /// Standard deviation of the suppression kernel, in voxels.
    pub sigma: f64,
    /// Half-width, in voxels, of the window of the original heatmap whose positive values are
    /// averaged around each peak for a sub-voxel position; 0 keeps the voxel centre. The window is
    /// clipped at the heatmap's border, which pulls peaks there towards the inside.
    pub refine_radius: usize,
}

impl Default for NmsParams {
    fn default() -> Self {
        Self {
            count: 8,
            sigma: 2.0,
            refine_radius: 0,
        }
    }
}

impl HeatmapDims {
    /// Number of voxels, or an error if any dimension is zero or there are more than
    /// [`HeatmapDims::MAX_VOXELS`] (a shape typo must be an error, not a 4-exabyte allocation
    /// that aborts the process).
    pub fn voxel_count(&self) -> Result<usize> {
        let count = self
            .depth
            .checked_mul(self.height)
            .and_then(|n| n.checked_mul(self.width));
        match count {
            Some(n) if n > 0 && n <= Self::MAX_VOXELS => Ok(n),
            _ => Err(GeometryError::InvalidParameter {
                name: "dims",
                reason: "every dimension must be positive and there may be at most 2^30 voxels",
            }),
        }
    }

    /// 2^30 voxels, 4 GiB of f32: far above any network's heatmap (64³ = 2^18).
    pub const MAX_VOXELS: usize = 1 << 30;

    /// The longest axis: no kernel or window needs to reach further than this.
    fn longest_axis(&self) -> usize {
        self.depth.max(self.height).max(self.width)
    }

    fn index(&self, z: usize, v: usize, u: usize) -> usize {
        (z * self.height + v) * self.width + u
    }
}

/// Peaks of a heatmap, as the paper's step 5: take the arg-max voxel, subtract from the whole
/// volume a Gaussian of standard deviation `sigma` voxels centred there whose amplitude is the
/// value at the peak (so the peak becomes 0), and repeat `count` times.
///
/// The Gaussian is applied within [`GAUSSIAN_TRUNCATION_SIGMAS`] sigmas. Ties go to the lowest
/// flat index. Stops early, returning fewer peaks, once no positive voxel remains; fails with
/// [`GeometryError::EmptyHeatmap`] if there is none to begin with.
pub fn non_maximum_suppression(
    volume: &[f32],
    dims: HeatmapDims,
    params: &NmsParams,
) -> Result<Vec<Peak>> {
    let voxel_count = dims.voxel_count()?;
    if volume.len() != voxel_count {
        return Err(GeometryError::ShapeMismatch {
            what: "heatmap length (depth·height·width)",
            expected: voxel_count,
            got: volume.len(),
        });
    }
    ensure_positive("sigma", params.sigma)?;
    if params.count == 0 || params.count > voxel_count {
        return Err(GeometryError::InvalidParameter {
            name: "count",
            reason: "must be at least 1 and at most the number of voxels",
        });
    }

    let mut work = volume.to_vec();
    // Arg-max over the whole volume is the hot loop: keep each (z, v) row's maximum, so that a
    // peak costs a scan of the row maxima plus one row, and suppression refreshes only the rows
    // its kernel touched.
    let mut row_max = Vec::with_capacity(dims.depth * dims.height);
    for row in work.chunks_exact(dims.width) {
        let (max, finite) = row_max_and_finiteness(row);
        if !finite {
            return Err(GeometryError::NonFinite { what: "heatmap" });
        }
        row_max.push(max);
    }

    // A kernel wider than the volume is cut at its longest axis: nothing beyond is ever indexed.
    let radius = (GAUSSIAN_TRUNCATION_SIGMAS * params.sigma)
        .ceil()
        .min(dims.longest_axis() as f64) as usize;
    let kernel: Vec<f32> = (0..=radius)
        .map(|d| (-((d * d) as f64) / (2.0 * params.sigma * params.sigma)).exp() as f32)
        .collect();
    let mut peaks = Vec::with_capacity(params.count);
    while peaks.len() < params.count {
        let row = first_argmax(&row_max);
        let score = row_max[row];
        if score <= 0.0 {
            break;
        }
        let row_values = &work[row * dims.width..(row + 1) * dims.width];
        let u = first_argmax(row_values);
        let (z, v) = (row / dims.height, row % dims.height);
        let voxel = [z, v, u];

        let span = |centre: usize, len: usize| {
            centre.saturating_sub(radius)..(centre + radius + 1).min(len)
        };
        for zz in span(z, dims.depth) {
            let wz = kernel[zz.abs_diff(z)] * score;
            for vv in span(v, dims.height) {
                let wzv = wz * kernel[vv.abs_diff(v)];
                let start = dims.index(zz, vv, 0);
                let row_values = &mut work[start..start + dims.width];
                for uu in span(u, dims.width) {
                    row_values[uu] -= wzv * kernel[uu.abs_diff(u)];
                }
                row_max[zz * dims.height + vv] = row_max_and_finiteness(row_values).0;
            }
        }

        let coord = if params.refine_radius == 0 {
            VoxelCoord {
                z_bin: z as f64,
                v: v as f64,
                u: u as f64,
            }
        } else {
            soft_argmax_around(volume, dims, voxel, params.refine_radius)
        };
        peaks.push(Peak {
            voxel,
            coord,
            score,
        });
    }
    if peaks.is_empty() {
        return Err(GeometryError::EmptyHeatmap);
    }
    Ok(peaks)
}

/// Maximum of a row and whether all its values are finite, in one pass that the compiler can
/// vectorise (independent lanes, a NaN/inf test by `x·0 ≠ 0`).
fn row_max_and_finiteness(row: &[f32]) -> (f32, bool) {
    const LANES: usize = 8;
    let mut max = [f32::NEG_INFINITY; LANES];
    let mut nan_probe = [0.0f32; LANES];
    let chunks = row.chunks_exact(LANES);
    let tail = chunks.remainder();
    for chunk in chunks {
        for k in 0..LANES {
            max[k] = if chunk[k] > max[k] { chunk[k] } else { max[k] };
            nan_probe[k] += chunk[k] * 0.0;
        }
    }
    for &x in tail {
        max[0] = if x > max[0] { x } else { max[0] };
        nan_probe[0] += x * 0.0;
    }
    let max = max
        .into_iter()
        .fold(f32::NEG_INFINITY, |m, x| if x > m { x } else { m });
    (max, nan_probe.iter().all(|&p| p == 0.0))
}

fn first_argmax(values: &[f32]) -> usize {
    let mut best = 0;
    for (i, &x) in values.iter().enumerate() {
        if x > values[best] {
            best = i;
        }
    }
    best
}

/// Mean position of the positive values of `volume` within `radius` voxels (per axis) of `voxel`,
/// weighted by value: a local soft-argmax, on the original heatmap so that earlier suppressions do
/// not bias it.
fn soft_argmax_around(
    volume: &[f32],
    dims: HeatmapDims,
    voxel: [usize; 3],
    radius: usize,
) -> VoxelCoord {
    let radius = radius.min(dims.longest_axis());
    let span =
        |centre: usize, len: usize| centre.saturating_sub(radius)..(centre + radius + 1).min(len);
    let (mut total, mut sum) = (0.0f64, [0.0f64; 3]);
    for z in span(voxel[0], dims.depth) {
        for v in span(voxel[1], dims.height) {
            for u in span(voxel[2], dims.width) {
                let w = volume[dims.index(z, v, u)].max(0.0) as f64;
                total += w;
                sum[0] += w * z as f64;
                sum[1] += w * v as f64;
                sum[2] += w * u as f64;
            }
        }
    }
    // The peak voxel itself is positive, so the total is too.
    VoxelCoord {
        z_bin: sum[0] / total,
        v: sum[1] / total,
        u: sum[2] / total,
    }
}

/// Renders a training target: at each voxel, the maximum over `centres` of
/// exp(−‖voxel − centre‖² / (2·sigma²)) (distances in voxels), zero beyond
/// [`GAUSSIAN_TRUNCATION_SIGMAS`] sigmas. Centres outside the volume contribute their tails.
pub fn render_target_heatmap(
    dims: HeatmapDims,
    centres: &[VoxelCoord],
    sigma: f64,
) -> Result<Vec<f32>> {
    let mut volume = vec![0.0f32; dims.voxel_count()?];
    add_targets(&mut volume, dims, centres, sigma)?;
    Ok(volume)
}

/// Max-combines the Gaussians of [`render_target_heatmap`] at `centres` into `volume` (of
/// `dims`), so that a caller can draw many centres in parts, e.g. checking for an interrupt
/// between them; the work of each centre is [`target_support_voxels`].
pub fn add_targets(
    volume: &mut [f32],
    dims: HeatmapDims,
    centres: &[VoxelCoord],
    sigma: f64,
) -> Result<()> {
    let voxel_count = dims.voxel_count()?;
    if volume.len() != voxel_count {
        return Err(GeometryError::InvalidParameter {
            name: "volume",
            reason: "its length is not the dims' voxel count",
        });
    }
    ensure_positive("sigma", sigma)?;
    ensure_finite(
        "target centres",
        centres.iter().flat_map(|c| [&c.z_bin, &c.v, &c.u]),
    )?;
    let reach = GAUSSIAN_TRUNCATION_SIGMAS * sigma;
    let gauss = |d: f64| (-(d * d) / (2.0 * sigma * sigma)).exp();
    for c in centres {
        for z in target_span(c.z_bin, reach, dims.depth) {
            let gz = gauss(z as f64 - c.z_bin);
            for v in target_span(c.v, reach, dims.height) {
                let gzv = gz * gauss(v as f64 - c.v);
                for u in target_span(c.u, reach, dims.width) {
                    let value = (gzv * gauss(u as f64 - c.u)) as f32;
                    let cell = &mut volume[dims.index(z, v, u)];
                    *cell = cell.max(value);
                }
            }
        }
    }
    Ok(())
}

/// How many voxels the target Gaussian at `centre` touches: its truncated support clipped to the
/// volume, the work of drawing it (0 for a centre whose support misses the volume).
pub fn target_support_voxels(dims: HeatmapDims, centre: &VoxelCoord, sigma: f64) -> usize {
    let reach = GAUSSIAN_TRUNCATION_SIGMAS * sigma;
    target_span(centre.z_bin, reach, dims.depth).len()
        * target_span(centre.v, reach, dims.height).len()
        * target_span(centre.u, reach, dims.width).len()
}

/// Voxel indices within `reach` of `centre` along one axis of length `len` (empty when none).
fn target_span(centre: f64, reach: f64, len: usize) -> std::ops::Range<usize> {
    let lo = (centre - reach).ceil().max(0.0);
    let hi = (centre + reach).floor().min(len as f64 - 1.0);
    if lo > hi || lo.is_nan() || hi.is_nan() {
        0..0
    } else {
        lo as usize..hi as usize + 1
    }
}

/// Pinhole intrinsics of the full image, in pixels (OpenCV: pixel centres at integer coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeIntrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Where a heatmap's (u, v) grid lies in the full image.
///
/// Heatmap pixel (u, v) has its centre at image pixel coordinates
/// `u_img = x0 + (u + 0.5)·sx − 0.5`, `v_img = y0 + (v + 0.5)·sy − 0.5`: (x0, y0) is the image
/// pixel index where the crop begins and (sx, sy) the image pixels per heatmap pixel. This is the
/// half-pixel-centre convention of `cv2.resize` and of `align_corners=False` interpolation, so a
/// crop of image pixels x0..x0+w resized to w/sx pixels maps exactly; sx folds in both the resize
/// to the network's input and the network's output stride.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CropTransform {
    pub x0: f64,
    pub y0: f64,
    pub sx: f64,
    pub sy: f64,
}

/// The heatmap's depth axis: z-bin `k` has its centre at camera depth
/// `z = z_ref + z_min + (k + 0.5)·bin_size`, with `z_ref` a per-crop reference depth (for example
/// the median depth of the crop) and `z_min` the offset of the first bin's near edge from it.
/// Depth is the camera-frame z coordinate (planar depth), not the length of the ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthBins {
    pub z_ref: f64,
    pub z_min: f64,
    pub bin_size: f64,
}

/// Everything that ties heatmap voxels to camera-frame points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelGrid {
    pub intrinsics: PinholeIntrinsics,
    pub crop: CropTransform,
    pub depth: DepthBins,
}

impl VoxelGrid {
    /// The camera-frame point (metres) at a continuous voxel position.
    pub fn back_project(&self, coord: &VoxelCoord) -> Result<Point3<f64>> {
        self.validate()?;
        ensure_finite("voxel coordinate", [&coord.z_bin, &coord.v, &coord.u])?;
        let (k, c, d) = (&self.intrinsics, &self.crop, &self.depth);
        let z = d.z_ref + d.z_min + (coord.z_bin + 0.5) * d.bin_size;
        ensure_in_front(z)?;
        let u_img = c.x0 + (coord.u + 0.5) * c.sx - 0.5;
        let v_img = c.y0 + (coord.v + 0.5) * c.sy - 0.5;
        Ok(Point3::new(
            (u_img - k.cx) * z / k.fx,
            (v_img - k.cy) * z / k.fy,
            z,
        ))
    }

    /// The continuous voxel position of a camera-frame point: the inverse of
    /// [`VoxelGrid::back_project`]. The point must be in front of the camera (z > 0); positions
    /// outside the heatmap's extent are returned as they are.
    pub fn project(&self, point: &Point3<f64>) -> Result<VoxelCoord> {
        self.validate()?;
        ensure_finite("point", point.coords.iter())?;
        ensure_in_front(point.z)?;
        let (k, c, d) = (&self.intrinsics, &self.crop, &self.depth);
        let u_img = k.fx * point.x / point.z + k.cx;
        let v_img = k.fy * point.y / point.z + k.cy;
        Ok(VoxelCoord {
            z_bin: (point.z - d.z_ref - d.z_min) / d.bin_size - 0.5,
            v: (v_img + 0.5 - c.y0) / c.sy - 0.5,
            u: (u_img + 0.5 - c.x0) / c.sx - 0.5,
        })
    }

    fn validate(&self) -> Result<()> {
        let (k, c, d) = (&self.intrinsics, &self.crop, &self.depth);
        ensure_finite(
            "voxel grid",
            [&k.fx, &k.fy, &k.cx, &k.cy, &c.x0, &c.y0, &c.sx, &c.sy],
        )?;
        ensure_finite("depth bins", [&d.z_ref, &d.z_min, &d.bin_size])?;
        ensure_positive("fx", k.fx)?;
        ensure_positive("fy", k.fy)?;
        ensure_positive("sx", c.sx)?;
        ensure_positive("sy", c.sy)?;
        ensure_positive("bin_size", d.bin_size)
    }
}

fn ensure_positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(GeometryError::InvalidParameter {
            name,
            reason: "must be finite and positive",
        })
    }
}

fn ensure_in_front(z: f64) -> Result<()> {
    if z > 0.0 {
        Ok(())
    } else {
        Err(GeometryError::InvalidParameter {
            name: "depth",
            reason: "point must be in front of the camera (z > 0)",
        })
    }
}
