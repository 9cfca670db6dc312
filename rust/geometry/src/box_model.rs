//! The box model: a cuboid centred at its frame's origin with axes along its edges, its 8 corners,
//! and its rotational symmetry group.

use std::sync::OnceLock;

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

use crate::error::{GeometryError, Result, ensure_finite};

/// Number of corners of a box.
pub const CORNER_COUNT: usize = 8;

/// A box of size (dx, dy, dz) in metres, centred at the origin of its own frame.
///
/// Corner `i` (0..8) is `(±dx/2, ±dy/2, ±dz/2)` with bit 0 of `i` choosing the sign of x, bit 1 of y,
/// bit 2 of z (0 = −, 1 = +), so corner 0 is (−,−,−) and corner 7 is (+,+,+).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxModel {
    size: Vector3<f64>,
}

/// How many side lengths of a box are equal, which fixes the order of its symmetry group.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShapeClass {
    /// Three different side lengths: 4 rotations (identity and 180° about each axis).
    Generic,
    /// Two equal side lengths: 8 rotations (dihedral group D4 about `axis`, the odd side out).
    SquareFaced { axis: usize },
    /// Three equal side lengths: the 24 rotations of the cube.
    Cube,
}

/// A rotation that maps the box onto itself, with the corner permutation it induces:
/// `rotation * corner(i) == corner(corner_permutation[i])`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxSymmetry {
    pub rotation: Rotation3<f64>,
    pub corner_permutation: [usize; CORNER_COUNT],
}

impl BoxModel {
    /// Relative tolerance under which two side lengths count as equal for [`BoxModel::symmetries`].
    pub const DEFAULT_SYMMETRY_TOLERANCE: f64 = 1e-6;

    /// A box with the given side lengths; each must be finite and positive.
    pub fn new(size: Vector3<f64>) -> Result<Self> {
        ensure_finite("box size", size.iter())?;
        if size.iter().any(|&side| side <= 0.0) {
            return Err(GeometryError::InvalidParameter {
                name: "size",
                reason: "every side length must be positive",
            });
        }
        Ok(Self { size })
    }

    /// The paper's model: a unit cube.
    pub fn unit() -> Self {
        Self {
            size: Vector3::repeat(1.0),
        }
    }

    /// Side lengths (dx, dy, dz).
    pub fn size(&self) -> Vector3<f64> {
        self.size
    }

    /// The 8 corners in the documented order.
    pub fn corners(&self) -> [Point3<f64>; CORNER_COUNT] {
        std::array::from_fn(|i| Point3::from(corner_signs(i).component_mul(&self.size) * 0.5))
    }

    /// Length of the space diagonal, the largest distance between two points of the box.
    pub fn diameter(&self) -> f64 {
        self.size.norm()
    }

    /// dx · dy · dz.
    pub fn volume(&self) -> f64 {
        self.size.product()
    }

    /// Shape class with side lengths compared under relative tolerance `relative_tolerance`.
    ///
    /// Two sides a, b are equal when |a − b| ≤ tol · max(a, b). If two of the three pairs are equal
    /// the box is a cube, so that the result is always a group even when equality is not transitive
    /// under the tolerance.
    pub fn shape_class(&self, relative_tolerance: f64) -> ShapeClass {
        let s = self.size;
        let equal = |a: f64, b: f64| (a - b).abs() <= relative_tolerance * a.max(b);
        let pairs = [(0, 1, 2), (1, 2, 0), (0, 2, 1)];
        let equal_pairs: Vec<usize> = pairs
            .iter()
            .filter(|&&(a, b, _)| equal(s[a], s[b]))
            .map(|&(_, _, odd)| odd)
            .collect();
        match equal_pairs.as_slice() {
            [] => ShapeClass::Generic,
            [odd_axis] => ShapeClass::SquareFaced { axis: *odd_axis },
            _ => ShapeClass::Cube,
        }
    }

