//! An external system under test (`boxpose search --sut`): a long-lived process that perceives
//! each rendered sample, speaking protocol `boxpose-sut/1` on its stdin and stdout. The search
//! samples, settles, renders and scores as it does for its own pipeline; only "find the target
//! box and its pose" is the process's (docs/search.md, "Your own system under test").
//!
//! One exchange per sample:
//! 1. When it starts, the process writes one line: `{"protocol": "boxpose-sut/1", "name": "…"}`.
//! 2. boxpose writes a request: one JSON line ([`RequestHeader`]), then its payloads, raw, in
//!    this order: RGB (height × width × 3 bytes, sRGB, row-major), depth (height × width
//!    little-endian f32, metres along the optical axis, 0 where no surface) and, with a crop,
//!    the target's visible mask (height × width bytes, 1 where the target is seen).
//! 3. The process answers one JSON line ([`AnswerLine`]): `{"request": n, "found": true,
//!    "rotation": [[…], […], […]], "translation_m": […]}` (the box's frame in the camera's, OpenCV
//!    axes; optionally `size_m` when it fits the size too, `confidence`, `peaks_camera_m`),
//!    `{"request": n, "found": false}` (no box), or `{"request": n, "error": "…"}` (it could not
//!    fit one).
//!
//! Anything else — a line that does not parse, another request's answer, an exit, no answer within
//! the timeout — is the process's own error: the sample is not scored (its invalid reason starts
//! "system under test"), the process is stopped and started again for the next sample.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use boxpose_data::{Frame, Instance, Intrinsics};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SearchError};

/// The protocol's name and version, the first line's `protocol`.
pub const PROTOCOL: &str = "boxpose-sut/1";

/// How far a returned rotation may be from orthonormal (‖RᵀR − I‖∞) before it is refused.
const ROTATION_TOLERANCE: f64 = 1e-6;

/// The JSON line that starts a request; the payloads follow it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RequestHeader {
    /// Counts from 0 in each process; the answer repeats it.
    pub request: u64,
    pub scene_id: i64,
    pub width: usize,
    pub height: usize,
    /// fx, fy, cx, cy in pixels, the top-left pixel's centre at (0, 0) (the dataset's).
    pub intrinsics: [f64; 4],
    pub target_object_id: i32,
    /// The target's true size (metres, its x, y, z extents), for systems that fit a box of known
    /// size; a system that estimates the size answers `size_m`.
    pub box_size_m: [f64; 3],
    /// With ground-truth crops: the target's visible bounding box (x_min, y_min, x_max, y_max,
    /// max exclusive), and its mask follows. None (`--crops predicted`): find the box yourself.
    pub crop: Option<[i32; 4]>,
    /// Byte lengths of the payloads, in order.
    pub rgb_bytes: usize,
    pub depth_bytes: usize,
    pub mask_bytes: usize,
}

/// The answer line, as written by the process.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnswerLine {
    pub request: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub found: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<[[f64; 3]; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_m: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_m: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confidence: Option<f64>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub peaks_camera_m: Vec<[f64; 3]>,
}

/// What the system made of the target, checked.
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    Found {
        /// The box's frame in the camera's.
        pose: Isometry3<f64>,
        /// The size it fitted, when it fits one (else the true size is the estimate's).
        size_m: Option<[f64; 3]>,
        confidence: Option<f64>,
        peaks: Vec<[f64; 3]>,
    },
    NotFound,
    FitFailed(String),
}

