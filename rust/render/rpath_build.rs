//! Build script for binary crates that depend on crates with `links` metadata `rpath` (e.g.
//! boxpose-render: libpython; boxpose-physics: libmujoco). Use it with
//! `build = "../render/rpath_build.rs"` in the binary crate's Cargo.toml: cargo does not pass a
//! dependency's link arguments on, so the binary adds every `DEP_*_RPATH` folder itself and
//! runs without LD_LIBRARY_PATH.
fn main() {
    let mut vars: Vec<(String, String)> = std::env::vars()
        .filter(|(k, _)| k.starts_with("DEP_") && k.ends_with("_RPATH"))
        .collect();
    vars.sort();
    for (key, rpath) in vars {
        println!("cargo::rerun-if-env-changed={key}");
        for dir in rpath.split(':').filter(|d| !d.is_empty()) {
            println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        }
    }
}
