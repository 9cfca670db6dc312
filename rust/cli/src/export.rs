//! `boxpose export bop|coco`: a dataset in the BOP scene-wise format that bop_toolkit reads, or
//! as COCO instances (RLE masks, optionally the 8 corners as keypoints) for segmentation and
//! keypoint tooling. See docs/export.md.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, ensure};
use boxpose_data::schema::FRAMES;
use boxpose_data::{Dataset, Frame, Instance, Intrinsics, Pose, Visibility};
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::{Value, json};

/// Command-line options of `boxpose export`.
#[derive(clap::Args)]
#[command(
    about = "Export a dataset to the BOP scene-wise format (bop_toolkit) or to COCO instances",
    long_about = "Export a dataset to the BOP scene-wise format (bop_toolkit) or to COCO instances.\n\n\
        `bop` writes one folder per scene (rgb/, depth/ as uint16 PNG with a depth_scale, mask/ and \
        mask_visib/, scene_camera.json, scene_gt.json, scene_gt_info.json), the box models (models/, \
        models_eval/: one PLY per distinct box size, in mm, with models_info.json and the box's discrete \
        symmetries), camera.json, test_targets_bop19.json and dataset_info.md. Poses and models are in \
        millimetres, as BOP expects.\n\n\
        `coco` writes annotations.json (one `box` category; per visible box a COCO RLE of its visible mask, \
        bbox, area, and the amodal silhouette as amodal_segmentation/amodal_bbox) and the images as PNG \
        files under images/; with --keypoints also the box's 8 corners as COCO keypoints (visibility \
        0/1/2) and the category's corner names and 12-edge skeleton.\n\n\
        Visible masks come from the exact instance mask; amodal masks (BOP mask/, COCO amodal_*) are the \
        box's projected silhouette (its convex hull clipped to the near plane), the same silhouette the \
        dataset's visible_fraction is measured against. The output folder is written under OUT.partial \
        and renamed to OUT when complete; OUT must not exist or be empty.",
    after_help = "Examples:\n  \
        boxpose export bop datasets/generated/demo build/bop/boxpose_demo\n  \
        boxpose export bop datasets/generated/demo build/bop/boxpose_demo --split val --min-visib-fract 0.2\n  \
        boxpose export coco datasets/generated/demo build/coco/demo\n  \
        boxpose export coco datasets/generated/demo build/coco/demo_keypoints --keypoints\n\n\
        See docs/export.md for every file, field and unit."
)]
pub struct Args {
    #[command(subcommand)]
    pub format: Format,
}

#[derive(clap::Subcommand)]
pub enum Format {
    /// BOP scene-wise format: OUT/SPLIT/{scene_id:06d}/…, OUT/models/, OUT/models_eval/, camera.json,
    /// test_targets_bop19.json, dataset_info.md (millimetres; depth as uint16 × depth_scale = mm).
    Bop(BopArgs),
    /// COCO instances: OUT/annotations.json (RLE visible and amodal masks, bbox, area) and OUT/images/*.png.
    Coco(CocoArgs),
}

#[derive(clap::Args)]
pub struct BopArgs {
    /// Dataset folder (scenes/, objects/, frames/, instances/).
    pub dataset: PathBuf,
    /// Output folder (the BOP dataset root); must not exist or be empty.
    pub out: PathBuf,
    /// Split folder the scenes go to (BOP: test, val or train, optionally with a _TYPE suffix).
    #[arg(long, default_value = "test", value_name = "NAME")]
    pub split: String,
    /// Smallest visib_fract of an instance listed in test_targets_bop19.json (BOP'19 uses 0.1).
    #[arg(long, default_value_t = 0.1, value_name = "F")]
    pub min_visib_fract: f64,
}

#[derive(clap::Args)]
pub struct CocoArgs {
    /// Dataset folder (scenes/, objects/, frames/, instances/).
    pub dataset: PathBuf,
    /// Output folder (annotations.json and images/); must not exist or be empty.
    pub out: PathBuf,
    /// Also write the box's 8 corners per annotation as COCO `keypoints` (visibility 2 visible,
    /// 1 occluded or self-occluded, 0 outside the image) with `num_keypoints`, and the corner
    /// names and the 12-edge `skeleton` in the category.
    #[arg(long)]
    pub keypoints: bool,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.format {
        Format::Bop(a) => {
            Dataset::open(&a.dataset)?;
            with_partial(&a.out, |tmp| bop(a, tmp))
        }
        Format::Coco(a) => {
            Dataset::open(&a.dataset)?;
            with_partial(&a.out, |tmp| coco(a, tmp))
        }
    }
}

