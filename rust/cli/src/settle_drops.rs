//! `boxpose settle-drops`: the scene stage's MuJoCo engine. The Drake stage samples and projects
//! a scene (python/drake_scenes) and hands its drop here as one JSON line; this answers with one
//! JSON line: the settled poses and the certificate, under the Drake stage's stop rule and
//! checks (`boxpose_physics::settle_drop`).

use std::io::{BufRead, Write};

use anyhow::Context;
use serde_json::json;

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
        let answer = boxpose_physics::settle_drop(&line)
            .unwrap_or_else(|e| json!({"error": format!("line {}: {e}", number + 1)}));
        // one line per drop, flushed: the caller waits for it before sending the next
        writeln!(stdout, "{answer}")?;
        stdout.flush()?;
    }
    Ok(())
}
