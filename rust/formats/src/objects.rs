//! BOP object ids, one per distinct box size, and the box models BOP reads: a PLY in millimetres
//! and `models_info.json`'s extent and discrete symmetries.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use boxpose_data::{Dataset, Instance};
use serde_json::{Value, json};

use crate::error::{FormatError, Result};

/// A box size in units of 0.1 mm: two boxes whose sizes round to the same key share an obj_id.
pub type SizeKey = [i64; 3];

pub fn size_key(size_m: [f64; 3]) -> SizeKey {
    size_m.map(|s| (s * 1e4).round() as i64)
}

/// The size in millimetres.
pub fn key_mm(key: SizeKey) -> [f64; 3] {
    key.map(|k| k as f64 / 10.0)
}

/// obj_id (1-based) of every distinct box size of the dataset's `objects`, in increasing
/// (dx, dy, dz) order: the same dataset always gets the same ids, in `export bop` and in the
/// results scorer alike.
pub fn object_ids(dataset: &Dataset) -> Result<BTreeMap<SizeKey, u32>> {
    let mut keys: Vec<SizeKey> = dataset
        .objects()?
        .iter()
        .map(|o| size_key(o.size))
        .collect();
    keys.sort();
    keys.dedup();
    Ok(keys.into_iter().zip(1..).collect())
}

/// The obj_id of an instance's box size; an error naming the instance when no `objects` row has it.
pub fn obj_id(ids: &BTreeMap<SizeKey, u32>, instance: &Instance) -> Result<u32> {
    ids.get(&size_key(instance.size)).copied().ok_or_else(|| {
        FormatError::Invalid(format!(
            "scene {} frame {} object {}: size {:?} m is in no `objects` row",
            instance.scene_id, instance.frame_id, instance.object_id, instance.size
        ))
    })
}

/// The proper rotations mapping an axis-aligned box of this size onto itself, identity excluded
/// (BOP's `symmetries_discrete` leaves it out): the geometry crate's symmetry group of the box,
/// whose sides here are compared as size keys. 3 for three distinct sides, 7 with two equal, 23
/// for a cube.
pub fn box_symmetries(key: SizeKey) -> Result<Vec<[[f64; 3]; 3]>> {
    let model = boxpose_geometry::BoxModel::new(nalgebra::Vector3::from(key_mm(key))).map_err(
        |source| FormatError::Geometry {
            context: format!("a box of {:?} mm", key_mm(key)),
            source,
        },
    )?;
    Ok(model
        .symmetries()
        .into_iter()
        .skip(1) // the identity comes first
        .map(|s| std::array::from_fn(|row| std::array::from_fn(|col| s.rotation[(row, col)])))
        .collect())
}

/// ASCII PLY of a box centred at the origin, in mm: 24 vertices (4 per face, with the face's
/// outward normal) and 12 counter-clockwise triangles.
pub fn box_ply(size_mm: [f64; 3]) -> String {
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
        writeln!(ply, "{} {} {} {} {} {}", p[0], p[1], p[2], n[0], n[1], n[2])
            .expect("writing to a String");
    }
    for f in &faces {
        writeln!(ply, "3 {} {} {}", f[0], f[1], f[2]).expect("writing to a String");
    }
    ply
}

/// A box's `models_info.json` entry: diameter, extent and `symmetries_discrete` as row-major
/// 4 × 4 transforms, in mm.
pub fn model_info(key: SizeKey) -> Result<Value> {
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
}
