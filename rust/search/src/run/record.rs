//! `run.json`: what a run searches and how, and the check that a resumed or sharded process
//! finds the same.

use boxpose_search_stats::{CeConfig, CeError, SplittingConfig, SplittingError};
use serde::{Deserialize, Serialize};

use super::AUTO_TILT;
use crate::error::{Result, SearchError};
use crate::space::SearchSpace;
use crate::sut::{Crops, Predicate};

/// Version of the run folder's layout and `run.json`.
pub const RUN_FORMAT: u32 = 1;

/// Which sampler draws the scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Naive Monte Carlo from the nominal distribution.
    Mc,
    /// Cross-entropy adaptive importance sampling, then a frozen defensive proposal.
    Ce,
    /// Subset simulation (adaptive multilevel splitting) from the nominal.
    Splitting,
}

impl Sampler {
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Mc => "mc",
            Sampler::Ce => "ce",
            Sampler::Splitting => "splitting",
        }
    }
}

/// How a run samples and scores; stored in `run.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSettings {
    pub sampler: Sampler,
    /// Monte Carlo: samples in all. Cross-entropy: the final batch (`ce.final_samples`).
    /// Subset simulation: particles per stage (`splitting.particles`).
    pub samples: usize,
    /// Samples per batch file (the unit of resumption and of sharding).
    pub batch_size: usize,
    pub seed: u64,
    pub crops: Crops,
    /// Render whole frames even for ground-truth crops (the samples' frames then differ from a
    /// region render's, so it is part of the run's identity).
    #[serde(default)]
    pub whole_frames: bool,
    /// The fit's pose laid on the depth image's points of the box's visible faces
    /// (`--refine-depth`; [`boxpose_geometry::depth_refine`]).
    #[serde(default)]
    pub refine_depth: bool,
    /// The perception reads the simulated sensor's depth (`--sensor-depth`;
    /// [`boxpose_data::Frame::use_sensor_depth`]), not the exact render depth.
    #[serde(default)]
    pub sensor_depth: bool,
    /// Segmenter crops from two renders: the whole frame at the segmenter's input width, the
    /// keypoint network's window at full resolution (`SystemUnderTest::two_resolutions`). False
    /// in runs recorded before it existed, which rendered the whole frame at full resolution.
    #[serde(default)]
    pub two_resolutions: bool,
    /// The pose fit: paper, fast, robust or size.
    pub fit: String,
    pub predicate: Predicate,
    /// Cross-entropy settings (`final_samples` is `samples`); unused by Monte Carlo.
    pub ce: CeConfig,
    /// Cross-entropy: the parameters the proposal may tilt (names or prefixes of z's dimensions,
    /// e.g. `target.size_m`); the others stay at their nominal, so they add no weight variance.
    /// Empty: all of them. [`AUTO_TILT`] alone: chosen from the nominal tuning iterations' scores
    /// ([`boxpose_search_stats::choose_tilt`]).
    #[serde(default)]
    pub ce_tilt: Vec<String>,
    /// Subset simulation's settings (`particles` is `samples`); only with that sampler.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub splitting: Option<SplittingConfig>,
    /// The networks, as given (their files are not hashed).
    pub model: String,
    pub segmenter: Option<String>,
    /// An external system under test (`exec:COMMAND` or `python:MODULE:CALLABLE`), instead of
    /// the networks; as given (what it runs is not hashed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sut: Option<String>,
}

/// `run.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub format: u32,
    pub settings: RunSettings,
    pub space_toml: String,
    pub recipe_toml: String,
    /// Names of z's dimensions, in order.
    pub dimensions: Vec<String>,
    /// The strata (neighbour counts), each of nominal probability 1 / len.
    pub strata: Vec<u32>,
    /// A `[pile]` space's boxes, as read from its dataset when the run started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pile: Option<Vec<crate::space::PileBox>>,
}