/// Writes into `OUT.partial` (cleared first) and renames it to `OUT` once `write` succeeded;
/// removes it when `write` fails.
fn with_partial(out: &Path, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    if out.exists() {
        let empty = out.is_dir() && fs::read_dir(out)?.next().is_none();
        ensure!(
            empty,
            "{} exists and is not an empty folder: choose a new output folder",
            out.display()
        );
        fs::remove_dir(out)?;
    }
    let name = out
        .file_name()
        .with_context(|| format!("{} has no folder name", out.display()))?;
    let tmp = out.with_file_name(format!("{}.partial", name.to_string_lossy()));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).with_context(|| format!("cannot clear {}", tmp.display()))?;
    }
    fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    if let Err(e) = write(&tmp) {
        let _ = fs::remove_dir_all(&tmp);
        return Err(e);
    }
    fs::rename(&tmp, out)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), out.display()))?;
    println!("wrote {}", out.display());
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Object ids: one per distinct box size

/// A box size in units of 0.1 mm: two boxes whose sizes round to the same key share an obj_id.
type SizeKey = [i64; 3];

fn size_key(size_m: [f64; 3]) -> SizeKey {
    size_m.map(|s| (s * 1e4).round() as i64)
}

fn key_mm(key: SizeKey) -> [f64; 3] {
    key.map(|k| k as f64 / 10.0)
}

/// obj_id (1-based) of every distinct box size of the dataset's `objects`, in increasing
/// (dx, dy, dz) order: the same dataset always gets the same ids.
pub(crate) fn object_ids(dataset: &Dataset) -> anyhow::Result<BTreeMap<SizeKey, u32>> {
    let mut keys: Vec<SizeKey> = dataset
        .objects()?
        .iter()
        .map(|o| size_key(o.size))
        .collect();
    keys.sort();
    keys.dedup();
    Ok(keys.into_iter().zip(1..).collect())
}

pub(crate) fn obj_id(ids: &BTreeMap<SizeKey, u32>, instance: &Instance) -> anyhow::Result<u32> {
    ids.get(&size_key(instance.size)).copied().with_context(|| {
        format!(
            "scene {} frame {} object {}: size {:?} m is in no `objects` row",
            instance.scene_id, instance.frame_id, instance.object_id, instance.size
        )
    })
}

/// The proper rotations mapping an axis-aligned box of this size onto itself, identity excluded
/// (BOP's `symmetries_discrete` leaves it out): the geometry crate's symmetry group of the box,
/// whose sides here are compared as size keys. 3 for three distinct sides, 7 with two equal, 23
/// for a cube.
fn box_symmetries(key: SizeKey) -> anyhow::Result<Vec<[[f64; 3]; 3]>> {
    let model = boxpose_geometry::BoxModel::new(nalgebra::Vector3::from(key_mm(key)))
        .with_context(|| format!("a box of {:?} mm", key_mm(key)))?;
    Ok(model
        .symmetries()
        .into_iter()
        .skip(1) // the identity comes first
        .map(|s| std::array::from_fn(|row| std::array::from_fn(|col| s.rotation[(row, col)])))
        .collect())
}

/// ASCII PLY of a box centred at the origin, in mm: 24 vertices (4 per face, with the face's
/// outward normal) and 12 counter-clockwise triangles.
fn box_ply(size_mm: [f64; 3]) -> String {
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for a in 0..3 {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        for s in [-1.0, 1.0] {
            let base = vertices.len();
            let mut quad = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
            if s < 0.0 {
                quad.reverse();
            }
            for (sb, sc) in quad {
                let mut p = [0.0; 3];
                let mut n = [0.0; 3];
                p[a] = s * size_mm[a] / 2.0;
                p[b] = sb * size_mm[b] / 2.0;
                p[c] = sc * size_mm[c] / 2.0;
                n[a] = s;
                vertices.push((p, n));
            }
            faces.push([base, base + 1, base + 2]);
            faces.push([base, base + 2, base + 3]);
        }
    }
    let mut ply = format!(
        "ply\nformat ascii 1.0\ncomment boxpose box model, size {} x {} x {} mm\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        size_mm[0],
        size_mm[1],
        size_mm[2],
        vertices.len(),
        faces.len()
    );
    for (p, n) in &vertices {
        writeln!(ply, "{} {} {} {} {} {}", p[0], p[1], p[2], n[0], n[1], n[2]).unwrap();
    }
    for f in &faces {
        writeln!(ply, "3 {} {} {}", f[0], f[1], f[2]).unwrap();
    }
    ply
}

