//! A frame from image files: an 8-bit RGB PNG and a 16-bit depth PNG in units of `depth_scale`
//! millimetres (BOP's convention; `write_bop` writes 0.1), as `boxpose predict --rgb --depth`
//! reads them.

use std::path::Path;

use boxpose_data::{Frame, Intrinsics};

use crate::error::{FormatError, Result, io};

fn read_png(path: &Path) -> Result<(png::OutputInfo, Vec<u8>)> {
    let invalid = |what: String| FormatError::Invalid(format!("{}: {what}", path.display()));
    let file = std::fs::File::open(path).map_err(io(path))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| invalid(format!("not a PNG ({e})")))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| invalid("image too large".into()))?;
    let mut buffer = vec![0; size];
    let info = reader
        .next_frame(&mut buffer)
        .map_err(|e| invalid(format!("corrupt PNG ({e})")))?;
    buffer.truncate(info.buffer_size());
    Ok((info, buffer))
}

/// The frame (scene_id −1, no ground truth) of `rgb` and `depth` taken with `intrinsics`; depth
/// 0 is no measurement. An error names the file that is not what it must be.
pub fn read_rgbd(
    rgb: &Path,
    depth: &Path,
    intrinsics: Intrinsics,
    depth_scale: f64,
) -> Result<Frame> {
    let (info, rgb_bytes) = read_png(rgb)?;
    if !(info.color_type == png::ColorType::Rgb && info.bit_depth == png::BitDepth::Eight) {
        return Err(FormatError::Invalid(format!(
            "{}: expected an 8-bit RGB PNG, found {:?} at {:?} bits",
            rgb.display(),
            info.color_type,
            info.bit_depth
        )));
    }
    let (dinfo, depth_bytes) = read_png(depth)?;
    if !(dinfo.color_type == png::ColorType::Grayscale && dinfo.bit_depth == png::BitDepth::Sixteen)
    {
        return Err(FormatError::Invalid(format!(
            "{}: expected a 16-bit greyscale PNG of depths (units of --depth-scale millimetres)",
            depth.display()
        )));
    }
    if (dinfo.width, dinfo.height) != (info.width, info.height) {
        return Err(FormatError::Invalid(format!(
            "{} is {}×{} but {} is {}×{}",
            depth.display(),
            dinfo.width,
            dinfo.height,
            rgb.display(),
            info.width,
            info.height
        )));
    }
    let depth_m = depth_bytes
        .chunks(2)
        .map(|b| (f64::from(u16::from_be_bytes([b[0], b[1]])) * depth_scale / 1000.0) as f32)
        .collect();
    let size = (info.width as usize, info.height as usize);
    Ok(Frame::from_images(
        -1, size, intrinsics, rgb_bytes, depth_m, None,
    ))
}
