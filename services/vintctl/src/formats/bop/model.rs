//! The object models' `models_info.json` entries: extents and diameter measured on the model PLY
//! itself (millimetres, read with `eval::ply`, the one PLY reader), so they describe exactly the file
//! the export ships.

use anyhow::{anyhow, bail};

use super::frames::Vec3;

/// BOP's per-model geometry: the axis-aligned box (`min_*`, `size_*`) and the diameter — the
/// largest distance between two vertices — all in the model's units (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelGeometry {
    pub min: Vec3,
    pub size: Vec3,
    pub diameter: f64,
}

impl ModelGeometry {
    pub fn of(vertices: &[Vec3]) -> anyhow::Result<ModelGeometry> {
        let first = *vertices.first().ok_or_else(|| anyhow!("the model has no vertices"))?;
        let (mut lo, mut hi) = (first, first);
        for v in vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        Ok(ModelGeometry { min: lo, size: [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]], diameter: diameter(vertices) })
    }
}

/// The model PLY as vint writes it (binary little-endian, the `vertex` element first with float32
/// `x y z` alone) with every vertex moved by `d` (mm): the same triangles in another frame. Any
/// other layout is refused rather than guessed at.
pub fn moved_ply(bytes: &[u8], d: Vec3) -> anyhow::Result<Vec<u8>> {
    const END: &[u8] = b"end_header\n";
    let end =
        bytes.windows(END.len()).position(|w| w == END).ok_or_else(|| anyhow!("PLY has no end_header"))? + END.len();
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| anyhow!("PLY header is not text"))?;
    let lines: Vec<&str> =
        header.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("comment")).collect();
    let count = match lines.as_slice() {
        [
            "ply",
            "format binary_little_endian 1.0",
            vertex,
            "property float x",
            "property float y",
            "property float z",
            rest @ ..,
        ] if rest.first().is_none_or(|l| l.starts_with("element ")) => {
            vertex.strip_prefix("element vertex ").and_then(|n| n.parse::<usize>().ok())
        }
        _ => None,
    };
    let Some(count) = count else {
        bail!("the model PLY is not vint's layout (binary little-endian, vertex element of float x y z first)");
    };
    let mut out = bytes.to_vec();
    let body = out.get_mut(end..end + count * 12).ok_or_else(|| anyhow!("PLY vertex data ends early"))?;
    for vertex in body.chunks_exact_mut(12) {
        for (k, value) in vertex.chunks_exact_mut(4).enumerate() {
            let v = f32::from_le_bytes([value[0], value[1], value[2], value[3]]);
            value.copy_from_slice(&((f64::from(v) + d[k]) as f32).to_le_bytes());
        }
    }
    Ok(out)
}

/// The exact largest vertex distance. Pairs are visited farthest-from-the-centroid first and the
/// search stops once no remaining pair can beat the best (|a − b| ≤ |a − c| + |b − c|), which
/// prunes almost all of the n² pairs of a convex-ish model without approximating.
pub fn diameter(vertices: &[Vec3]) -> f64 {
    let n = vertices.len().max(1) as f64;
    let c = [0, 1, 2].map(|k| vertices.iter().map(|v| v[k]).sum::<f64>() / n);
    let mut by_radius: Vec<(f64, Vec3)> = vertices.iter().map(|v| (distance(v, &c), *v)).collect();
    by_radius.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best = 0.0f64;
    for (i, (ri, a)) in by_radius.iter().enumerate() {
        if 2.0 * ri <= best {
            break;
        }
        for (rj, b) in &by_radius[i + 1..] {
            if ri + rj <= best {
                break;
            }
            best = best.max(distance(a, b));
        }
    }
    best
}

fn distance(a: &Vec3, b: &Vec3) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every pair, the definition itself.
    fn brute_force(vertices: &[Vec3]) -> f64 {
        let mut best = 0.0f64;
        for a in vertices {
            for b in vertices {
                best = best.max(distance(a, b));
            }
        }
        best
    }

    #[test]
    fn a_box_has_its_space_diagonal_as_diameter_and_its_edges_as_size() {
        let corners: Vec<Vec3> = (0..8)
            .map(|i| {
                [
                    if i & 1 == 0 { -30.0 } else { 30.0 },
                    if i & 2 == 0 { -79.0 } else { 79.0 },
                    if i & 4 == 0 { -105.0 } else { 105.0 },
                ]
            })
            .collect();
        let g = ModelGeometry::of(&corners).expect("geometry");
        assert_eq!(g.min, [-30.0, -79.0, -105.0]);
        assert_eq!(g.size, [60.0, 158.0, 210.0]);
        assert!((g.diameter - (60.0f64.powi(2) + 158.0f64.powi(2) + 210.0f64.powi(2)).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn the_pruned_diameter_equals_the_brute_force_one() {
        // A deterministic scatter of awkward shapes: a lopsided cloud, a line, duplicate points.
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let cloud: Vec<Vec3> =
            (0..400).map(|i| [next() * 100.0 + f64::from(i % 7), next() * 20.0, next().powi(3) * 300.0]).collect();
        assert_eq!(diameter(&cloud), brute_force(&cloud));
        let line: Vec<Vec3> = (0..50).map(|i| [f64::from(i), 0.0, 0.0]).collect();
        assert_eq!(diameter(&line), 49.0);
        assert_eq!(diameter(&[[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]]), 0.0);
    }

    #[test]
    fn a_moved_model_keeps_its_triangles_and_moves_each_vertex() {
        let mut ply = b"ply\nformat binary_little_endian 1.0\ncomment vint object model, units: mm\nelement vertex 2\n\
            property float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for v in [1.0f32, 2.0, 3.0, -4.0, 5.5, 0.0] {
            ply.extend_from_slice(&v.to_le_bytes());
        }
        ply.extend_from_slice(&[3, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0]);
        let moved = moved_ply(&ply, [40.0, 35.0, 15.0]).expect("vint's layout");
        let vertices = crate::eval::ply::vertices(&moved).expect("still a PLY");
        assert_eq!(vertices, vec![[41.0, 37.0, 18.0], [36.0, 40.5, 15.0]]);
        assert_eq!(moved.len(), ply.len());
        assert_eq!(moved[moved.len() - 13..], ply[ply.len() - 13..]);
        let ascii = b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        assert!(moved_ply(ascii, [1.0; 3]).is_err());
    }
}
