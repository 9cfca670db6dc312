//! The system under test a run names, loaded: its networks and fit, or its external process, and
//! the embedded Blender — one place for `boxpose search`, `search replay` and `search variants`.

use std::path::Path;
use std::time::Duration;

use boxpose_learn::backend::BackendKind;
use boxpose_learn::inference::KeypointModel;
use boxpose_learn::segmentation::SegmenterModel;
use boxpose_render::Renderer;

use crate::error::{Result, SearchError};
use crate::external::ExternalSut;
use crate::run::{Run, RunSettings};
use crate::space::SearchSpace;
use crate::sut::{self, Crops, SystemUnderTest};

/// How long a run's external system may take per sample when the command that resumes or replays
/// it does not say (`boxpose search --sut-timeout`'s default).
pub const DEFAULT_SUT_TIMEOUT: Duration = Duration::from_secs(60);

/// The search space a run recorded (its texts and pile, not today's files).
pub fn space_of(run: &Run) -> Result<SearchSpace> {
    SearchSpace::from_texts(
        &run.record.space_toml,
        &run.record.recipe_toml,
        run.record.pile.clone(),
    )
}

/// The system `settings` name: the external process (`external` when the caller started it
/// already, to refuse a system that cannot start before any folder is made), or the networks
/// (`model` instead of the run's keypoint network, for a replay) and the fit; with a renderer of
/// `threads` Cycles threads.
pub fn load(
    space: &SearchSpace,
    settings: &RunSettings,
    model: Option<&Path>,
    external: Option<ExternalSut>,
    threads: usize,
    backend: BackendKind,
) -> Result<SystemUnderTest> {
    if let Some(spec) = &settings.sut {
        if model.is_some() {
            return Err(SearchError::Sample(format!(
                "the run tested another system (--sut {spec}): a keypoint network does not apply"
            )));
        }
        let system = match external {
            Some(system) => system,
            None => ExternalSut::start(spec, DEFAULT_SUT_TIMEOUT)?,
        };
        let mut sut =
            SystemUnderTest::external(space, Renderer::new(threads)?, system, settings.crops)?;
        sut.sensor_depth = settings.sensor_depth;
        return Ok(sut);
    }
    let method = sut::method_named(&settings.fit).map_err(SearchError::Sample)?;
    let device = backend.device()?;
    let network = KeypointModel::load(model.unwrap_or(Path::new(&settings.model)), device.clone())?;
    let segmenter = match (settings.crops, &settings.segmenter) {
        (Crops::Predicted, Some(dir)) => Some(SegmenterModel::load(Path::new(dir), device)?),
        _ => None,
    };
    let renderer = Renderer::new(threads)?;
    let mut sut =
        SystemUnderTest::new(space, renderer, network, segmenter, settings.crops, method)?;
    sut.whole_frames = settings.whole_frames;
    sut.refine_depth = settings.refine_depth;
    sut.sensor_depth = settings.sensor_depth;
    sut.two_resolutions = settings.two_resolutions;
    Ok(sut)
}