fn model_info(key: SizeKey) -> anyhow::Result<Value> {
    let s = key_mm(key);
    let symmetries: Vec<Vec<f64>> = box_symmetries(key)?
        .iter()
        .map(|r| {
            let mut m = Vec::with_capacity(16);
            for row in r {
                m.extend_from_slice(row);
                m.push(0.0);
            }
            m.extend_from_slice(&[0.0, 0.0, 0.0, 1.0]);
            m
        })
        .collect();
    Ok(json!({
        "diameter": (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt(),
        "min_x": -s[0] / 2.0, "min_y": -s[1] / 2.0, "min_z": -s[2] / 2.0,
        "size_x": s[0], "size_y": s[1], "size_z": s[2],
        "symmetries_discrete": symmetries,
    }))
}

// ---------------------------------------------------------------------------------------------
// Geometry: rotations, box edges and the amodal silhouette

fn rotation(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn flat(r: &[[f64; 3]; 3]) -> Vec<f64> {
    r.iter().flatten().copied().collect()
}

fn mm(t: [f64; 3]) -> Vec<f64> {
    t.iter().map(|v| v * 1000.0).collect()
}

/// R_w2c and t_w2c (metres) of the camera pose T_world_camera.
fn world_to_camera(world_camera: &Pose) -> ([[f64; 3]; 3], [f64; 3]) {
    let r = rotation(world_camera.quat_wxyz);
    let rt: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| r[j][i]));
    let t = world_camera.translation;
    let t_w2c = std::array::from_fn(|i| -(rt[i][0] * t[0] + rt[i][1] * t[1] + rt[i][2] * t[2]));
    (rt, t_w2c)
}

/// The box's 12 edges as pairs of corner indices (i, j), i < j, in increasing (i, axis) order: the
/// corners of an edge differ in the sign along one axis, i.e. in one bit of the corner index
/// (docs/dataset.md: bit 0 is x, bit 1 y, bit 2 z).
fn box_edges() -> impl Iterator<Item = (usize, usize)> {
    (0..8usize).flat_map(|i| {
        (0..3)
            .filter(move |bit| i >> bit & 1 == 0)
            .map(move |bit| (i, i | 1 << bit))
    })
}

/// Near plane of the silhouette, as in blender_scripts.geometry.silhouette_mask.
const NEAR_M: f64 = 1e-3;

/// Counter-clockwise convex hull (pixels) of the box's corners clipped to z >= NEAR_M and
/// projected: blender_scripts.geometry's clip_box_to_near_plane + convex_hull_2d, step for step,
/// so the pixel counts agree with the ones visible_fraction was computed from.
fn silhouette_hull(k: &Intrinsics, corners: &[[f64; 3]; 8]) -> Vec<[f64; 2]> {
    let mut verts: Vec<[f64; 3]> = corners.iter().filter(|p| p[2] >= NEAR_M).copied().collect();
    for (i, j) in box_edges() {
        let (a, b) = (corners[i], corners[j]);
        if (a[2] - NEAR_M) * (b[2] - NEAR_M) < 0.0 {
            let s = (NEAR_M - a[2]) / (b[2] - a[2]);
            verts.push(std::array::from_fn(|d| a[d] + s * (b[d] - a[d])));
        }
    }
    if verts.len() < 3 {
        return Vec::new();
    }
    let round = |v: f64| (v * 1e12).round_ties_even() / 1e12;
    let mut pts: Vec<[f64; 2]> = verts
        .iter()
        .map(|p| {
            let z = if p[2].abs() < 1e-12 { 1e-12 } else { p[2] };
            [round(k.fx * p[0] / z + k.cx), round(k.fy * p[1] / z + k.cy)]
        })
        .collect();
    pts.sort_by(|a, b| a.partial_cmp(b).expect("finite pixel coordinates"));
    pts.dedup();
    if pts.len() <= 2 {
        return Vec::new();
    }
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut lower: Vec<[f64; 2]> = Vec::new();
    for &p in &pts {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<[f64; 2]> = Vec::new();
    for &p in pts.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    if lower.len() < 3 { Vec::new() } else { lower }
}

/// The amodal silhouette of one box in one frame: pixels whose centres fall in the hull.
struct Silhouette {
    /// height × width, in-image pixels.
    mask: Vec<bool>,
    /// Pixels in the image.
    count: u64,
    /// [x, y, w, h] of the silhouette over an image three times as large (the image in its
    /// centre), as bop_toolkit's calc_gt_info renders it: may extend past the image; [-1; 4] when empty.
    bbox: [i64; 4],
}

fn silhouette(frame: &Frame, instance: &Instance) -> Silhouette {
    let (w, h) = (frame.width as i64, frame.height as i64);
    let mut out = Silhouette {
        mask: vec![false; frame.width * frame.height],
        count: 0,
        bbox: [-1; 4],
    };
    let hull = silhouette_hull(&frame.intrinsics, &instance.corners_camera);
    if hull.is_empty() {
        return out;
    }
    let (min_u, max_u) = hull
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p[0]), b.max(p[0]))
        });
    let (min_v, max_v) = hull
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p[1]), b.max(p[1]))
        });
    let clamp = |v: f64, lo: i64, hi: i64| (v.clamp(lo as f64, hi as f64)) as i64;
    let (x0, x1) = (
        clamp(min_u.floor(), -w, 2 * w),
        clamp(max_u.ceil() + 1.0, -w, 2 * w),
    );
    let (y0, y1) = (
        clamp(min_v.floor(), -h, 2 * h),
        clamp(max_v.ceil() + 1.0, -h, 2 * h),
    );
    let (mut bx0, mut by0, mut bx1, mut by1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for y in y0..y1 {
        for x in x0..x1 {
            let (u, v) = (x as f64, y as f64);
            let inside = (0..hull.len()).all(|k| {
                let (a, b) = (hull[k], hull[(k + 1) % hull.len()]);
                (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0]) >= 0.0
            });
            if !inside {
                continue;
            }
            (bx0, by0, bx1, by1) = (bx0.min(x), by0.min(y), bx1.max(x), by1.max(y));
            if (0..w).contains(&x) && (0..h).contains(&y) {
                out.mask[(y * w + x) as usize] = true;
                out.count += 1;
            }
        }
    }
    if bx0 <= bx1 {
        out.bbox = [bx0, by0, bx1 - bx0 + 1, by1 - by0 + 1];
    }
    out
}

