//! In-process re-rendering of boxpose scenes: an embedded CPython (pyo3) imports Blender's `bpy`
//! and `blender_scripts` once; a [`Renderer`] loads a scene from its `scenes` / `objects` rows and
//! renders any of its frames — at any sample count, only a crop region (Cycles border render), or
//! with changed box poses — returning the `frames` / `instances` rows as Arrow record batches
//! through the Arrow C data interface (no temporary files, no process per render).
//!
//! The loaded scene stays in Blender between renders (Cycles keeps its scene data), so a
//! re-render after a pose change costs only the render itself.
//!
//! # Finding Python
//! The binary links pyenv's `libpython3.11.so` (rpath set by this crate's build script and, for
//! binaries, by `rpath_build.rs`). At run time the interpreter is initialized as if it were the
//! boxpose virtual environment's `python` (its `pyvenv.cfg` selects the base installation and
//! the venv's site-packages, where `make setup` installs the stage packages editable): the venv is
//! `$BOXPOSE_VENV`, else `$VIRTUAL_ENV`, else the `.venv` of the repository holding the binary or
//! this crate. The repository root and `python/` are also put on `sys.path` directly.

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering};

pub use arrow;
use arrow::record_batch::RecordBatch;
use arrow_pyarrow::{FromPyArrow, ToPyArrow};
use boxpose_data::Pose;
use boxpose_data::schema::{self, Table};
use pyo3::ffi;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

/// Errors of the renderer; Python exceptions carry their traceback.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("cannot set up the embedded Python: {0}")]
    Setup(String),
    #[error("{0}")]
    Python(String),
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Data(#[from] boxpose_data::DataError),
}

pub type Result<T> = std::result::Result<T, RenderError>;

fn py_err(py: Python<'_>, e: PyErr) -> RenderError {
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
    let mut starts = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        starts.push(exe);
    }
    starts.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    for start in starts {
        for dir in start.ancestors() {
            let venv = dir.join(".venv");
            if valid(&venv) {
                return Some(venv);
            }
        }
    }
    None
}

