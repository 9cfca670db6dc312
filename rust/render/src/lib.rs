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

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use arrow_pyarrow::{FromPyArrow, ToPyArrow};
use boxpose_data::Pose;
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_data::schema::{self, Table};
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

mod python;
mod quiet;

pub use python::find_venv;
use python::{check_python, init_python, py_err};
pub use quiet::quiet_blender_output;

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
    /// Render the whole frame smaller, this many pixels across: the height and focal lengths
    /// scaled alike, the principal point at the centre (what a network that reads a smaller image
    /// sees); at or above the recipe's width the recipe's size. Excludes `crop` and
    /// `crop_object`; `render_settings` then records the recipe's size as `scaled_from`.
    pub width: Option<u32>,
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
            let bpy = match py.import("bpy") {
                Ok(bpy) => bpy,
                Err(e) => {
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
            };

            let module = py
                .import("blender_scripts.session")
                .map_err(|e| py_err(py, e))?;
            let session = module
                .getattr("Session")
                .and_then(|s| s.call1((threads,)))
                .map_err(|e| py_err(py, e))?;
            // read after the Session: resetting Blender to factory settings makes a new one
            let blender_tempdir: String = bpy
                .getattr("app")
                .and_then(|app| app.getattr("tempdir"))
                .and_then(|dir| dir.extract())
                .map_err(|e| py_err(py, e))?;
            quiet::at_exit(Path::new(&blender_tempdir));
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
            let options = || -> PyResult<()> {
                kwargs.set_item("frame_id", request.frame_id)?;
                set_given(&kwargs, "samples", request.samples)?;
                set_given(&kwargs, "denoise", request.denoise)?;
                set_given(&kwargs, "sensor_depth", request.sensor_depth)?;
                let crop = request.crop.map(|c| PyTuple::new(py, c)).transpose()?;
                set_given(&kwargs, "crop", crop)?;
                set_given(&kwargs, "crop_object", request.crop_object)?;
                set_given(&kwargs, "width", request.width)?;
                if !request.poses.is_empty() {
                    let poses = PyDict::new(py);
                    for (oid, pose) in &request.poses {
                        let value = (pose.quat_wxyz.to_vec(), pose.translation.to_vec());
                        poses.set_item(*oid, value)?;
                    }
                    kwargs.set_item("poses", poses)?;
                }
                Ok(())
            };
            options().map_err(|e| py_err(py, e))?;
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

/// Sets `key` to the request's value when it gives one, so the session's default holds otherwise.
fn set_given<'py, V: IntoPyObject<'py>>(
    kwargs: &Bound<'py, PyDict>,
    key: &str,
    value: Option<V>,
) -> PyResult<()> {
    value.map_or(Ok(()), |v| kwargs.set_item(key, v))
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

/// The `scenes` row of `scene_id` and its `objects` rows from a dataset folder, as batches of the
/// contract's schema ([`boxpose_data::Dataset::scene_batches`]).
pub fn scene_rows(dataset: &Path, scene_id: i64) -> Result<(RecordBatch, RecordBatch)> {
    boxpose_data::Dataset::open(dataset)?
        .scene_batches(scene_id)?
        .ok_or_else(|| {
            RenderError::Input(format!("scene {scene_id} is not in {}", dataset.display()))
        })
}