/// [x, y, w, h] of a visible_bbox (x_min, y_min, x_max, y_max; max exclusive), or [-1; 4].
fn xywh(bbox: Option<[i32; 4]>) -> [i64; 4] {
    bbox.map_or([-1; 4], |b| {
        [
            b[0] as i64,
            b[1] as i64,
            (b[2] - b[0]) as i64,
            (b[3] - b[1]) as i64,
        ]
    })
}

/// [x, y, w, h] of the set pixels of a row-major mask, or [-1; 4] when none is set.
fn mask_bbox(mask: &[bool], width: usize) -> [i64; 4] {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (i % width, i / width);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 == usize::MAX {
        [-1; 4]
    } else {
        [
            x0 as i64,
            y0 as i64,
            (x1 - x0 + 1) as i64,
            (y1 - y0 + 1) as i64,
        ]
    }
}

// ---------------------------------------------------------------------------------------------
// Files

fn write_png(
    path: &Path,
    data: &[u8],
    width: usize,
    height: usize,
    color: png::ColorType,
    depth: png::BitDepth,
) -> anyhow::Result<()> {
    let file =
        fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    encoder.set_color(color);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header()?;
    writer
        .write_image_data(data)
        .with_context(|| format!("cannot write {}", path.display()))?;
    writer.finish()?;
    Ok(())
}

fn write_rgb(path: &Path, frame: &Frame) -> anyhow::Result<()> {
    write_png(
        path,
        &frame.rgb,
        frame.width,
        frame.height,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
    )
}

fn write_mask(path: &Path, mask: impl Iterator<Item = bool>, frame: &Frame) -> anyhow::Result<()> {
    let data: Vec<u8> = mask.map(|m| if m { 255 } else { 0 }).collect();
    write_png(
        path,
        &data,
        frame.width,
        frame.height,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
    )
}

/// Writes the depth as uint16 PNG (value × depth_scale = mm) with the finest of 0.1, 1 and 10 mm
/// steps that holds the frame's farthest depth; returns that depth_scale.
fn write_depth(path: &Path, frame: &Frame) -> anyhow::Result<f64> {
    let max_mm = frame.depth.iter().fold(0.0f64, |m, &d| m.max(d as f64)) * 1000.0;
    let scale = [0.1, 1.0, 10.0]
        .into_iter()
        .find(|s| (max_mm / s).round() <= u16::MAX as f64)
        .with_context(|| {
            format!(
                "scene {} frame {}: depth {max_mm} mm is too far for a uint16 PNG",
                frame.scene_id, frame.frame_id
            )
        })?;
    let mut data = Vec::with_capacity(frame.depth.len() * 2);
    for &d in &frame.depth {
        let v = (d as f64 * 1000.0 / scale).round() as u16;
        data.extend_from_slice(&v.to_be_bytes());
    }
    write_png(
        path,
        &data,
        frame.width,
        frame.height,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
    )?;
    Ok(scale)
}

