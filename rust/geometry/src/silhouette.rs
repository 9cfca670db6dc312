//! The amodal silhouette of a box in an image: its corners clipped to the near plane, projected
//! and wrapped in a convex hull, then rasterised. Step for step the Blender stage's
//! `blender_scripts.geometry` (`clip_box_to_near_plane`, `convex_hull_2d`, `silhouette_mask`), so
//! the pixel counts agree with the ones a dataset's `visible_fraction` was measured against.

/// Near plane of the silhouette (metres), as in `blender_scripts.geometry.silhouette_mask`.
const NEAR_M: f64 = 1e-3;

/// The box's 12 edges as pairs of corner indices (i, j), i < j, in increasing (i, axis) order: the
/// corners of an edge differ in the sign along one axis, i.e. in one bit of the corner index
/// (bit 0 is x, bit 1 y, bit 2 z; see the crate's conventions).
pub fn box_edges() -> impl Iterator<Item = (usize, usize)> {
    (0..8usize).flat_map(|i| {
        (0..3)
            .filter(move |bit| i >> bit & 1 == 0)
            .map(move |bit| (i, i | 1 << bit))
    })
}

/// Counter-clockwise convex hull (pixels) of the box's camera-frame corners clipped to
/// z ≥ 1 mm and projected with `intrinsics` = fx, fy, cx, cy; empty when less than a triangle
/// is in front of the camera.
pub fn silhouette_hull(intrinsics: [f64; 4], corners: &[[f64; 3]; 8]) -> Vec<[f64; 2]> {
    let [fx, fy, cx, cy] = intrinsics;
    let mut verts: Vec<[f64; 3]> = corners.iter().filter(|p| p[2] >= NEAR_M).copied().collect();
    for (i, j) in box_edges() {
        let (a, b) = (corners[i], corners[j]);
        if (a[2] - NEAR_M) * (b[2] - NEAR_M) < 0.0 {
            let s = (NEAR_M - a[2]) / (b[2] - a[2]);
            verts.push(std::array::from_fn(|d| a[d] + s * (b[d] - a[d])));
        }
    }
    if verts.len() < 3 {
        return Vec::new();
    }
    let round = |v: f64| (v * 1e12).round_ties_even() / 1e12;
    let mut pts: Vec<[f64; 2]> = verts
        .iter()
        .map(|p| {
            let z = if p[2].abs() < 1e-12 { 1e-12 } else { p[2] };
            [round(fx * p[0] / z + cx), round(fy * p[1] / z + cy)]
        })
        .collect();
    pts.sort_by(|a, b| a.partial_cmp(b).expect("finite pixel coordinates"));
    pts.dedup();
    if pts.len() <= 2 {
        return Vec::new();
    }
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut lower: Vec<[f64; 2]> = Vec::new();
    for &p in &pts {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<[f64; 2]> = Vec::new();
    for &p in pts.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    if lower.len() < 3 { Vec::new() } else { lower }
}

/// The amodal silhouette of one box in one image: the pixels whose centres fall in its hull.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    /// height × width, row-major, in-image pixels.
    pub mask: Vec<bool>,
    /// Pixels in the image.
    pub count: u64,
    /// [x, y, w, h] of the silhouette over an image three times as large (the image in its
    /// centre), as bop_toolkit's `calc_gt_info` renders it: may extend past the image; [-1; 4]
    /// when empty.
    pub bbox: [i64; 4],
}

/// The silhouette of a box with camera-frame `corners` in a `width` × `height` image taken with
/// `intrinsics` = fx, fy, cx, cy.
pub fn silhouette(
    intrinsics: [f64; 4],
    width: usize,
    height: usize,
    corners: &[[f64; 3]; 8],
) -> Silhouette {
    let (w, h) = (width as i64, height as i64);
    let mut out = Silhouette {
        mask: vec![false; width * height],
        count: 0,
        bbox: [-1; 4],
    };
    let hull = silhouette_hull(intrinsics, corners);
    if hull.is_empty() {
        return out;
    }
    let (min_u, max_u) = hull
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p[0]), b.max(p[0]))
        });
    let (min_v, max_v) = hull
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p[1]), b.max(p[1]))
        });
    let clamp = |v: f64, lo: i64, hi: i64| (v.clamp(lo as f64, hi as f64)) as i64;
    let (x0, x1) = (
        clamp(min_u.floor(), -w, 2 * w),
        clamp(max_u.ceil() + 1.0, -w, 2 * w),
    );
    let (y0, y1) = (
        clamp(min_v.floor(), -h, 2 * h),
        clamp(max_v.ceil() + 1.0, -h, 2 * h),
    );
    let (mut bx0, mut by0, mut bx1, mut by1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for y in y0..y1 {
        for x in x0..x1 {
            let (u, v) = (x as f64, y as f64);
            let inside = (0..hull.len()).all(|k| {
                let (a, b) = (hull[k], hull[(k + 1) % hull.len()]);
                (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0]) >= 0.0
            });
            if !inside {
                continue;
            }
            (bx0, by0, bx1, by1) = (bx0.min(x), by0.min(y), bx1.max(x), by1.max(y));
            if (0..w).contains(&x) && (0..h).contains(&y) {
                out.mask[(y * w + x) as usize] = true;
                out.count += 1;
            }
        }
    }
    if bx0 <= bx1 {
        out.bbox = [bx0, by0, bx1 - bx0 + 1, by1 - by0 + 1];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 0.2 m cube 1 m in front of a 100 px focal-length camera.
    fn cube_in_front() -> [[f64; 3]; 8] {
        std::array::from_fn(|i| {
            let s = |b: usize| if i >> b & 1 == 1 { 0.1 } else { -0.1 };
            [s(0), s(1), 1.0 + s(2)]
        })
    }

    #[test]
    fn box_edges_join_corners_one_sign_apart() {
        let edges: Vec<(usize, usize)> = box_edges().collect();
        assert_eq!(edges.len(), 12);
        for &(i, j) in &edges {
            assert!(i < j && j < 8 && (i ^ j).count_ones() == 1, "{i}-{j}");
        }
        let unique: std::collections::BTreeSet<_> = edges.iter().collect();
        assert_eq!(unique.len(), 12);
        // every corner meets three edges
        for corner in 0..8 {
            let degree = edges.iter().filter(|&&(i, j)| i == corner || j == corner);
            assert_eq!(degree.count(), 3);
        }
    }

    #[test]
    fn hull_of_a_box_in_front_is_convex_and_ccw() {
        let hull = silhouette_hull([100.0, 100.0, 50.0, 50.0], &cube_in_front());
        assert_eq!(hull.len(), 4);
        let near = 50.0 - 100.0 * 0.1 / 0.9;
        assert!(
            (hull[0][0] - near).abs() < 1e-9 && (hull[0][1] - near).abs() < 1e-9,
            "{hull:?}"
        );
    }

    #[test]
    fn the_silhouette_counts_its_pixels_and_bounds_them() {
        let s = silhouette([100.0, 100.0, 50.0, 50.0], 100, 100, &cube_in_front());
        // the near face spans 50 ± 11.1 px: pixel centres 39..=61 in each direction
        assert_eq!(s.bbox, [39, 39, 23, 23]);
        assert_eq!(s.count, 23 * 23);
        assert_eq!(s.mask.iter().filter(|m| **m).count() as u64, s.count);
        let behind = silhouette(
            [100.0, 100.0, 50.0, 50.0],
            100,
            100,
            &cube_in_front().map(|[x, y, z]| [x, y, -z]),
        );
        assert_eq!((behind.count, behind.bbox), (0, [-1; 4]));
    }
}
