//! Crop re-render from Rust: a 128 × 128 region of a 640 × 480 clutter frame, rendered through
//! the embedded Blender with the scene kept loaded (the search loop's case, also after a box
//! moved) versus rebuilt before every render.
//!
//!     cargo bench -p boxpose-render --bench crop_rerender -- [--samples 16] [--repeats 5] [--boxes 12] [--denoise]
//!
//! Prints one line per case: `crop <size> <case>: mean … s, min … s, max … s, CPU … s (n renders)`.

use std::time::Instant;

use arrow_pyarrow::FromPyArrow;
use boxpose_data::Pose;
use boxpose_data::arrow::array::AsArray;
use boxpose_data::arrow::datatypes::Float64Type;
use boxpose_data::arrow::record_batch::RecordBatch;
use boxpose_render::{RenderRequest, Renderer};
use pyo3::prelude::*;

struct Options {
    samples: i32,
    repeats: usize,
    boxes: usize,
    denoise: bool,
    size: u32,
}

fn options() -> Options {
    let mut o = Options {
        samples: 16,
        repeats: 5,
        boxes: 12,
        denoise: false,
        size: 128,
    };
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    while i < args.len() {
        let value = || args.get(i + 1).expect("flag needs a value").clone();
        match args[i].as_str() {
            "--samples" => o.samples = value().parse().expect("--samples N"),
            "--repeats" => o.repeats = value().parse().expect("--repeats N"),
            "--boxes" => o.boxes = value().parse().expect("--boxes N"),
            "--size" => o.size = value().parse().expect("--size N"),
            "--denoise" => {
                o.denoise = true;
                i += 1;
                continue;
            }
            _ => {
                i += 1; // cargo bench passes --bench; ignore unknown flags
                continue;
            }
        }
        i += 2;
    }
    o
}

/// The benchmark scene: the clutter recipe's 640 × 480 camera over synthetic boxes in its bin
/// (blender_scripts.synthetic, same rows as scripts/bench_render.py).
fn scene(boxes: usize) -> (RecordBatch, RecordBatch) {
    Python::attach(|py| {
        let code = format!(
            r#"
import boxpose_io
from blender_scripts.bench import bench_scene
scene, objects = bench_scene({boxes})
result = (boxpose_io.table_from_rows("scenes", [scene]).to_batches()[0], boxpose_io.table_from_rows("objects", objects).to_batches()[0])
"#
        );
        let code = std::ffi::CString::new(code).unwrap();
        let globals = pyo3::types::PyDict::new(py);
        py.run(&code, Some(&globals), None)
            .expect("bench scene rows");
        let result = globals.get_item("result").unwrap().unwrap();
        (
            RecordBatch::from_pyarrow_bound(&result.get_item(0).unwrap()).unwrap(),
            RecordBatch::from_pyarrow_bound(&result.get_item(1).unwrap()).unwrap(),
        )
    })
}

/// CPU seconds of this process so far (all threads): /proc/self/stat utime + stime.
fn cpu_seconds() -> f64 {
    unsafe extern "C" {
        fn sysconf(name: std::ffi::c_int) -> std::ffi::c_long;
    }
    const SC_CLK_TCK: std::ffi::c_int = 2;
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks: f64 = fields
        .get(11..13)
        .map(|f| f.iter().filter_map(|v| v.parse::<f64>().ok()).sum())
        .unwrap_or(0.0);
    ticks / unsafe { sysconf(SC_CLK_TCK) } as f64
}

/// Runs `f` `n` times; prints mean / min / max wall seconds and mean CPU seconds.
fn measure(name: &str, n: usize, mut f: impl FnMut(usize)) {
    let (mut times, cpu0) = (Vec::new(), cpu_seconds());
    for k in 0..n {
        let t = Instant::now();
        f(k);
        times.push(t.elapsed().as_secs_f64());
    }
    let cpu = (cpu_seconds() - cpu0) / n as f64;
    let mean = times.iter().sum::<f64>() / n as f64;
    let min = times.iter().cloned().fold(f64::INFINITY, f64::min);
    let max = times.iter().cloned().fold(0.0, f64::max);
    println!(
        "{name}: mean {mean:.3} s, min {min:.3} s, max {max:.3} s, CPU {cpu:.3} s ({n} renders)"
    );
}

fn main() {
    let o = options();
    let t = Instant::now();
    let mut renderer = Renderer::new(0).expect("start the embedded Blender");
    println!(
        "embedded Blender started in {:.2} s",
        t.elapsed().as_secs_f64()
    );
    let (scenes, objects) = scene(o.boxes);
    let (x0, y0) = ((640 - o.size) / 2, (480 - o.size) / 2);
    let request = RenderRequest {
        frame_id: 0,
        samples: Some(o.samples),
        denoise: Some(o.denoise),
        crop: Some([x0, y0, x0 + o.size, y0 + o.size]),
        ..Default::default()
    };
    let label = format!(
        "crop {0}x{0} at {1} samples{2}",
        o.size,
        o.samples,
        if o.denoise { " + denoise" } else { "" }
    );

    let t = Instant::now();
    renderer.load_scene(&scenes, &objects, 0).expect("load");
    println!(
        "scene with {} boxes built in {:.2} s",
        o.boxes,
        t.elapsed().as_secs_f64()
    );
    renderer.render(&request).expect("warm-up render"); // Cycles device init, first BVH build

    measure(&format!("{label}, scene reused"), o.repeats, |_| {
        renderer.render(&request).expect("render");
    });

    // The search loop: move a box, re-render the crop (persistent Cycles data, pose update only).
    let l = objects
        .column_by_name("world_box_translation_m")
        .unwrap()
        .as_list::<i32>();
    let q = objects
        .column_by_name("world_box_quat_wxyz")
        .unwrap()
        .as_list::<i32>();
    let (t0, q0) = (l.value(0), q.value(0));
    let (t0, q0) = (
        t0.as_primitive::<Float64Type>().values(),
        q0.as_primitive::<Float64Type>().values(),
    );
    measure(
        &format!("{label}, scene reused, one box moved"),
        o.repeats,
        |k| {
            let pose = Pose {
                quat_wxyz: [q0[0], q0[1], q0[2], q0[3]],
                translation: [t0[0] + 0.002 * (k + 1) as f64, t0[1], t0[2]],
            };
            renderer
                .render(&RenderRequest {
                    poses: vec![(0, pose)],
                    ..request.clone()
                })
                .expect("render");
        },
    );
    measure(&format!("{label}, scene rebuilt"), o.repeats, |_| {
        renderer.load_scene(&scenes, &objects, 0).expect("load");
        renderer.render(&request).expect("render");
    });
}
