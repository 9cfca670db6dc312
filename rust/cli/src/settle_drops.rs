//! `boxpose settle-drops`: the scene stage's MuJoCo engine. The Drake stage samples and projects
//! a scene (python/drake_scenes) and hands its drop here as one JSON line; this answers with one
//! JSON line: the settled poses and the certificate, under the Drake stage's stop rule and
//! checks (`boxpose-physics`).

use std::io::{BufRead, Write};

use anyhow::Context;
use boxpose_physics::{BoxBody, Pose, RecipePhysics, SceneDescription, settle};
use serde_json::{Value, json};

/// Command-line options of `boxpose settle-drops`.
#[derive(clap::Args)]
#[command(
    about = "Settle scene drops read as JSON lines on stdin with MuJoCo (the scene stage's `settle.engine = \"mujoco\"`)",
    long_about = "Settle scene drops read as JSON lines on stdin with MuJoCo, one JSON line out per line in.\n\n\
        This is the scene stage's MuJoCo engine: `python -m drake_scenes` runs it for recipes with \
        `[settle] engine = \"mujoco\"`, and a line goes out as soon as its drop is settled. A line in is \
        {\"recipe_toml\": TEXT, \"boxes\": [{\"size_m\": [dx, dy, dz], \"mass_kg\": M, \"friction\": MU, \
        \"quat_wxyz\": [w, x, y, z], \"translation_m\": [x, y, z]}, …]} (the recipe's [support] and [settle] \
        sections apply; each box is dropped from its pose with zero velocity). A line out is {\"settled\", \"stable\", \
        \"rejection\" (null or the Drake stage's reason), \"poses\": [{\"quat_wxyz\", \"translation_m\"}, …], \
        \"settle_time_s\", \"max_linear_speed_mps\", \"max_angular_speed_radps\", \"min_signed_distance_m\", \
        \"wall_time_s\", \"steps\"}, or {\"error\": MESSAGE} for a line that cannot be settled; the next lines \
        are still read.",
    after_help = "Example:\n  \
        echo '{\"recipe_toml\": …, \"boxes\": […]}' | boxpose settle-drops"
)]
pub struct Args {}

pub fn run(_args: &Args) -> anyhow::Result<()> {
    let stdin = std::io::stdin().lock();
    let mut stdout = std::io::stdout().lock();
    for (number, line) in stdin.lines().enumerate() {
        let line = line.context("reading stdin")?;
        if line.trim().is_empty() {
            continue;
        }
        let answer = settle_line(&line)
            .unwrap_or_else(|e| json!({"error": format!("line {}: {e:#}", number + 1)}));
        // one line per drop, flushed: the caller waits for it before sending the next
        writeln!(stdout, "{answer}")?;
        stdout.flush()?;
    }
    Ok(())
}

fn settle_line(line: &str) -> anyhow::Result<Value> {
    let drop: Value = serde_json::from_str(line).context("not a JSON object")?;
    let recipe_toml = drop["recipe_toml"]
        .as_str()
        .context("\"recipe_toml\" must be the recipe's TOML text")?;
    let recipe = RecipePhysics::from_toml(recipe_toml).context("recipe_toml")?;
    let boxes = drop["boxes"]
        .as_array()
        .context("\"boxes\" must be a list")?
        .iter()
        .enumerate()
        .map(|(i, b)| box_body(b).with_context(|| format!("boxes[{i}]")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let scene = SceneDescription {
        support: recipe.support,
        boxes,
    };
    let outcome = settle(&scene, &recipe.settle)?;
    let c = &outcome.certificate;
    Ok(json!({
        "settled": outcome.settled,
        "stable": outcome.stable,
        "rejection": outcome.rejection.map(|r| r.as_str()),
        "poses": outcome.poses.iter().map(|p| json!({
            "quat_wxyz": p.quat_wxyz,
            "translation_m": p.translation,
        })).collect::<Vec<_>>(),
        "settle_time_s": c.settle_time_s,
        "max_linear_speed_mps": c.max_linear_speed_mps,
        "max_angular_speed_radps": c.max_angular_speed_radps,
        "min_signed_distance_m": c.min_signed_distance_m,
        "wall_time_s": c.wall_time_s,
        "steps": c.steps,
    }))
}

fn numbers<const N: usize>(value: &Value, key: &str) -> anyhow::Result<[f64; N]> {
    let list = value[key]
        .as_array()
        .filter(|l| l.len() == N)
        .with_context(|| format!("\"{key}\" must be a list of {N} numbers"))?;
    let mut out = [0.0; N];
    for (slot, v) in out.iter_mut().zip(list) {
        *slot = v
            .as_f64()
            .with_context(|| format!("\"{key}\" must be a list of {N} numbers, got {v}"))?;
    }
    Ok(out)
}

fn number(value: &Value, key: &str) -> anyhow::Result<f64> {
    value[key]
        .as_f64()
        .with_context(|| format!("\"{key}\" must be a number"))
}

fn box_body(value: &Value) -> anyhow::Result<BoxBody> {
    Ok(BoxBody {
        size: numbers(value, "size_m")?,
        mass_kg: number(value, "mass_kg")?,
        friction: number(value, "friction")?,
        initial: Pose {
            quat_wxyz: numbers(value, "quat_wxyz")?,
            translation: numbers(value, "translation_m")?,
        },
        at_rest: false,
    })
}
