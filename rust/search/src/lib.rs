//! The counterexample search (the paper's Section IV and its future work): sample box scenes from
//! a search space ([`space`]), build them in the dataset contract and settle them with MuJoCo
//! ([`scene`]), render them through the embedded Blender and run the perception pipeline on them
//! ([`sut`]; or hand the frames to another system's process, [`external`]), and estimate how often it fails — Monte Carlo or cross-entropy importance sampling,
//! resumable and shardable ([`run`]) — and compare two runs on the same inputs ([`compare`]);
//! statistics come from `boxpose-search-stats`.

pub mod compare;
pub mod error;
pub mod external;
pub mod external_eval;
mod nuisance;
pub mod run;
pub mod scene;
pub mod space;
pub mod sut;
pub mod system;
pub mod variants;

pub use error::{Result, SearchError};