static INIT: Once = Once::new();
static INIT_ERROR: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Initializes the embedded interpreter as the venv's `python` (once per process). A no-op
/// when Python is already running in this process.
fn init_python() -> Result<()> {
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
fn check_python(py: Python<'_>) -> Result<()> {
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
    // The repository (blender_scripts) and python/ (boxpose_io) on sys.path, even in a venv
    // without the editable install.
    let repo = venv.parent().map(Path::to_path_buf);
    if let Some(repo) = repo.filter(|r| r.join("blender_scripts").is_dir()) {
        let path = sys.getattr("path").map_err(|e| py_err(py, e))?;
        for dir in [repo.join("python"), repo] {
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
    }
    Ok(())
}

mod quiet;

static LIVE: AtomicBool = AtomicBool::new(false);

/// What to render of the loaded scene. `Default` renders frame 0 as the recipe says.
#[derive(Debug, Clone, Default)]
pub struct RenderRequest {
    pub frame_id: i32,
    /// Cycles samples; `None`: the recipe's `[render] samples`.
    pub samples: Option<i32>,
    /// OpenImageDenoise; `None`: the recipe's `[render] denoise`.
    pub denoise: Option<bool>,
    /// Render only the pixels [x0, x1) × [y0, y1) of the frame; the returned frame is that
    /// region (width x1 − x0, principal point shifted by (x0, y0)).
    pub crop: Option<[u32; 4]>,
    /// Simulated structured-light depth; `None`: the recipe's `[render] sensor_depth`.
    pub sensor_depth: Option<bool>,
    /// Boxes moved for this render only: (object_id, T_world_box).
    pub poses: Vec<(i32, Pose)>,
    /// Render only the region around one box: (object_id, margin), the square of side
    /// max(margin, 1) × the longer side of its projected corners' bounding box, centred on it,
    /// plus 2 pixels (the whole frame when the box is partly behind the camera). Excludes `crop`.
    pub crop_object: Option<(i32, f64)>,
}

/// The rows of one render: one `frames` row and the frame's `instances` rows, with the
/// contract's schemas.
#[derive(Debug, Clone)]
pub struct Rendered {
    pub frames: RecordBatch,
    pub instances: RecordBatch,
}

/// The embedded Blender, holding at most one loaded scene. One per process (bpy is global).
pub struct Renderer {
    session: Py<PyAny>,
    scene_id: Option<i64>,
    /// Cycles initializes its devices on the first render (and warns about CUDA then).
    rendered: bool,
}

impl Renderer {
    /// Starts Python, imports bpy and blender_scripts, resets Blender. `threads`: Cycles threads
    /// (0 = all cores).
    pub fn new(threads: usize) -> Result<Self> {
        if LIVE.swap(true, Ordering::SeqCst) {
            return Err(RenderError::Setup(
                "a Renderer already exists in this process (bpy is process-global)".into(),
            ));
        }
        let made = Self::start(threads);
        if made.is_err() {
            LIVE.store(false, Ordering::SeqCst);
        }
        made
    }

    fn start(threads: usize) -> Result<Self> {
        init_python()?;
        quiet::filter_output(|| Self::start_session(threads))
    }

    fn start_session(threads: usize) -> Result<Self> {
        Python::attach(|py| {
            check_python(py)?;
            if let Err(e) = py.import("bpy") {
                let sys_exe: String = py
                    .import("sys")
                    .and_then(|s| s.getattr("executable"))
                    .and_then(|v| v.extract())
                    .unwrap_or_default();
                return Err(RenderError::Setup(format!(
                    "bpy is not importable by the embedded Python ({sys_exe}): {}",
                    e.value(py)
                )));
            }
            let module = py
                .import("blender_scripts.session")
                .map_err(|e| py_err(py, e))?;
            let session = module
                .getattr("Session")
                .and_then(|s| s.call1((threads,)))
                .map_err(|e| py_err(py, e))?;
            quiet::at_exit();
            Ok(Self {
                session: session.unbind(),
                scene_id: None,
                rendered: false,
            })
        })
    }

    /// The scene currently loaded, if any.
    pub fn scene_id(&self) -> Option<i64> {
        self.scene_id
    }

    /// Builds scene `scene_id` in Blender from `scenes` and `objects` batches (contract schemas;
    /// other scenes' rows are ignored).
    pub fn load_scene(
        &mut self,
        scenes: &RecordBatch,
        objects: &RecordBatch,
        scene_id: i64,
    ) -> Result<()> {
        self.scene_id = None;
        Python::attach(|py| {
            let scenes = scenes.to_pyarrow(py).map_err(|e| py_err(py, e))?;
            let objects = objects.to_pyarrow(py).map_err(|e| py_err(py, e))?;
            self.session
                .bind(py)
                .call_method1("load_batches", (scenes, objects, scene_id))
                .map_err(|e| py_err(py, e))?;
            Ok::<(), RenderError>(())
        })?;
        self.scene_id = Some(scene_id);
        Ok(())
    }

    /// Loads scene `scene_id` of a dataset folder (reads its `scenes` and `objects` tables).
    pub fn load_from_dataset(&mut self, dataset: &Path, scene_id: i64) -> Result<()> {
        let (scenes, objects) = scene_rows(dataset, scene_id)?;
        self.load_scene(&scenes, &objects, scene_id)
    }

    /// Renders a frame of the loaded scene.
    pub fn render(&mut self, request: &RenderRequest) -> Result<Rendered> {
        if self.scene_id.is_none() {
            return Err(RenderError::Input(
                "no scene loaded: call load_scene first".into(),
            ));
        }
        if !self.rendered {
            self.rendered = true;
            return quiet::filter_output(|| self.render_now(request));
        }
        self.render_now(request)
    }

    fn render_now(&self, request: &RenderRequest) -> Result<Rendered> {
        Python::attach(|py| {
            let kwargs = PyDict::new(py);
            let set =
                |k: &str, v: Bound<'_, PyAny>| kwargs.set_item(k, v).map_err(|e| py_err(py, e));
            set(
                "frame_id",
                request
                    .frame_id
                    .into_pyobject(py)
                    .map_err(|e| py_err(py, e.into()))?
                    .into_any(),
            )?;
            if let Some(s) = request.samples {
                set(
                    "samples",
                    s.into_pyobject(py)
                        .map_err(|e| py_err(py, e.into()))?
                        .into_any(),
                )?;
            }
            if let Some(d) = request.denoise {
                set(
                    "denoise",
                    pyo3::types::PyBool::new(py, d).to_owned().into_any(),
                )?;
            }
            if let Some(d) = request.sensor_depth {
                set(
                    "sensor_depth",
                    pyo3::types::PyBool::new(py, d).to_owned().into_any(),
                )?;
            }
            if let Some(c) = request.crop {
                set(
                    "crop",
                    PyTuple::new(py, c).map_err(|e| py_err(py, e))?.into_any(),
                )?;
            }
            if let Some(c) = request.crop_object {
                set(
                    "crop_object",
                    c.into_pyobject(py).map_err(|e| py_err(py, e))?.into_any(),
                )?;
            }
            if !request.poses.is_empty() {
                let poses = PyDict::new(py);
                for (oid, pose) in &request.poses {
                    let value = (pose.quat_wxyz.to_vec(), pose.translation.to_vec());
                    poses.set_item(*oid, value).map_err(|e| py_err(py, e))?;
                }
                set("poses", poses.into_any())?;
            }
            let out = self
                .session
                .bind(py)
                .call_method("render_batches", (), Some(&kwargs))
                .map_err(|e| py_err(py, e))?;
            let frames =
                RecordBatch::from_pyarrow_bound(&out.get_item(0).map_err(|e| py_err(py, e))?)
                    .map_err(|e| py_err(py, e))?;
            let instances =
                RecordBatch::from_pyarrow_bound(&out.get_item(1).map_err(|e| py_err(py, e))?)
                    .map_err(|e| py_err(py, e))?;
            check_schema(&frames, &schema::FRAMES)?;
            check_schema(&instances, &schema::INSTANCES)?;
            Ok(Rendered { frames, instances })
        })
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        LIVE.store(false, Ordering::SeqCst);
    }
}

fn check_schema(batch: &RecordBatch, table: &Table) -> Result<()> {
    let expected = table.arrow_schema();
    if batch.schema().fields() != expected.fields() {
        return Err(RenderError::Python(format!(
            "blender_scripts returned a {} batch whose schema differs from the contract",
            table.name
        )));
    }
    Ok(())
}

/// The `scenes` row of `scene_id` and its `objects` rows from a dataset folder, as batches.
pub fn scene_rows(dataset: &Path, scene_id: i64) -> Result<(RecordBatch, RecordBatch)> {
    let ds = boxpose_data::Dataset::open(dataset)?;
    let pick = |table: &'static Table| -> Result<RecordBatch> {
        let mut parts = Vec::new();
        for sb in ds.read_table(table)? {
            let ids = sb.batch.column_by_name("scene_id").expect("validated");
            let ids =
                arrow::array::AsArray::as_primitive::<arrow::datatypes::Int64Type>(ids.as_ref());
            let keep: arrow::array::BooleanArray =
                ids.iter().map(|v| Some(v == Some(scene_id))).collect();
            let part = arrow::compute::filter_record_batch(&sb.batch, &keep)
                .map_err(|e| RenderError::Input(e.to_string()))?;
            if part.num_rows() > 0 {
                parts.push(part);
            }
        }
        let schema = std::sync::Arc::new(table.arrow_schema());
        let parts = parts
            .iter()
            .map(|p| conform(p, table))
            .collect::<Result<Vec<_>>>()?;
        arrow::compute::concat_batches(&schema, &parts)
            .map_err(|e| RenderError::Input(e.to_string()))
    };
    let scenes = pick(&schema::SCENES)?;
    if scenes.num_rows() == 0 {
        return Err(RenderError::Input(format!(
            "scene {scene_id} is not in {}",
            dataset.display()
        )));
    }
    Ok((scenes, pick(&schema::OBJECTS)?))
}

/// `batch` with exactly the contract schema of `table`: columns in contract order, cast to the
/// contract types (Parquet writers name fixed-size-list items differently).
pub fn conform(batch: &RecordBatch, table: &Table) -> Result<RecordBatch> {
    let schema = std::sync::Arc::new(table.arrow_schema());
    let mut columns = Vec::with_capacity(table.columns.len());
    for column in table.columns {
        let array = batch.column_by_name(column.name).ok_or_else(|| {
            RenderError::Input(format!("{} batch lacks column {}", table.name, column.name))
        })?;
        columns.push(
            arrow::compute::cast(array, &column.arrow_type())
                .map_err(|e| RenderError::Input(format!("{}.{}: {e}", table.name, column.name)))?,
        );
    }
    RecordBatch::try_new(schema, columns)
        .map_err(|e| RenderError::Input(format!("{}: {e}", table.name)))
}