    /// The rotation group of the box (identity first), with side lengths compared under
    /// [`BoxModel::DEFAULT_SYMMETRY_TOLERANCE`].
    pub fn symmetries(&self) -> Vec<BoxSymmetry> {
        self.symmetries_with_tolerance(Self::DEFAULT_SYMMETRY_TOLERANCE)
    }

    /// The rotation group of the box: 4, 8 or 24 elements by [`BoxModel::shape_class`].
    pub fn symmetries_with_tolerance(&self, relative_tolerance: f64) -> Vec<BoxSymmetry> {
        let class = self.shape_class(relative_tolerance);
        // A box symmetry is a signed axis permutation with det +1 that maps each axis onto an axis
        // of the same length.
        let maps_axes_onto_equal_sides = |axis_image: [usize; 3]| match class {
            ShapeClass::Generic => axis_image == [0, 1, 2],
            ShapeClass::SquareFaced { axis } => axis_image[axis] == axis,
            ShapeClass::Cube => true,
        };
        cube_rotations()
            .filter(|(_, axis_image)| maps_axes_onto_equal_sides(*axis_image))
            .map(|(matrix, _)| BoxSymmetry {
                corner_permutation: std::array::from_fn(|i| {
                    corner_index_of_signs(&(matrix * corner_signs(i)))
                }),
                rotation: Rotation3::from_matrix_unchecked(matrix),
            })
            .collect()
    }
}

impl BoxModel {
    /// Corner permutations of the symmetry group with side lengths compared exactly, identity
    /// first, from tables computed once per shape class (the searches run often). Exact, because
    /// the searches drop assignments that a symmetry maps onto others, which is lossless only if
    /// their errors are equal, not nearly equal.
    pub(crate) fn symmetry_permutations(&self) -> &'static [[usize; CORNER_COUNT]] {
        static TABLES: OnceLock<[Vec<[usize; CORNER_COUNT]>; 5]> = OnceLock::new();
        let tables = TABLES.get_or_init(|| {
            let representative = |size: [f64; 3]| {
                BoxModel {
                    size: Vector3::from(size),
                }
                .symmetries()
                .iter()
                .map(|g| g.corner_permutation)
                .collect()
            };
            [
                representative([1.0, 2.0, 3.0]),
                representative([1.0, 2.0, 2.0]),
                representative([2.0, 1.0, 2.0]),
                representative([2.0, 2.0, 1.0]),
                representative([1.0, 1.0, 1.0]),
            ]
        });
        let table = match self.shape_class(0.0) {
            ShapeClass::Generic => 0,
            ShapeClass::SquareFaced { axis } => 1 + axis,
            ShapeClass::Cube => 4,
        };
        &tables[table]
    }
}

/// The corner permutations of the cube's 24 proper rotations (identity first): permutation `π`
/// sends corner `i` to corner `π[i]`, the corner whose sign vector is the rotated sign vector of
/// `i`. What the corners of any box can be relabelled by when its side lengths are ignored.
pub fn cube_corner_permutations() -> &'static [[usize; CORNER_COUNT]] {
    BoxModel::unit().symmetry_permutations()
}

/// The sign vector (±1, ±1, ±1) of corner `i`.
pub(crate) fn corner_signs(i: usize) -> Vector3<f64> {
    Vector3::from_fn(|axis, _| if (i >> axis) & 1 == 1 { 1.0 } else { -1.0 })
}

/// The corner index whose sign pattern matches the signs of `v`.
fn corner_index_of_signs(v: &Vector3<f64>) -> usize {
    (0..3)
        .filter(|&axis| v[axis] > 0.0)
        .map(|axis| 1 << axis)
        .sum()
}

