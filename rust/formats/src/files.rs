//! The files an export writes: PNG images (8-bit RGB and masks, 16-bit depth) and JSON.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use boxpose_data::Frame;
use serde_json::Value;

use crate::error::{FormatError, Result, io};

fn write_png(
    path: &Path,
    data: &[u8],
    frame: &Frame,
    color: png::ColorType,
    depth: png::BitDepth,
) -> Result<()> {
    let png_error = |source| FormatError::Png {
        path: path.to_path_buf(),
        source,
    };
    let file = fs::File::create(path).map_err(io(path))?;
    let mut encoder = png::Encoder::new(
        std::io::BufWriter::new(file),
        frame.width as u32,
        frame.height as u32,
    );
    encoder.set_color(color);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header().map_err(png_error)?;
    writer.write_image_data(data).map_err(png_error)?;
    writer.finish().map_err(png_error)
}

pub(crate) fn write_rgb(path: &Path, frame: &Frame) -> Result<()> {
    write_png(
        path,
        &frame.rgb,
        frame,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
    )
}

/// A frame-sized mask as an 8-bit PNG, 255 where set.
pub(crate) fn write_mask(
    path: &Path,
    mask: impl Iterator<Item = bool>,
    frame: &Frame,
) -> Result<()> {
    let data: Vec<u8> = mask.map(|m| if m { 255 } else { 0 }).collect();
    write_png(
        path,
        &data,
        frame,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
    )
}

/// Writes the depth as uint16 PNG (value × depth_scale = mm) with the finest of 0.1, 1 and 10 mm
/// steps that holds the frame's farthest depth; returns that depth_scale.
pub(crate) fn write_depth(path: &Path, frame: &Frame) -> Result<f64> {
    let max_mm = frame.depth.iter().fold(0.0f64, |m, &d| m.max(d as f64)) * 1000.0;
    let scale = [0.1, 1.0, 10.0]
        .into_iter()
        .find(|s| (max_mm / s).round() <= u16::MAX as f64)
        .ok_or_else(|| {
            FormatError::Invalid(format!(
                "scene {} frame {}: depth {max_mm} mm is too far for a uint16 PNG",
                frame.scene_id, frame.frame_id
            ))
        })?;
    let mut data = Vec::with_capacity(frame.depth.len() * 2);
    for &d in &frame.depth {
        let v = (d as f64 * 1000.0 / scale).round() as u16;
        data.extend_from_slice(&v.to_be_bytes());
    }
    write_png(
        path,
        &data,
        frame,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
    )?;
    Ok(scale)
}

pub(crate) fn write_text(path: &Path, text: &str) -> Result<()> {
    fs::write(path, text).map_err(io(path))
}

pub(crate) fn create_dir(path: &Path) -> Result<()> {
    fs::create_dir_all(path).map_err(io(path))
}

/// A JSON object keyed by integers written in numeric order, one entry a line (BOP's layout).
pub(crate) fn write_keyed(path: &Path, entries: &BTreeMap<i64, Value>) -> Result<()> {
    let body: Vec<String> = entries
        .iter()
        .map(|(k, v)| format!("  \"{k}\": {v}"))
        .collect();
    let text = if body.is_empty() {
        "{}\n".to_string()
    } else {
        format!("{{\n{}\n}}\n", body.join(",\n"))
    };
    write_text(path, &text)
}

pub(crate) fn write_json(path: &Path, value: &Value) -> Result<()> {
    write_text(path, &format!("{value:#}\n"))
}
