//! Box pose from 3D corner keypoints: steps 5–7 of "Robust Pose Estimation from 3D Keypoints"
//! and what goes beyond them.
//!
//! Conventions (as everywhere in boxpose): metres; OpenCV camera frame (x right, y down, z
//! forward); a box's frame has its origin at the box centre and axes along its edges; corner `i`
//! of a box of size (dx, dy, dz) is (±dx/2, ±dy/2, ±dz/2) with bit 0 of `i` the sign of x, bit 1
//! of y, bit 2 of z (0 = −, 1 = +). A pose maps box-frame points into the camera frame.
//!
//! - [`heatmap`]: NMS peaks of the 3D heatmap, back-projection, target rendering (step 5).
//! - [`align`]: Kabsch and Umeyama least-squares alignment.
//! - [`correspondence`]: the paper's brute-force correspondence search and an exact fast one
//!   (step 6).
//! - [`robust`]: a pose that survives up to half the peaks being outliers.
//! - [`size_fit`]: pose and box size together, for boxes of unknown size.
//! - [`metrics`]: the paper's error (step 7) and the usual pose metrics.
//! - [`pipeline`]: peaks → every pose fit → scores, as each evaluation runs them.
//! - [`depth_refine`]: a fitted pose laid on the depth image's points of the box's faces.
//! - [`silhouette`]: a box's amodal silhouette in an image (the exports' amodal masks).
//! - [`synthetic`]: a perfect network's heatmap of a box and its fits (`eval-geometry`).

pub mod adaptive;
pub mod align;
pub mod benchmark;
pub mod box_model;
pub mod correspondence;
pub mod depth;
pub mod depth_refine;
pub mod detection;
pub mod error;
pub mod heatmap;
pub mod metrics;
pub mod pipeline;
pub mod robust;
pub mod silhouette;
pub mod size_fit;
pub mod synthetic;

pub use box_model::{BoxModel, BoxSymmetry, ShapeClass};
pub use error::{GeometryError, Result};