impl RunRecord {
    pub fn new(space: &SearchSpace, settings: RunSettings) -> Result<Self> {
        if settings.samples == 0 || settings.batch_size == 0 {
            return Err(SearchError::Settings(
                "--samples and --batch-size must be at least 1".into(),
            ));
        }
        if settings.sampler == Sampler::Ce {
            let mut ce = settings.ce.clone();
            ce.final_samples = settings.samples;
            ce.validate().map_err(|e| match e {
                CeError::Config { key, message } => {
                    SearchError::Settings(format!("{}: {message}", ce_flag(key)))
                }
                other => SearchError::Settings(other.to_string()),
            })?;
        }
        match (settings.sampler, &settings.splitting) {
            (Sampler::Splitting, Some(config)) => {
                if config.particles != settings.samples {
                    return Err(SearchError::Settings(format!(
                        "splitting particles {} differ from --samples {}",
                        config.particles, settings.samples
                    )));
                }
                config.validate().map_err(|e| match e {
                    SplittingError::Config { key, message } => SearchError::Settings(format!(
                        "{}: {message}",
                        if key == "particles" {
                            "--samples".to_string()
                        } else {
                            setting_flag(&format!("splitting.{key}"))
                        }
                    )),
                    other => SearchError::Settings(other.to_string()),
                })?;
                if space.strata().len() > 1 {
                    return Err(SearchError::Settings(format!(
                        "--sampler splitting draws from one stratum, and this space has {} \
                         (its neighbour counts): use --sampler mc or ce",
                        space.strata().len()
                    )));
                }
            }
            (Sampler::Splitting, None) => {
                return Err(SearchError::Settings(
                    "--sampler splitting needs its settings".into(),
                ));
            }
            (_, Some(_)) => {
                return Err(SearchError::Settings(
                    "splitting settings are for --sampler splitting only".into(),
                ));
            }
            (_, None) => {}
        }
        let names: Vec<&str> = space.dimensions.iter().map(|d| d.name.as_str()).collect();
        if settings.ce_tilt.iter().any(|t| t == AUTO_TILT) {
            if settings.ce_tilt.len() > 1 {
                return Err(SearchError::Settings(format!(
                    "--ce-tilt {AUTO_TILT} chooses the parameters itself: give it alone, or name them"
                )));
            }
            if settings.ce.samples_per_iteration < boxpose_search_stats::tilt::MIN_SAMPLES {
                return Err(SearchError::Settings(format!(
                    "--ce-tilt {AUTO_TILT} tests the first iteration's samples: give \
                     --ce-samples-per-iteration at least {} (a few hundred to find weak effects)",
                    boxpose_search_stats::tilt::MIN_SAMPLES
                )));
            }
        }
        for prefix in settings.ce_tilt.iter().filter(|t| *t != AUTO_TILT) {
            if !names.iter().any(|n| n.starts_with(prefix.as_str())) {
                return Err(SearchError::Settings(format!(
                    "--ce-tilt {prefix}: no parameter of the space starts with it (they are: {})",
                    names.join(", ")
                )));
            }
        }
        Ok(Self {
            format: RUN_FORMAT,
            settings,
            space_toml: space.text.clone(),
            recipe_toml: space.recipe_toml.clone(),
            dimensions: space.dimensions.iter().map(|d| d.name.clone()).collect(),
            strata: space.strata(),
            pile: space.pile.clone(),
        })
    }
}

/// The `boxpose search` flag that sets a cross-entropy setting, for errors in the user's terms.
fn ce_flag(key: &str) -> String {
    match key {
        "final_samples" => "--samples".to_string(),
        "defensive_lambda" => "--ce-lambda".to_string(),
        other => format!("--ce-{}", other.replace('_', "-")),
    }
}

/// Refuses a shard that is not one of `num_shards` (checked before a run folder is touched).
pub fn check_shard(shard: usize, num_shards: usize) -> Result<()> {
    if num_shards == 0 || shard >= num_shards {
        return Err(SearchError::Settings(format!(
            "--shard {shard} is not below --num-shards {num_shards} (shards are numbered 0 to N − 1, N ≥ 1)"
        )));
    }
    Ok(())
}