impl AnswerLine {
    /// The answer, or why the line breaks the protocol.
    pub fn check(self, request: u64) -> std::result::Result<Answer, String> {
        if self.request != request {
            return Err(format!(
                "answered request {} while request {request} was asked",
                self.request
            ));
        }
        if let Some(error) = self.error {
            return Ok(Answer::FitFailed(error));
        }
        match self.found {
            None => Err("the answer has neither \"found\" nor \"error\"".into()),
            Some(false) => Ok(Answer::NotFound),
            Some(true) => {
                let (Some(rotation), Some(translation)) = (self.rotation, self.translation_m)
                else {
                    return Err("\"found\": true needs \"rotation\" and \"translation_m\"".into());
                };
                let all_finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
                let r = Matrix3::from_fn(|i, j| rotation[i][j]);
                let off = (r.transpose() * r - Matrix3::identity()).amax();
                if !all_finite(r.as_slice()) || off > ROTATION_TOLERANCE || r.determinant() <= 0.0 {
                    return Err(format!(
                        "\"rotation\" {rotation:?} is not a rotation (RᵀR − I is {off:.1e} away, \
                         det {:.3})",
                        r.determinant()
                    ));
                }
                if !all_finite(&translation) {
                    return Err(format!("\"translation_m\" {translation:?} is not finite"));
                }
                if let Some(size) = self.size_m
                    && !size.iter().all(|s| s.is_finite() && *s > 0.0)
                {
                    return Err(format!("\"size_m\" {size:?} must be finite and positive"));
                }
                if let Some(c) = self.confidence
                    && !c.is_finite()
                {
                    return Err(format!("\"confidence\" {c} is not finite"));
                }
                if !self.peaks_camera_m.iter().all(|p| all_finite(p)) {
                    return Err("\"peaks_camera_m\" holds a value that is not finite".into());
                }
                let rotation =
                    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
                Ok(Answer::Found {
                    pose: Isometry3::from_parts(
                        Translation3::from(Vector3::from(translation)),
                        rotation,
                    ),
                    size_m: self.size_m,
                    confidence: self.confidence,
                    peaks: self.peaks_camera_m,
                })
            }
        }
    }

    /// The line an answer is written as (the serving side, [`serve`]).
    pub fn of(request: u64, answer: &Answer) -> Self {
        match answer {
            Answer::NotFound => Self {
                request,
                found: Some(false),
                ..Self::default()
            },
            Answer::FitFailed(error) => Self {
                request,
                error: Some(error.clone()),
                ..Self::default()
            },
            Answer::Found {
                pose,
                size_m,
                confidence,
                peaks,
            } => {
                let r = pose.rotation.to_rotation_matrix().into_inner();
                Self {
                    request,
                    found: Some(true),
                    rotation: Some(std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)]))),
                    translation_m: Some(pose.translation.vector.into()),
                    size_m: *size_m,
                    confidence: *confidence,
                    peaks_camera_m: peaks.clone(),
                    ..Self::default()
                }
            }
        }
    }
}

/// How `--sut` names the process: `exec:COMMAND` (a shell command line) or
/// `python:MODULE:CALLABLE` (a Python callable served by `python3 -m boxpose_io.sut`).
pub fn command_of(spec: &str) -> std::result::Result<String, String> {
    if let Some(command) = spec.strip_prefix("exec:") {
        if command.trim().is_empty() {
            return Err("--sut exec: needs a command after the colon".into());
        }
        return Ok(command.to_string());
    }
    if let Some(target) = spec.strip_prefix("python:") {
        let valid = target.split_once(':').is_some_and(|(module, callable)| {
            let name = |s: &str| {
                !s.is_empty()
                    && s.split('.').all(|part| {
                        part.chars()
                            .next()
                            .is_some_and(|c| c.is_alphabetic() || c == '_')
                            && part.chars().all(|c| c.is_alphanumeric() || c == '_')
                    })
            };
            name(module) && name(callable)
        });
        if !valid {
            return Err(format!(
                "--sut python:{target}: give python:MODULE:CALLABLE, e.g. python:examples.sut.pca_baseline:perceive"
            ));
        }
        return Ok(format!("python3 -m boxpose_io.sut {target}"));
    }
    Err(format!(
        "--sut {spec}: use exec:COMMAND (a process speaking {PROTOCOL}) or python:MODULE:CALLABLE"
    ))
}

/// A running system: its process, a thread that writes requests into its stdin (so that a
/// process which stops reading cannot block the search past the timeout) and one that reads its
/// stdout's lines.
struct Process {
    child: Child,
    requests: Option<mpsc::Sender<Vec<u8>>>,
    lines: mpsc::Receiver<std::io::Result<String>>,
}