/// A JSON object keyed by integers written in numeric order, one entry a line (BOP's layout).
fn write_keyed(path: &Path, entries: &BTreeMap<i64, Value>) -> anyhow::Result<()> {
    let body: Vec<String> = entries
        .iter()
        .map(|(k, v)| Ok(format!("  \"{k}\": {}", serde_json::to_string(v)?)))
        .collect::<anyhow::Result<_>>()?;
    let text = if body.is_empty() {
        "{}\n".to_string()
    } else {
        format!("{{\n{}\n}}\n", body.join(",\n"))
    };
    fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// The dataset's folder name, as an export records its source: not the absolute path, which
/// would leak the exporting machine's layout into a shared dataset.
fn dataset_name(dataset: &Path) -> String {
    fs::canonicalize(dataset)
        .unwrap_or_else(|_| dataset.to_path_buf())
        .file_name()
        .map_or_else(
            || dataset.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
}

fn write_json(path: &Path, value: &Value) -> anyhow::Result<()> {
    fs::write(path, serde_json::to_string_pretty(value)? + "\n")
        .with_context(|| format!("cannot write {}", path.display()))
}

fn progress(dataset: &Dataset, what: &str) -> anyhow::Result<ProgressBar> {
    let frames = dataset.count(&FRAMES)?;
    Ok(
        ProgressBar::new(frames as u64).with_style(ProgressStyle::with_template(&format!(
            "{what} {{bar:30}} {{pos}}/{{len}} frames [{{elapsed_precise}}<{{eta_precise}}]"
        ))?),
    )
}

// ---------------------------------------------------------------------------------------------
// BOP

#[derive(Default)]
struct BopScene {
    camera: BTreeMap<i64, Value>,
    gt: BTreeMap<i64, Value>,
    gt_info: BTreeMap<i64, Value>,
}

fn bop(args: &BopArgs, out: &Path) -> anyhow::Result<()> {
    ensure!(
        !args.split.is_empty()
            && !args.split.contains(['/', '\\'])
            && !["models", "models_eval"].contains(&args.split.as_str()),
        "--split {:?} must be a plain folder name other than models",
        args.split
    );
    let dataset = Dataset::open(&args.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let ids = object_ids(&dataset)?;

    for models in ["models", "models_eval"] {
        let dir = out.join(models);
        fs::create_dir_all(&dir)?;
        let mut info = BTreeMap::new();
        for (&key, &id) in &ids {
            fs::write(dir.join(format!("obj_{id:06}.ply")), box_ply(key_mm(key)))?;
            info.insert(id as i64, model_info(key)?);
        }
        write_keyed(&dir.join("models_info.json"), &info)?;
    }

    let bar = progress(&dataset, "bop")?;
    let mut scenes: BTreeMap<i64, BopScene> = BTreeMap::new();
    let mut targets: Vec<Value> = Vec::new();
    let mut camera: Option<Value> = None;
    let (mut images, mut annotations) = (0usize, 0usize);
    for frame in dataset.frames()? {
        let frame = frame?;
        let im_id = frame.frame_id as i64;
        let dir = out.join(&args.split).join(format!("{:06}", frame.scene_id));
        if !dir.exists() {
            for sub in ["rgb", "depth", "mask", "mask_visib"] {
                fs::create_dir_all(dir.join(sub))?;
            }
        }
        write_rgb(&dir.join("rgb").join(format!("{im_id:06}.png")), &frame)?;
        let depth_scale = write_depth(&dir.join("depth").join(format!("{im_id:06}.png")), &frame)?;
        let k = frame.intrinsics;
        let cam_k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0];
        camera.get_or_insert_with(|| {
            json!({"cx": k.cx, "cy": k.cy, "depth_scale": depth_scale, "fx": k.fx, "fy": k.fy,
                   "height": frame.height, "width": frame.width})
        });
        let (r_w2c, t_w2c) = world_to_camera(&frame.world_camera);
        let scene = scenes.entry(frame.scene_id).or_default();
        scene.camera.insert(
            im_id,
            json!({"cam_K": cam_k, "depth_scale": depth_scale, "cam_R_w2c": flat(&r_w2c), "cam_t_w2c": mm(t_w2c)}),
        );

        let (mut gt, mut gt_info) = (Vec::new(), Vec::new());
        let mut inst_count: BTreeMap<u32, usize> = BTreeMap::new();
        for (gt_id, instance) in frame.instances.iter().enumerate() {
            let obj = obj_id(&ids, instance)?;
            gt.push(json!({
                "cam_R_m2c": flat(&rotation(instance.camera_box.quat_wxyz)),
                "cam_t_m2c": mm(instance.camera_box.translation),
                "obj_id": obj,
            }));
            let sil = silhouette(&frame, instance);
            let label = instance.mask_label();
            let own = frame.instance_mask.iter().map(|&m| m == label);
            write_mask(
                &dir.join("mask_visib")
                    .join(format!("{im_id:06}_{gt_id:06}.png")),
                own,
                &frame,
            )?;
            write_mask(
                &dir.join("mask").join(format!("{im_id:06}_{gt_id:06}.png")),
                sil.mask.iter().copied(),
                &frame,
            )?;
            let valid = sil
                .mask
                .iter()
                .zip(&frame.depth)
                .filter(|&(&m, &d)| m && d > 0.0)
                .count();
            let visib = instance.visible_pixels as u64;
            let visib_fract = if sil.count > 0 {
                (visib as f64 / sil.count as f64).min(1.0)
            } else {
                0.0
            };
            gt_info.push(json!({
                "bbox_obj": sil.bbox,
                "bbox_visib": xywh(instance.visible_bbox),
                "px_count_all": sil.count,
                "px_count_valid": valid,
                "px_count_visib": visib,
                "visib_fract": visib_fract,
            }));
            if visib_fract >= args.min_visib_fract {
                *inst_count.entry(obj).or_default() += 1;
            }
            annotations += 1;
        }
        for (obj, count) in inst_count {
            targets.push(json!({"im_id": im_id, "inst_count": count, "obj_id": obj, "scene_id": frame.scene_id}));
        }
        scene.gt.insert(im_id, Value::from(gt));
        scene.gt_info.insert(im_id, Value::from(gt_info));
        images += 1;
        bar.inc(1);
    }
    bar.finish_and_clear();

    for (scene_id, scene) in &scenes {
        let dir = out.join(&args.split).join(format!("{scene_id:06}"));
        write_keyed(&dir.join("scene_camera.json"), &scene.camera)?;
        write_keyed(&dir.join("scene_gt.json"), &scene.gt)?;
        write_keyed(&dir.join("scene_gt_info.json"), &scene.gt_info)?;
    }
    if let Some(camera) = &camera {
        write_json(&out.join("camera.json"), camera)?;
    }
    let targets_text = format!(
        "[\n{}\n]\n",
        targets
            .iter()
            .map(|t| format!("  {t}"))
            .collect::<Vec<_>>()
            .join(",\n")
    );
    fs::write(
        out.join("test_targets_bop19.json"),
        if targets.is_empty() {
            "[]\n".to_string()
        } else {
            targets_text
        },
    )?;

    let source = dataset_name(&args.dataset);
    let objects: BTreeMap<String, Value> = ids
        .iter()
        .map(|(&key, &id)| {
            (
                id.to_string(),
                json!({"size_mm": key_mm(key), "size_m": key.map(|k| k as f64 / 1e4)}),
            )
        })
        .collect();
    write_json(
        &out.join("dataset_info.json"),
        &json!({
            "source": source,
            "split": args.split,
            "scenes": scenes.len(), "images": images, "instances": annotations,
            "min_visib_fract": args.min_visib_fract,
            "objects": objects,
        }),
    )?;
    let mut md = format!(
        "# boxpose dataset in BOP format\n\n\
         Exported by `boxpose export bop` from `{}`: {} scenes, {} images, {} annotated instances in `{}/`.\n\n\
         - Units: millimetres for models and translations; depth PNGs are uint16 with value × depth_scale = mm \
         (depth_scale per image in scene_camera.json: 0.1 unless the frame is deeper than 6.5 m).\n\
         - Every box of every frame is annotated in scene_gt.json, hidden or not; gt_id is the rank of its \
         boxpose object_id in the frame (the object_id itself when the frame lists every box).\n\
         - mask_visib/ is the exact instance mask; mask/ is the projected box silhouette (no occluders).\n\
         - test_targets_bop19.json lists the instances with visib_fract >= {}.\n\n\
         | obj_id | size_x (mm) | size_y (mm) | size_z (mm) | discrete symmetries |\n|---|---|---|---|---|\n",
        source,
        scenes.len(),
        images,
        annotations,
        args.split,
        args.min_visib_fract
    );
    for (&key, &id) in &ids {
        let s = key_mm(key);
        writeln!(
            md,
            "| {id} | {} | {} | {} | {} |",
            s[0],
            s[1],
            s[2],
            box_symmetries(key)?.len()
        )?;
    }
    fs::write(out.join("dataset_info.md"), md)?;
    println!(
        "{} scenes, {images} images, {annotations} instances, {} models",
        scenes.len(),
        ids.len()
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// COCO

/// Uncompressed COCO RLE of a row-major height × width mask: run lengths in column-major
/// (Fortran) order, starting with a (possibly empty) run of zeros.
fn rle(mask: &[bool], width: usize, height: usize) -> Value {
    let mut counts: Vec<u64> = Vec::new();
    let (mut current, mut run) = (false, 0u64);
    for x in 0..width {
        for y in 0..height {
            let m = mask[y * width + x];
            if m != current {
                counts.push(run);
                (current, run) = (m, 0);
            }
            run += 1;
        }
    }
    counts.push(run);
    json!({"size": [height, width], "counts": counts})
}

/// COCO's visibility flag of a corner. COCO labels a hidden joint with its position and v = 1, so
/// corners hidden by another box or by the box's own faces (whose exact positions the dataset
/// has) get 1; a corner outside the image (or behind the camera) has no position in it and is
/// not labelled (0).
fn coco_visibility(visibility: Visibility) -> u8 {
    match visibility {
        Visibility::Visible => 2,
        Visibility::OccludedByOther | Visibility::SelfOccluded => 1,
        Visibility::OutsideImage => 0,
    }
}

/// An instance's corners as COCO `keypoints` [x1, y1, v1, …] in corner order, unlabelled ones as
/// 0, 0, 0 (COCO's convention), and `num_keypoints`, the labelled ones. Pixel coordinates as in
/// the dataset (the top-left pixel's centre at (0, 0)), COCO's keypoint convention too; the
/// flags are integers, as in COCO's own files.
fn coco_keypoints(instance: &Instance) -> (Vec<Value>, usize) {
    let mut keypoints = Vec::with_capacity(3 * 8);
    let mut labelled = 0;
    for (&[x, y], &visibility) in instance.corners_px.iter().zip(&instance.visibility) {
        let v = coco_visibility(visibility);
        if v == 0 {
            keypoints.extend([json!(0), json!(0), json!(0)]);
        } else {
            keypoints.extend([json!(x), json!(y), json!(v)]);
            labelled += 1;
        }
    }
    (keypoints, labelled)
}

/// The `box` category; with keypoints, the corners' names and the box's edges as COCO's 1-based
/// `skeleton`.
fn coco_category(keypoints: bool) -> Value {
    let mut category = json!({"id": 1, "name": "box", "supercategory": "box"});
    if keypoints {
        let names: Vec<String> = (0..8).map(|i| format!("corner_{i}")).collect();
        let skeleton: Vec<[usize; 2]> = box_edges().map(|(i, j)| [i + 1, j + 1]).collect();
        category["keypoints"] = json!(names);
        category["skeleton"] = json!(skeleton);
    }
    category
}

fn coco(args: &CocoArgs, out: &Path) -> anyhow::Result<()> {
    let dataset = Dataset::open(&args.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let ids = object_ids(&dataset)?;
    let images_dir = out.join("images");
    fs::create_dir_all(&images_dir)?;
    let bar = progress(&dataset, "coco")?;
    let (mut images, mut annotations) = (Vec::new(), Vec::new());
    for frame in dataset.frames()? {
        let frame = frame?;
        let image_id = images.len() + 1;
        let file_name = format!("{:06}_{:06}.png", frame.scene_id, frame.frame_id);
        write_rgb(&images_dir.join(&file_name), &frame)?;
        images.push(json!({
            "id": image_id, "file_name": file_name, "width": frame.width, "height": frame.height,
            "scene_id": frame.scene_id, "frame_id": frame.frame_id,
        }));
        for instance in &frame.instances {
            if instance.visible_pixels == 0 {
                continue;
            }
            let label = instance.mask_label();
            let own: Vec<bool> = frame.instance_mask.iter().map(|&m| m == label).collect();
            let sil = silhouette(&frame, instance);
            let bbox = xywh(instance.visible_bbox);
            let amodal_bbox = mask_bbox(&sil.mask, frame.width);
            let mut annotation = json!({
                "id": annotations.len() + 1,
                "image_id": image_id,
                "category_id": 1,
                "segmentation": rle(&own, frame.width, frame.height),
                "area": instance.visible_pixels,
                "bbox": bbox,
                "iscrowd": 0,
                "amodal_segmentation": rle(&sil.mask, frame.width, frame.height),
                "amodal_area": sil.count,
                "amodal_bbox": amodal_bbox,
                "visib_fract": instance.visible_fraction,
                "object_id": instance.object_id,
                "obj_id": obj_id(&ids, instance)?,
            });
            if args.keypoints {
                let (keypoints, num_keypoints) = coco_keypoints(instance);
                annotation["keypoints"] = json!(keypoints);
                annotation["num_keypoints"] = json!(num_keypoints);
            }
            annotations.push(annotation);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let source = dataset_name(&args.dataset);
    let (n_images, n_annotations) = (images.len(), annotations.len());
    write_json(
        &out.join("annotations.json"),
        &json!({
            "info": {
                "description": format!("boxpose dataset {source} (boxpose export coco)"),
                "version": env!("CARGO_PKG_VERSION"),
            },
            "licenses": [],
            "images": images,
            "annotations": annotations,
            "categories": [coco_category(args.keypoints)],
        }),
    )?;
    println!("{n_images} images, {n_annotations} annotations");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetry_group_sizes() {
        assert_eq!(box_symmetries([1, 2, 3]).unwrap().len(), 3);
        assert_eq!(box_symmetries([2, 2, 3]).unwrap().len(), 7);
        assert_eq!(box_symmetries([2, 3, 2]).unwrap().len(), 7);
        assert_eq!(box_symmetries([4, 4, 4]).unwrap().len(), 23);
        for r in box_symmetries([4, 4, 4]).unwrap() {
            let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
                - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
                + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
            assert_eq!(det, 1.0);
        }
    }

    #[test]
    fn rle_is_column_major() {
        // 2 × 3 mask, row-major [0 1 1; 0 0 1]; column by column 0 0 | 1 0 | 1 1:
        // runs of 2 zeros, 1 one, 1 zero, 2 ones
        let mask = [false, true, true, false, false, true];
        assert_eq!(rle(&mask, 3, 2)["counts"], json!([2, 1, 1, 2]));
        assert_eq!(rle(&[true; 4], 2, 2)["counts"], json!([0, 4]));
    }

    #[test]
    fn box_edges_join_corners_one_sign_apart() {
        let edges: Vec<(usize, usize)> = box_edges().collect();
        assert_eq!(edges.len(), 12);
        for &(i, j) in &edges {
            assert!(i < j && j < 8 && (i ^ j).count_ones() == 1, "{i}-{j}");
        }
        let unique: std::collections::BTreeSet<_> = edges.iter().collect();
        assert_eq!(unique.len(), 12);
        // every corner meets three edges
        for corner in 0..8 {
            let degree = edges.iter().filter(|&&(i, j)| i == corner || j == corner);
            assert_eq!(degree.count(), 3);
        }
    }

    #[test]
    fn coco_visibility_flags_and_keypoint_category() {
        assert_eq!(coco_visibility(Visibility::Visible), 2);
        assert_eq!(coco_visibility(Visibility::OccludedByOther), 1);
        assert_eq!(coco_visibility(Visibility::SelfOccluded), 1);
        assert_eq!(coco_visibility(Visibility::OutsideImage), 0);
        let category = coco_category(true);
        assert_eq!(category["keypoints"][7], json!("corner_7"));
        assert_eq!(category["skeleton"][0], json!([1, 2]));
        assert_eq!(
            coco_category(false),
            json!({"id": 1, "name": "box", "supercategory": "box"})
        );
    }

    #[test]
    fn hull_of_a_box_in_front_is_convex_and_ccw() {
        let k = Intrinsics {
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 50.0,
        };
        let corners: [[f64; 3]; 8] = std::array::from_fn(|i| {
            let s = |b: usize| if i >> b & 1 == 1 { 0.1 } else { -0.1 };
            [s(0), s(1), 1.0 + s(2)]
        });
        let hull = silhouette_hull(&k, &corners);
        assert_eq!(hull.len(), 4);
        let near = 50.0 - 100.0 * 0.1 / 0.9;
        assert!(
            (hull[0][0] - near).abs() < 1e-9 && (hull[0][1] - near).abs() < 1e-9,
            "{hull:?}"
        );
    }
}