/// What differs between the search a run folder holds (`run`) and a command's (`this`), in the
/// command's terms: the flag (or the file) and both values.
pub(crate) fn differences(run: &RunRecord, this: &RunRecord) -> Vec<String> {
    let mut out = Vec::new();
    if run.space_toml != this.space_toml {
        out.push("the search space differs".to_string());
    }
    if run.recipe_toml != this.recipe_toml {
        out.push("the base recipe differs".to_string());
    }
    if run.pile != this.pile {
        out.push("the pile's boxes differ (its dataset changed since the run started)".to_string());
    }
    let fields = |settings: &RunSettings| match serde_json::to_value(settings) {
        Ok(serde_json::Value::Object(fields)) => fields,
        _ => unreachable!("run settings serialise as a JSON object"),
    };
    let (theirs, ours) = (fields(&run.settings), fields(&this.settings));
    let shown = |value: Option<&serde_json::Value>| match value {
        Some(serde_json::Value::String(text)) => text.clone(),
        Some(serde_json::Value::Null) | None => "none".to_string(),
        Some(value) => value.to_string(),
    };
    let mut differ =
        |name: &str, theirs: Option<&serde_json::Value>, ours: Option<&serde_json::Value>| {
            if theirs != ours {
                out.push(format!(
                    "{} is {} there, {} here",
                    setting_flag(name),
                    shown(theirs),
                    shown(ours)
                ));
            }
        };
    for (key, value) in &theirs {
        match (key.as_str(), value, ours.get(key)) {
            ("ce", serde_json::Value::Object(theirs), Some(serde_json::Value::Object(ours))) => {
                for (ce_key, value) in theirs {
                    // the final stage's sample count is --samples, compared above
                    if ce_key != "final_samples" {
                        differ(&format!("ce.{ce_key}"), Some(value), ours.get(ce_key));
                    }
                }
            }
            (
                "splitting",
                serde_json::Value::Object(theirs),
                Some(serde_json::Value::Object(ours)),
            ) => {
                for (split_key, value) in theirs {
                    // the particles are --samples, compared above
                    if split_key != "particles" {
                        differ(
                            &format!("splitting.{split_key}"),
                            Some(value),
                            ours.get(split_key),
                        );
                    }
                }
            }
            // follows from --crops and --whole-frames (no flag of its own), named above
            ("two_resolutions", ..) => {}
            (_, value, ours) => differ(key, Some(value), ours),
        }
    }
    if out.is_empty() {
        out.push("its record differs".to_string());
    }
    out
}

/// The command-line flag that sets a field of [`RunSettings`] (dotted for `ce`).
fn setting_flag(field: &str) -> String {
    let flag = match field {
        "predicate" => "fail-when",
        "ce.defensive_lambda" => "ce-lambda",
        other => other,
    };
    format!("--{}", flag.replace(['_', '.'], "-"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_of_another_search_names_each_setting_that_differs() {
        let record = RunRecord {
            format: RUN_FORMAT,
            settings: RunSettings {
                sampler: Sampler::Ce,
                samples: 100,
                batch_size: 25,
                seed: 3,
                crops: Crops::Gt,
                whole_frames: false,
                refine_depth: false,
                sensor_depth: false,
                two_resolutions: false,
                fit: "paper".into(),
                predicate: Predicate::default(),
                ce: CeConfig::default(),
                ce_tilt: Vec::new(),
                splitting: None,
                model: "models/keypoint-slim".into(),
                segmenter: None,
                sut: None,
            },
            space_toml: "name = \"single_box\"".into(),
            recipe_toml: String::new(),
            dimensions: Vec::new(),
            strata: vec![0],
            pile: None,
        };
        let mut other = record.clone();
        other.settings.seed = 4;
        other.settings.model = "models/keypoint-slm".into();
        other.settings.ce.defensive_lambda = 0.25;
        other.settings.ce.final_samples += 1;
        let mut found = differences(&record, &other);
        found.sort();
        let lambda = record.settings.ce.defensive_lambda;
        assert_eq!(
            found,
            [
                format!("--ce-lambda is {lambda} there, 0.25 here"),
                "--model is models/keypoint-slim there, models/keypoint-slm here".into(),
                "--seed is 3 there, 4 here".into(),
            ]
        );
        other = record.clone();
        other.space_toml = "name = \"clutter\"".into();
        assert_eq!(differences(&record, &other), ["the search space differs"]);
        // splitting's settings by their flags; its particles are --samples, named once
        let mut split = record.clone();
        split.settings.sampler = Sampler::Splitting;
        split.settings.splitting = Some(SplittingConfig {
            particles: 100,
            ..SplittingConfig::default()
        });
        let mut other = split.clone();
        let settings = other.settings.splitting.as_mut().unwrap();
        settings.level_probability = 0.2;
        settings.particles = 200;
        other.settings.samples = 200;
        let mut found = differences(&split, &other);
        found.sort();
        assert_eq!(
            found,
            [
                "--samples is 100 there, 200 here",
                "--splitting-level-probability is 0.1 there, 0.2 here"
            ]
        );
        // a run recorded before the scene seed could be kept drew a new one at every move: it
        // reads as 0, and a command with today's default is told which flag resumes it
        let mut old: serde_json::Value = serde_json::to_value(&split).unwrap();
        old["settings"]["splitting"]
            .as_object_mut()
            .unwrap()
            .remove("keep_scene_seed");
        let old: RunRecord = serde_json::from_value(old).unwrap();
        assert_eq!(
            old.settings.splitting.as_ref().unwrap().keep_scene_seed,
            0.0
        );
        let mut today = split.clone();
        today.settings.splitting.as_mut().unwrap().keep_scene_seed = 0.8;
        assert_eq!(
            differences(&old, &today),
            ["--splitting-keep-scene-seed is 0.0 there, 0.8 here"]
        );
    }
}
