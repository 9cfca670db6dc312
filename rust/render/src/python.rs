//! The embedded CPython: finding the boxpose virtual environment, starting the interpreter as
//! its `python`, checking that it is the version the venv was made with, and turning Python
//! exceptions into [`RenderError`]s.

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::Once;

use pyo3::ffi;
use pyo3::prelude::*;

use crate::{RenderError, Result};

pub(crate) fn py_err(py: Python<'_>, e: PyErr) -> RenderError {
    let traceback = e
        .traceback(py)
        .and_then(|tb| tb.format().ok())
        .unwrap_or_default();
    // Input problems raised by blender_scripts (RenderInputError, RecipeError) are ValueErrors.
    let is_input = e.is_instance_of::<pyo3::exceptions::PyValueError>(py);
    let message = e.value(py).to_string();
    let kind = e
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    if is_input {
        RenderError::Input(format!("{kind}: {message}"))
    } else {
        RenderError::Python(format!("{traceback}{kind}: {message}"))
    }
}

/// Where the boxpose virtual environment is (see the crate docs).
pub fn find_venv() -> Option<PathBuf> {
    let valid = |p: &Path| p.join("pyvenv.cfg").is_file() && p.join("bin").join("python").exists();
    for var in ["BOXPOSE_VENV", "VIRTUAL_ENV"] {
        if let Some(p) = std::env::var_os(var).map(PathBuf::from)
            && valid(&p)
        {
            return Some(p);
        }
    }
    boxpose_data::shipped::nearest_folder_above(|dir| valid(&dir.join(".venv")))
        .map(|dir| dir.join(".venv"))
}

static INIT: Once = Once::new();
static INIT_ERROR: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Initializes the embedded interpreter as the venv's `python` (once per process). A no-op
/// when Python is already running in this process.
pub(crate) fn init_python() -> Result<()> {
    INIT.call_once(|| {
        if let Err(e) = unsafe { init_python_inner() } {
            let _ = INIT_ERROR.set(e);
        }
    });
    match INIT_ERROR.get() {
        Some(e) => Err(RenderError::Setup(e.clone())),
        None => Ok(()),
    }
}

unsafe fn init_python_inner() -> std::result::Result<(), String> {
    unsafe {
        if ffi::Py_IsInitialized() != 0 {
            return Ok(());
        }
        let venv = find_venv().ok_or("no Python virtual environment found: set BOXPOSE_VENV to the boxpose .venv (made by `make setup`)")?;
        let python = venv.join("bin").join("python");
        let program =
            CString::new(python.to_string_lossy().as_bytes()).map_err(|e| e.to_string())?;
        let mut config = std::mem::MaybeUninit::<ffi::PyConfig>::zeroed();
        ffi::PyConfig_InitPythonConfig(config.as_mut_ptr());
        let config = config.assume_init_mut();
        config.install_signal_handlers = 0; // like pyo3's Py_InitializeEx(0): Rust keeps its signals
        config.parse_argv = 0;
        let status =
            ffi::PyConfig_SetBytesString(config, &mut config.program_name, program.as_ptr());
        if ffi::PyStatus_Exception(status) != 0 {
            ffi::PyConfig_Clear(config);
            return Err(format!(
                "PyConfig_SetBytesString({}) failed",
                python.display()
            ));
        }
        let status = ffi::Py_InitializeFromConfig(config);
        ffi::PyConfig_Clear(config);
        if ffi::PyStatus_Exception(status) != 0 {
            let msg = if status.err_msg.is_null() {
                "unknown error".to_string()
            } else {
                std::ffi::CStr::from_ptr(status.err_msg)
                    .to_string_lossy()
                    .into_owned()
            };
            return Err(format!(
                "Py_InitializeFromConfig with program {}: {msg}",
                python.display()
            ));
        }
        // Release the GIL: pyo3 attaches per call from here on.
        ffi::PyEval_SaveThread();
        Ok(())
    }
}

/// The Python version the binary runs and the one the venv was made with; a mismatch means the
/// binary found another libpython3.11 (e.g. the system's) instead of the venv's base.
pub(crate) fn check_python(py: Python<'_>) -> Result<()> {
    let sys = py.import("sys").map_err(|e| py_err(py, e))?;
    let version: String = sys
        .getattr("version")
        .and_then(|v| v.extract())
        .map_err(|e| py_err(py, e))?;
    let Some(venv) = find_venv() else {
        return Ok(());
    };
    let cfg = std::fs::read_to_string(venv.join("pyvenv.cfg")).unwrap_or_default();
    let wanted = cfg.lines().find_map(|l| {
        l.strip_prefix("version")
            .map(|v| v.trim_start_matches([' ', '=']).trim().to_string())
    });
    if let Some(wanted) = wanted
        && !version.starts_with(&format!("{wanted} "))
    {
        return Err(RenderError::Setup(format!(
            "this binary runs Python {} but {} was made with {wanted}: it loaded another libpython3.11 (give the binary an rpath to the venv's base installation, see rust/render/rpath_build.rs, or set LD_LIBRARY_PATH)",
            version.split_whitespace().next().unwrap_or("?"),
            venv.display()
        )));
    }
    // The repository's python/ (blender_scripts, boxpose_io) on sys.path, even in a venv
    // without the editable install.
    let packages = venv.parent().map(|repo| repo.join("python"));
    if let Some(dir) = packages.filter(|p| p.join("blender_scripts").is_dir()) {
        let path = sys.getattr("path").map_err(|e| py_err(py, e))?;
        let dir = dir.to_string_lossy().into_owned();
        let present: bool = path
            .call_method1("__contains__", (&dir,))
            .and_then(|v| v.extract())
            .map_err(|e| py_err(py, e))?;
        if !present {
            path.call_method1("insert", (0, dir))
                .map_err(|e| py_err(py, e))?;
        }
    }
    Ok(())
}
