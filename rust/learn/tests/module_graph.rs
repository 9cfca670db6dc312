//! The data, loader and sample_server modules do not use burn, so crops, targets, batching and
//! the examples served to other frameworks can be reused and tested without a backend. (That the
//! crate's modules depend one way, burn's examples' data → model → training → inference layering,
//! tests/test_architecture.py checks for every crate.)

use std::path::Path;

#[test]
fn crops_targets_and_batching_do_not_use_burn() {
    for module in ["data", "loader", "sample_server"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("src")
            .join(format!("{module}.rs"));
        let text = std::fs::read_to_string(path).expect("read a module");
        assert!(!text.contains("burn::"), "{module}.rs uses burn");
        assert!(
            !text.contains("crate::training"),
            "{module}.rs uses training"
        );
    }
}
