//! `boxpose samples`: the keypoint network's training examples for another framework's training
//! loop (`boxpose_io.torch`), drawn by the very code `boxpose train` draws them with, spoken as
//! protocol `boxpose-samples/1` on a reader and a writer (the binary's stdin and stdout).
//!
//! 1. The server introduces itself with one JSON line ([`Hello`]): the protocol, how many training
//!    and held-out items the config's datasets hold, and the arrays' shapes.
//! 2. Each request is one JSON line ([`Request`]): `{"request": n, "split": "train", "index": i,
//!    "seed": s}`. A training item with a seed is augmented as training augments it with the
//!    random stream `ChaCha8Rng::seed_from_u64(s)` (the depth it reads, then the crop's jitter,
//!    turn and colour; `boxpose train` seeds each example's stream from its run seed, step and
//!    slot); without a seed, and always for `"held_out"`, it is read as validation reads it.
//! 3. The answer is one JSON line ([`Answer`]) and then its payloads, raw, in this order: the input
//!    (`input_shape` little-endian f32: R, G, B normalised, depth relative to the crop's reference
//!    depth), the target heatmap (`target_shape` little-endian f32) and the box's own mask in the
//!    crop (`mask_shape` bytes, 1 on the box). A request that cannot be answered (an index out of
//!    range, a frame that fails to read) gets `{"request": n, "error": "…"}` and no payload; a
//!    line that is not a request ends the server with an error.

use std::io::{BufRead, Write};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::LearnError;
use crate::data::{self, Sample};
use crate::keypoint::KeypointTask;

/// The protocol's name and version, the first line's `protocol`.
pub const PROTOCOL: &str = "boxpose-samples/1";

/// The server's first line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hello {
    pub protocol: String,
    /// Training items (each counted as often as the config's `repeat` lists it) and held-out ones.
    pub train: usize,
    pub held_out: usize,
    /// `[4, S, S]`: R, G, B, depth at the network's input size S.
    pub input_shape: [usize; 3],
    /// `[depth bins, H, W]` of the target heatmap.
    pub target_shape: [usize; 3],
    /// `[S, S]`.
    pub mask_shape: [usize; 2],
}

/// Which items a request reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    HeldOut,
}

/// One request line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Request {
    pub request: u64,
    pub split: Split,
    pub index: usize,
    /// The augmentation's random stream (training items only); none: not augmented.
    #[serde(default)]
    pub seed: Option<u64>,
}

/// What an answer says of its item beside the arrays.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Answer {
    pub request: u64,
    pub scene_id: i64,
    pub frame_id: i32,
    pub object_id: i32,
    /// The box's x, y, z extents (metres).
    pub box_size_m: [f64; 3],
    /// fx, fy, cx, cy of the camera (pixels; an in-plane turn keeps them).
    pub intrinsics: [f64; 4],
    /// The crop: x0, y0 and side of the square window in the (turned) image, pixel i spanning
    /// [i, i + 1]: input pixel (r, c) sees the image at (x0 + (c + ½)·side/S − ½,
    /// y0 + (r + ½)·side/S − ½) in the intrinsics' pixel coordinates.
    pub crop: [f64; 3],
    /// The in-plane turn of the camera the crop was read through (radians; 0 without one).
    pub turn_rad: f64,
    /// The depth the input's depth channel is relative to, and the heatmap's depth axis centres
    /// on (metres).
    pub reference_depth_m: f64,
    /// The 8 true corners in the (turned) camera's frame, in the dataset's corner order: the
    /// target heatmap's Gaussian centres.
    pub corners_camera_m: [[f64; 3]; 8],
    /// Each corner's visibility code in the frame (0 visible, 1 occluded by another box,
    /// 2 self-occluded, 3 outside the image: the `instances` table's).
    pub corner_visibility: [u8; 8],
    /// Byte lengths of the payloads, in order: input, target, mask.
    pub payload_bytes: [usize; 3],
}