/// The 24 proper signed permutation matrices (identity first), each with the axis each column maps
/// to: column `i` is ±e_{axis_image[i]}.
fn cube_rotations() -> impl Iterator<Item = (Matrix3<f64>, [usize; 3])> {
    const PERMUTATIONS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    PERMUTATIONS.into_iter().flat_map(|axis_image| {
        (0..8usize).filter_map(move |sign_bits| {
            let matrix = Matrix3::from_fn(|row, col| {
                let sign = if (sign_bits >> col) & 1 == 1 {
                    -1.0
                } else {
                    1.0
                };
                if axis_image[col] == row { sign } else { 0.0 }
            });
            (matrix.determinant() > 0.0).then_some((matrix, axis_image))
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(x: f64, y: f64, z: f64) -> BoxModel {
        BoxModel::new(Vector3::new(x, y, z)).unwrap()
    }

    #[test]
    fn corners_follow_the_bit_convention() {
        let corners = model(2.0, 4.0, 6.0).corners();
        assert_eq!(corners[0], Point3::new(-1.0, -2.0, -3.0));
        assert_eq!(corners[1], Point3::new(1.0, -2.0, -3.0));
        assert_eq!(corners[2], Point3::new(-1.0, 2.0, -3.0));
        assert_eq!(corners[4], Point3::new(-1.0, -2.0, 3.0));
        assert_eq!(corners[7], Point3::new(1.0, 2.0, 3.0));
    }

    #[test]
    fn diameter_is_the_longest_corner_distance() {
        let m = model(0.3, 0.2, 0.1);
        let corners = m.corners();
        let longest = corners
            .iter()
            .flat_map(|a| corners.iter().map(move |b| (a - b).norm()))
            .fold(0.0, f64::max);
        assert!((m.diameter() - longest).abs() < 1e-15);
    }

    #[test]
    fn group_order_follows_shape_class() {
        assert_eq!(model(0.3, 0.2, 0.1).symmetries().len(), 4);
        assert_eq!(model(0.2, 0.2, 0.1).symmetries().len(), 8);
        assert_eq!(
            model(0.2, 0.1, 0.1).shape_class(1e-6),
            ShapeClass::SquareFaced { axis: 0 }
        );
        assert_eq!(model(0.1, 0.1, 0.1).symmetries().len(), 24);
        assert_eq!(model(0.1, 0.1 + 1e-9, 0.1).symmetries().len(), 24);
        assert_eq!(model(0.1, 0.1 + 1e-3, 0.1).symmetries().len(), 8);
    }

    #[test]
    fn symmetries_map_corners_onto_corners_and_form_a_group() {
        for m in [
            model(0.3, 0.2, 0.1),
            model(0.1, 0.3, 0.3),
            model(0.2, 0.2, 0.2),
        ] {
            let corners = m.corners();
            let group = m.symmetries();
            assert_eq!(group[0].rotation, Rotation3::identity());
            for g in &group {
                assert!((g.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
                for (i, corner) in corners.iter().enumerate() {
                    let image = g.rotation * corner;
                    assert!((image - corners[g.corner_permutation[i]]).norm() < 1e-12);
                }
                for h in &group {
                    let product = g.rotation * h.rotation;
                    let closed = group
                        .iter()
                        .any(|k| (k.rotation.matrix() - product.matrix()).norm() < 1e-12);
                    assert!(closed, "group not closed under composition");
                }
            }
        }
    }

    #[test]
    fn cached_permutations_match_the_group() {
        for m in [
            model(0.3, 0.2, 0.1),
            model(0.3, 0.1, 0.3),
            model(0.2, 0.3, 0.3),
            model(0.1, 0.1, 0.3),
            model(0.2, 0.2, 0.2),
        ] {
            let computed: Vec<_> = m
                .symmetries()
                .iter()
                .map(|g| g.corner_permutation)
                .collect();
            assert_eq!(m.symmetry_permutations(), computed.as_slice());
        }
        assert_eq!(
            model(0.2, 0.2 + 1e-12, 0.2).symmetry_permutations().len(),
            8
        );
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(matches!(
            BoxModel::new(Vector3::new(1.0, f64::NAN, 1.0)),
            Err(GeometryError::NonFinite { .. })
        ));
        assert!(matches!(
            BoxModel::new(Vector3::new(1.0, 0.0, 1.0)),
            Err(GeometryError::InvalidParameter { .. })
        ));
        assert!(matches!(
            BoxModel::new(Vector3::new(1.0, -1.0, 1.0)),
            Err(GeometryError::InvalidParameter { .. })
        ));
    }
}
