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

/// BOP's `depth_scale` (millimetres per unit) of a depth PNG that sits in a BOP scene folder,
/// `SCENE/depth/NNNNNN.png`: the entry of image NNNNNN in `SCENE/scene_camera.json` (the
/// scale varies per image). `None` when the file is not in such a folder; an error when the
/// folder's `scene_camera.json` has no usable entry for it.
pub fn bop_depth_scale(depth_png: &Path) -> Result<Option<f64>> {
    let image_id = depth_png
        .file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| s.parse::<u64>().ok());
    let folder = depth_png.parent();
    let (Some(image_id), Some(folder)) = (image_id, folder) else {
        return Ok(None);
    };
    if folder.file_name().and_then(|n| n.to_str()) != Some("depth") {
        return Ok(None);
    }
    let Some(cameras) = folder.parent().map(|scene| scene.join("scene_camera.json")) else {
        return Ok(None);
    };
    if !cameras.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&cameras).map_err(io(&cameras))?;
    let json: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| FormatError::Invalid(format!("{}: not JSON ({e})", cameras.display())))?;
    json.get(image_id.to_string())
        .and_then(|entry| entry.get("depth_scale"))
        .and_then(|v| v.as_f64())
        .filter(|s| s.is_finite() && *s > 0.0)
        .map(Some)
        .ok_or_else(|| {
            FormatError::Invalid(format!(
                "{}: no positive depth_scale for image {image_id} (the depth PNG {})",
                cameras.display(),
                depth_png.display()
            ))
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_depth_png_in_a_bop_scene_takes_its_image_s_depth_scale() {
        let root = std::env::temp_dir().join(format!("boxpose-depth-scale-{}", std::process::id()));
        let depth = root.join("000003").join("depth");
        std::fs::create_dir_all(&depth).unwrap();
        let cameras = root.join("000003").join("scene_camera.json");
        std::fs::write(
            &cameras,
            r#"{"7": {"depth_scale": 0.1}, "8": {"depth_scale": 1.0}, "9": {}}"#,
        )
        .unwrap();
        assert_eq!(
            bop_depth_scale(&depth.join("000007.png")).unwrap(),
            Some(0.1)
        );
        assert_eq!(
            bop_depth_scale(&depth.join("000008.png")).unwrap(),
            Some(1.0)
        );
        // an image the scene does not describe is an error naming the file, not a guess
        let missing = bop_depth_scale(&depth.join("000009.png"))
            .unwrap_err()
            .to_string();
        assert!(
            missing.contains("scene_camera.json") && missing.contains("image 9"),
            "{missing}"
        );
        // outside a BOP scene's depth/ folder: no scale from the folder
        assert_eq!(bop_depth_scale(&root.join("000007.png")).unwrap(), None);
        assert_eq!(bop_depth_scale(&depth.join("frame.png")).unwrap(), None);
        std::fs::remove_dir_all(&root).unwrap();
    }
}
