/// Everything that can go wrong when building or settling a scene. Messages name the box and the
/// bad value, so the caller never needs a backtrace.
#[derive(Debug, thiserror::Error)]
pub enum PhysicsError {
    #[error("scene has no boxes")]
    NoBoxes,
    #[error("box {index}: size {size:?} m must be finite and positive on every axis")]
    BadSize { index: usize, size: [f64; 3] },
    #[error("box {index}: mass {mass_kg} kg must be finite and positive")]
    BadMass { index: usize, mass_kg: f64 },
    #[error("box {index}: friction {friction} must be finite and non-negative")]
    BadFriction { index: usize, friction: f64 },
    #[error(
        "box {index}: pose is not finite (quat_wxyz {quat_wxyz:?}, translation {translation:?})"
    )]
    NonFinitePose {
        index: usize,
        quat_wxyz: [f64; 4],
        translation: [f64; 3],
    },
    #[error("box {index}: quaternion {quat_wxyz:?} has norm {norm}, not 1")]
    NonUnitQuaternion {
        index: usize,
        quat_wxyz: [f64; 4],
        norm: f64,
    },
    #[error("{rows} objects rows, but the scene declares num_objects = {declared}")]
    ObjectCount { rows: usize, declared: usize },
    #[error("{count} initial poses given for a scene of {expected} boxes")]
    PoseCount { count: usize, expected: usize },
    #[error("box {index} cannot be moved: the pile has {count} boxes")]
    NoSuchBox { index: usize, count: usize },
    #[error("support: {0}")]
    BadSupport(String),
    #[error("settle parameters: {0}")]
    BadParams(String),
    #[error("recipe: {0}")]
    Recipe(String),
    #[error("MuJoCo could not compile the generated MJCF: {message}")]
    Compile { message: String },
    #[error("MuJoCo: {0}")]
    MuJoCo(String),
    #[error(
        "simulation diverged at t = {time_s} s ({warning}); the initial state is probably deeply interpenetrating"
    )]
    Diverged { time_s: f64, warning: String },
}

pub type Result<T, E = PhysicsError> = std::result::Result<T, E>;
