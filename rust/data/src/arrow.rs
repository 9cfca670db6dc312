//! The parts of Apache Arrow that boxpose uses, from Arrow's own sub-crates, laid out as the
//! `arrow` crate lays them out (`boxpose_data::arrow::array::…`, `…::datatypes::…`).
//!
//! The `arrow` crate always builds every compute kernel (arithmetic, ordering, strings, row
//! format): about 100 CPU-seconds of a cold release build that nothing here calls. Every crate of
//! the workspace takes Arrow from this module instead, so the types stay the ones `parquet` and
//! `arrow-pyarrow` use.

/// Arrays, `RecordBatch` and the downcasting helpers (`arrow::array`).
pub mod array {
    pub use arrow_array::cast::*;
    pub use arrow_array::*;
}

/// Logical types and schemas (`arrow::datatypes`).
pub mod datatypes {
    pub use arrow_array::ArrowPrimitiveType;
    pub use arrow_array::types::*;
    pub use arrow_schema::{DataType, Field, Schema, SchemaRef};
}

/// `arrow::record_batch`.
pub mod record_batch {
    pub use arrow_array::RecordBatch;
}

/// The two kernels the readers need: casting a column to the contract's type, and
/// concatenating and filtering batches (`arrow::compute`).
pub mod compute {
    pub use arrow_cast::cast;
    pub use arrow_select::concat::concat_batches;
    pub use arrow_select::filter::filter_record_batch;
}

/// `arrow::error`.
pub mod error {
    pub use arrow_schema::ArrowError;
}