impl Process {
    fn start(command: &str, timeout: Duration) -> std::result::Result<(Self, String), String> {
        let mut child = {
            let mut command_line = Command::new("sh");
            command_line
                .arg("-c")
                .arg(command)
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit());
            // its own process group, so that stopping it stops what the shell started too
            std::os::unix::process::CommandExt::process_group(&mut command_line, 0);
            command_line
                .spawn()
                .map_err(|e| format!("could not start `{command}`: {e}"))?
        };
        let stdin: ChildStdin = child.stdin.take().expect("stdin is piped");
        let stdout = child.stdout.take().expect("stdout is piped");
        let (request_tx, request_rx) = mpsc::channel::<Vec<u8>>();
        std::thread::spawn(move || {
            let mut stdin = stdin;
            for bytes in request_rx {
                if stdin
                    .write_all(&bytes)
                    .and_then(|()| stdin.flush())
                    .is_err()
                {
                    break;
                }
            }
        });
        let (line_tx, line_rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                if line_tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut process = Self {
            child,
            requests: Some(request_tx),
            lines: line_rx,
        };
        let hello = process
            .next_line(timeout)
            .map_err(|e| format!("`{command}` did not introduce itself: {e}"))?;
        #[derive(Deserialize)]
        struct Hello {
            protocol: String,
            #[serde(default)]
            name: String,
        }
        let hello: Hello = serde_json::from_str(&hello).map_err(|e| {
            format!("`{command}`'s first line is not {{\"protocol\": \"{PROTOCOL}\", …}}: {e}: {hello:.200}")
        })?;
        if hello.protocol != PROTOCOL {
            return Err(format!(
                "`{command}` speaks {}, boxpose speaks {PROTOCOL}",
                hello.protocol
            ));
        }
        Ok((process, hello.name))
    }