/// The first line of `task`'s server.
pub fn hello(task: &KeypointTask) -> Hello {
    let network = &task.config.network;
    let (s, n) = (network.input_size, network.heatmap_size());
    Hello {
        protocol: PROTOCOL.to_string(),
        train: task.set.train.len(),
        held_out: task.set.val.len(),
        input_shape: [4, s, s],
        target_shape: [network.depth_bins, n, n],
        mask_shape: [s, s],
    }
}

/// Serves `task`'s examples: the hello line, then an answer to each request read from `input`
/// until it ends.
pub fn serve(
    task: &KeypointTask,
    input: &mut impl BufRead,
    output: &mut impl Write,
) -> Result<(), LearnError> {
    // the stream's own errors stay I/O errors: a reader that goes away (a broken pipe) is how a
    // client ends the exchange, which the binary tells from a failure
    let io = |e: std::io::Error| LearnError::Io(PROTOCOL.into(), e);
    writeln!(output, "{}", json_line(&hello(task))?).map_err(io)?;
    output.flush().map_err(io)?;
    let mut line = String::new();
    loop {
        line.clear();
        if input.read_line(&mut line).map_err(io)? == 0 {
            return Ok(());
        }
        if line.trim().is_empty() {
            continue;
        }
        let request: Request = serde_json::from_str(&line).map_err(|e| {
            LearnError::Data(format!("{PROTOCOL}: not a request ({e}): {}", line.trim()))
        })?;
        match answer(task, &request) {
            Ok((answer, payloads)) => {
                writeln!(output, "{}", json_line(&answer)?).map_err(io)?;
                for payload in payloads {
                    output.write_all(&payload).map_err(io)?;
                }
            }
            Err(e) => {
                let error = serde_json::json!({"request": request.request, "error": e.to_string()});
                writeln!(output, "{error}").map_err(io)?;
            }
        }
        output.flush().map_err(io)?;
    }
}

fn json_line(value: &impl Serialize) -> Result<String, LearnError> {
    serde_json::to_string(value).map_err(|e| LearnError::Data(format!("{PROTOCOL}: {e}")))
}

/// The answer to one request and its three payloads.
pub fn answer(
    task: &KeypointTask,
    request: &Request,
) -> Result<(Answer, [Vec<u8>; 3]), LearnError> {
    let (items, split) = match request.split {
        Split::Train => (&task.set.train, "training"),
        Split::HeldOut => (&task.set.val, "held-out"),
    };
    if request.index >= items.len() {
        return Err(LearnError::Data(format!(
            "index {} is past the {} {split} items",
            request.index,
            items.len()
        )));
    }
    let pick = items[request.index];
    let (sample, frame) = match (request.split, request.seed) {
        (Split::Train, Some(seed)) => {
            task.training_sample(request.index, &mut ChaCha8Rng::seed_from_u64(seed))?
        }
        _ => task.plain_sample(pick)?,
    };
    let instance = task.set.instance(pick);
    let mask = data::crop_mask(&task.config.network, &frame, &sample, instance.mask_label());
    let k = &frame.intrinsics;
    let Sample {
        input,
        target,
        grid,
        window,
        corners_camera,
        ..
    } = &sample;
    let answer = Answer {
        request: request.request,
        scene_id: instance.scene_id,
        frame_id: instance.frame_id,
        object_id: instance.object_id,
        box_size_m: instance.size,
        intrinsics: [k.fx, k.fy, k.cx, k.cy],
        crop: [window.x0, window.y0, window.side],
        turn_rad: sample.turn_rad(),
        reference_depth_m: grid.depth.z_ref,
        corners_camera_m: *corners_camera,
        corner_visibility: instance.visibility.map(|v| v as u8),
        payload_bytes: [input.len() * 4, target.len() * 4, mask.len()],
    };
    let bytes = |values: &[f32]| values.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok((answer, [bytes(input), bytes(target), mask]))
}
