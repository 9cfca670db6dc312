//! Gives this crate's own tests, benches and examples an rpath to the libpython pyo3 links
//! (pyenv's libpython3.11.so, not the system's), and hands the folder to dependents as
//! DEP_BOXPOSE_PYTHON_RPATH, read by `rpath_build.rs` in binary crates (e.g. boxpose-cli).
fn main() {
    let config = pyo3_build_config::get();
    if let Some(dir) = config.lib_dir() {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::metadata=rpath={dir}");
    } else {
        println!(
            "cargo::warning=pyo3 found no libpython folder: binaries will need LD_LIBRARY_PATH"
        );
    }
    if let Some(exe) = config.executable() {
        println!("cargo::rustc-env=BOXPOSE_BUILD_PYTHON={exe}");
    }
    println!("cargo::rerun-if-env-changed=PYO3_PYTHON");
}