    fn next_line(&mut self, timeout: Duration) -> std::result::Result<String, String> {
        match self.lines.recv_timeout(timeout) {
            Ok(Ok(line)) => Ok(line),
            Ok(Err(e)) => Err(format!("reading its output: {e}")),
            Err(mpsc::RecvTimeoutError::Timeout) => {
                Err(format!("no answer within {:.0} s", timeout.as_secs_f64()))
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                // its output ends a moment before its exit can be seen: wait a second for it
                for _ in 0..20 {
                    if let Ok(Some(status)) = self.child.try_wait() {
                        return Err(format!("it exited ({status})"));
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err("it closed its output".into())
            }
        }
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        // closing stdin asks a well-behaved system to finish; the group is stopped either way
        self.requests.take();
        let group = format!("-{}", self.child.id());
        let _ = Command::new("kill")
            .args(["-KILL", "--", &group])
            .stderr(Stdio::null())
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The client side: starts the process, sends each sample, checks each answer, and starts the
/// process again after an error.
pub struct ExternalSut {
    command: String,
    timeout: Duration,
    process: Option<Process>,
    next_request: u64,
    /// The name the process gave.
    pub name: String,
    /// Times the process was started again after an error.
    pub restarts: usize,
}

impl ExternalSut {
    /// Starts `spec` (see [`command_of`]) and checks its first line, so that a system that cannot
    /// start is refused before any sample.
    pub fn start(spec: &str, timeout: Duration) -> Result<Self> {
        let command = command_of(spec).map_err(SearchError::Sample)?;
        let (process, name) = Process::start(&command, timeout)
            .map_err(|e| SearchError::Sample(format!("--sut {spec}: {e}")))?;
        Ok(Self {
            command,
            timeout,
            process: Some(process),
            next_request: 0,
            name,
            restarts: 0,
        })
    }

    /// Asks the system about `target` in `frame`; with `crop`, the target's visible box and mask
    /// go with it. Err: the system broke the protocol, crashed or timed out (it is restarted for
    /// the next call).
    pub fn perceive(
        &mut self,
        scene_id: i64,
        frame: &Frame,
        target: &Instance,
        crop: Option<[i32; 4]>,
    ) -> std::result::Result<Answer, String> {
        let result = self.exchange(scene_id, frame, target, crop);
        if result.is_err() {
            self.process = None; // stopped (Drop); the next call starts it again
        }
        result
    }

    fn exchange(
        &mut self,
        scene_id: i64,
        frame: &Frame,
        target: &Instance,
        crop: Option<[i32; 4]>,
    ) -> std::result::Result<Answer, String> {
        if self.process.is_none() {
            let (process, _) = Process::start(&self.command, self.timeout)?;
            self.process = Some(process);
            self.next_request = 0;
            self.restarts += 1;
        }
        let process = self.process.as_mut().expect("started above");
        let request = self.next_request;
        self.next_request += 1;
        let label = target.mask_label();
        let mask: Vec<u8> = match crop {
            Some(_) => frame
                .instance_mask
                .iter()
                .map(|&m| u8::from(m == label))
                .collect(),
            None => Vec::new(),
        };
        let Intrinsics { fx, fy, cx, cy } = frame.intrinsics;
        let header = RequestHeader {
            request,
            scene_id,
            width: frame.width,
            height: frame.height,
            intrinsics: [fx, fy, cx, cy],
            target_object_id: target.object_id,
            box_size_m: target.size,
            crop,
            rgb_bytes: frame.rgb.len(),
            depth_bytes: 4 * frame.depth.len(),
            mask_bytes: mask.len(),
        };
        let mut bytes = serde_json::to_vec(&header).expect("a header serialises");
        bytes.push(b'\n');
        bytes.reserve(header.rgb_bytes + header.depth_bytes + header.mask_bytes);
        bytes.extend_from_slice(&frame.rgb);
        bytes.extend(frame.depth.iter().flat_map(|d| d.to_le_bytes()));
        bytes.extend_from_slice(&mask);
        let sent = process
            .requests
            .as_ref()
            .is_some_and(|requests| requests.send(bytes).is_ok());
        if !sent {
            return Err("its input is closed".into());
        }
        let line = process.next_line(self.timeout)?;
        let answer: AnswerLine = serde_json::from_str(&line)
            .map_err(|e| format!("answer to request {request} is not valid: {e}: {line:.200}"))?;
        answer.check(request)
    }
}

/// One request as the serving side reads it: the frame rebuilt (images, intrinsics; the target's
/// mask as its `instance_mask` label when a crop came) and the header.
pub struct Request {
    pub header: RequestHeader,
    pub frame: Frame,
}

/// Reads one request; None at the end of the input.
pub fn read_request(input: &mut impl BufRead) -> Result<Option<Request>> {
    let bad = |problem: String| SearchError::Sample(format!("{PROTOCOL} request: {problem}"));
    let mut line = String::new();
    if input.read_line(&mut line).map_err(|e| bad(e.to_string()))? == 0 {
        return Ok(None);
    }
    let header: RequestHeader =
        serde_json::from_str(line.trim_end()).map_err(|e| bad(format!("{e}: {line:.200}")))?;
    let pixels = header.width * header.height;
    let expected_mask = if header.crop.is_some() { pixels } else { 0 };
    if header.rgb_bytes != 3 * pixels
        || header.depth_bytes != 4 * pixels
        || header.mask_bytes != expected_mask
    {
        return Err(bad(format!(
            "payload sizes {} / {} / {} do not match a {}×{} frame",
            header.rgb_bytes, header.depth_bytes, header.mask_bytes, header.width, header.height
        )));
    }
    let mut read = |n: usize| -> Result<Vec<u8>> {
        let mut bytes = vec![0; n];
        input
            .read_exact(&mut bytes)
            .map_err(|e| bad(format!("payload: {e}")))?;
        Ok(bytes)
    };
    let rgb = read(header.rgb_bytes)?;
    let depth = read(header.depth_bytes)?
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let label = (header.target_object_id + 1) as u16;
    let instance_mask = match header.crop {
        Some(_) => Some(
            read(header.mask_bytes)?
                .into_iter()
                .map(|m| if m != 0 { label } else { 0 })
                .collect(),
        ),
        None => None,
    };
    let [fx, fy, cx, cy] = header.intrinsics;
    let frame = Frame::from_images(
        header.scene_id,
        (header.width, header.height),
        Intrinsics { fx, fy, cx, cy },
        rgb,
        depth,
        instance_mask,
    );
    Ok(Some(Request { header, frame }))
}

/// The serving side of the protocol over `input` / `output` (a process's stdin and stdout):
/// introduces itself as `name`, then answers each request with `perceive` until the input ends.
pub fn serve(
    name: &str,
    mut input: impl BufRead,
    mut output: impl Write,
    mut perceive: impl FnMut(&Request) -> Result<Answer>,
) -> Result<()> {
    let io = |e: std::io::Error| SearchError::Sample(format!("{PROTOCOL}: writing: {e}"));
    let hello = serde_json::json!({"protocol": PROTOCOL, "name": name});
    writeln!(output, "{hello}").map_err(io)?;
    output.flush().map_err(io)?;
    while let Some(request) = read_request(&mut input)? {
        let answer = perceive(&request)?;
        let line = AnswerLine::of(request.header.request, &answer);
        let text = serde_json::to_string(&line).expect("an answer serialises");
        writeln!(output, "{text}").map_err(io)?;
        output.flush().map_err(io)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use boxpose_data::Pose;

    #[test]
    fn an_answer_reads_back_as_written() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 1.3),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        let answer = Answer::Found {
            pose,
            size_m: Some([0.1, 0.2, 0.3]),
            confidence: Some(0.7),
            peaks: vec![[0.0, 0.1, 1.0]],
        };
        let text = serde_json::to_string(&AnswerLine::of(4, &answer)).unwrap();
        let Answer::Found { pose: back, .. } = serde_json::from_str::<AnswerLine>(&text)
            .unwrap()
            .check(4)
            .unwrap()
        else {
            panic!("not found")
        };
        assert!((back.rotation.angle_to(&pose.rotation)) < 1e-12);
        assert_eq!(back.translation, pose.translation);
        for answer in [Answer::NotFound, Answer::FitFailed("too few peaks".into())] {
            let text = serde_json::to_string(&AnswerLine::of(0, &answer)).unwrap();
            assert_eq!(
                serde_json::from_str::<AnswerLine>(&text)
                    .unwrap()
                    .check(0)
                    .unwrap(),
                answer
            );
        }
    }

    #[test]
    fn answers_that_break_the_protocol_say_how() {
        let found = |rotation: [[f64; 3]; 3]| AnswerLine {
            request: 0,
            found: Some(true),
            rotation: Some(rotation),
            translation_m: Some([0.0, 0.0, 1.0]),
            ..AnswerLine::default()
        };
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mirror = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]];
        let scaled = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(found(identity).check(0).is_ok());
        assert!(found(identity).check(1).unwrap_err().contains("request 0"));
        assert!(
            found(mirror)
                .check(0)
                .unwrap_err()
                .contains("not a rotation")
        );
        assert!(
            found(scaled)
                .check(0)
                .unwrap_err()
                .contains("not a rotation")
        );
        let no_pose = AnswerLine {
            found: Some(true),
            ..AnswerLine::default()
        };
        assert!(no_pose.check(0).unwrap_err().contains("rotation"));
        assert!(
            AnswerLine::default()
                .check(0)
                .unwrap_err()
                .contains("neither")
        );
        let bad_size = AnswerLine {
            size_m: Some([0.1, -0.1, 0.1]),
            ..found(identity)
        };
        assert!(bad_size.check(0).unwrap_err().contains("size_m"));
        assert!(
            serde_json::from_str::<AnswerLine>(r#"{"request": 0, "found": true, "pose": 1}"#)
                .is_err()
        );
    }

    #[test]
    fn a_sut_is_named_by_exec_or_python() {
        assert_eq!(
            command_of("exec:./my-sut --fast").unwrap(),
            "./my-sut --fast"
        );
        assert_eq!(
            command_of("python:examples.sut.pca_baseline:perceive").unwrap(),
            "python3 -m boxpose_io.sut examples.sut.pca_baseline:perceive"
        );
        for bad in [
            "exec:",
            "python:mod",
            "python:mod:",
            "python:a b:c",
            "./my-sut",
        ] {
            assert!(command_of(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_system_that_exits_or_stays_silent_is_an_error_and_is_restarted() {
        let echo_hello = format!(r#"echo '{{"protocol": "{PROTOCOL}", "name": "quits"}}'"#);
        let mut sut =
            ExternalSut::start(&format!("exec:{echo_hello}"), Duration::from_secs(5)).unwrap();
        assert_eq!(sut.name, "quits");
        let frame = tiny_frame();
        let target = frame.instances[0].clone();
        let error = sut.perceive(0, &frame, &target, None).unwrap_err();
        assert!(
            error.contains("exited") || error.contains("closed"),
            "{error}"
        );
        // started again for the next call, which fails the same way
        assert!(sut.perceive(1, &frame, &target, None).is_err());
        assert_eq!(sut.restarts, 1);

        let silent = format!("exec:{echo_hello}; sleep 30");
        let mut sut = ExternalSut::start(&silent, Duration::from_millis(300)).unwrap();
        let error = sut.perceive(0, &frame, &target, None).unwrap_err();
        assert!(error.contains("no answer within"), "{error}");

        let wrong = ExternalSut::start(
            "exec:echo '{\"protocol\": \"other/2\"}'",
            Duration::from_secs(5),
        );
        assert!(wrong.err().unwrap().to_string().contains("speaks other/2"));
    }

    /// A 4×3 frame with one box: what a request is made of.
    fn tiny_frame() -> Frame {
        let (width, height) = (4, 3);
        let instance = Instance {
            scene_id: 0,
            frame_id: 0,
            object_id: 0,
            size: [0.1, 0.2, 0.3],
            camera_box: Pose {
                quat_wxyz: [1.0, 0.0, 0.0, 0.0],
                translation: [0.0, 0.0, 1.0],
            },
            corners_camera: [[0.0; 3]; 8],
            corners_px: [[0.0; 2]; 8],
            visibility: [boxpose_data::Visibility::Visible; 8],
            label_keypoints_camera: None,
            label_keypoints_px: None,
            visible_bbox: Some([1, 1, 3, 2]),
            visible_pixels: 2,
            visible_fraction: 1.0,
        };
        let mut frame = Frame::from_images(
            0,
            (width, height),
            Intrinsics {
                fx: 10.0,
                fy: 10.0,
                cx: 2.0,
                cy: 1.5,
            },
            (0..width * height * 3).map(|i| i as u8).collect(),
            vec![1.0; width * height],
            Some(vec![0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0]),
        );
        frame.instances.push(instance);
        frame
    }

    #[test]
    fn a_request_reads_back_on_the_serving_side() {
        // the client's bytes through `serve`, which answers from what it read
        let frame = tiny_frame();
        let target = &frame.instances[0];
        let mut sut_input = Vec::new();
        let header = RequestHeader {
            request: 0,
            scene_id: 7,
            width: frame.width,
            height: frame.height,
            intrinsics: [10.0, 10.0, 2.0, 1.5],
            target_object_id: 0,
            box_size_m: target.size,
            crop: target.visible_bbox,
            rgb_bytes: frame.rgb.len(),
            depth_bytes: 4 * frame.depth.len(),
            mask_bytes: frame.instance_mask.len(),
        };
        sut_input.extend(serde_json::to_vec(&header).unwrap());
        sut_input.push(b'\n');
        sut_input.extend(&frame.rgb);
        sut_input.extend(frame.depth.iter().flat_map(|d| d.to_le_bytes()));
        sut_input.extend(frame.instance_mask.iter().map(|&m| m as u8));
        let mut output = Vec::new();
        serve("test", &sut_input[..], &mut output, |request| {
            assert_eq!(request.header, header);
            assert_eq!(request.frame.rgb, frame.rgb);
            assert_eq!(request.frame.depth, frame.depth);
            assert_eq!(request.frame.instance_mask, frame.instance_mask);
            Ok(Answer::NotFound)
        })
        .unwrap();
        let text = String::from_utf8(output).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].contains(PROTOCOL));
        assert_eq!(lines[1], r#"{"request":0,"found":false}"#);
    }
}
