//! Standard formats in and out of a boxpose dataset, so that BOP and COCO tooling reads its
//! scenes and other methods' results are scored with the project's metrics:
//!
//! - [`bop`]: the BOP scene-wise format that bop_toolkit reads (millimetres, uint16 depth).
//! - [`coco`]: COCO instances (RLE visible and amodal masks, optionally corner keypoints).
//! - [`bop_results`]: a BOP results CSV matched and scored against the dataset it came from.
//! - [`rgbd`]: a frame from an RGB PNG and a 16-bit depth PNG (BOP's depth units).
//! - [`objects`]: BOP object ids (one per distinct box size) and box models, shared by all three.
//!
//! Quiet like every boxpose library: nothing is printed; the exports call back after each frame
//! so the binary can draw a progress bar. docs/export.md describes every file and field.

pub mod bop;
pub mod bop_results;
pub mod coco;
pub mod error;
mod files;
pub mod objects;
pub mod rgbd;

pub use bop::{BopOptions, BopSummary, write_bop};
pub use bop_results::{ResultsScore, score_bop_results};
pub use coco::{CocoOptions, CocoSummary, write_coco};
pub use error::{FormatError, Result};
pub use rgbd::{bop_depth_scale, read_rgbd};
