//! Gives this crate's own binaries, tests and benches an rpath to the MuJoCo library, and hands
//! the same folders to dependents (`DEP_BOXPOSE_MUJOCO_RPATH`, read by rust/render/rpath_build.rs,
//! the build script of binary crates such as boxpose-cli), so no
//! binary needs LD_LIBRARY_PATH.
//!
//! mujoco-rs links `-lmujoco` from `MUJOCO_DYNAMIC_LINK_DIR` (an absolute folder holding
//! `libmujoco.so`, here `build/mujoco/`, symlinks into the `mujoco==3.17.0` wheel). The rpath
//! lists that folder and, resolved through the symlink, the wheel's own folder.
use std::env;
use std::path::PathBuf;

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    let Ok(dir) = env::var("MUJOCO_DYNAMIC_LINK_DIR") else {
        println!(
            "cargo::warning=MUJOCO_DYNAMIC_LINK_DIR is not set: mujoco-rs will fail to link (run `make setup`, or export it as the Makefile does)"
        );
        return;
    };
    let dir = PathBuf::from(dir);
    let mut dirs = vec![dir.clone()];
    if let Ok(lib) = dir.join("libmujoco.so").canonicalize()
        && let Some(parent) = lib.parent()
        && parent != dir
    {
        dirs.push(parent.to_path_buf());
    }
    let joined = dirs
        .iter()
        .map(|d| d.display().to_string())
        .collect::<Vec<_>>()
        .join(":");
    for d in &dirs {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{}", d.display());
    }
    println!("cargo::metadata=rpath={joined}");
}
