//! The object models' `models_info.json` entries: extents and diameter measured on the model PLY
//! itself (millimetres), so they describe exactly the file the export ships.

use anyhow::{Context, anyhow, bail};

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

/// The vertex positions of a binary little-endian PLY whose first element is `vertex` with
/// fixed-size properties including x, y and z (what the engines write, and what the BOP toolkit's
/// `load_ply` reads).
pub fn ply_vertices(bytes: &[u8]) -> anyhow::Result<Vec<Vec3>> {
    const END: &[u8] = b"end_header\n";
    let end = bytes.windows(END.len()).position(|w| w == END).ok_or_else(|| anyhow!("PLY has no end_header"))?;
    let header = std::str::from_utf8(&bytes[..end]).context("PLY header is not text")?;
    let body = &bytes[end + END.len()..];
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        bail!("not a PLY file");
    }
    let (mut format, mut count, mut offsets, mut stride) = (None, None, [None; 3], 0usize);
    let mut in_vertex = false;
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] => format = Some(*f),
            ["element", "vertex", n] if count.is_none() => {
                count = Some(n.parse::<usize>().context("PLY vertex count")?);
                in_vertex = true;
            }
            ["element", ..] if count.is_none() => bail!("PLY: the first element must be vertex"),
            ["element", ..] => in_vertex = false,
            ["property", "list", ..] if in_vertex => bail!("PLY: a list property in the vertex element"),
            ["property", kind, name] if in_vertex => {
                let size = scalar_size(kind)?;
                if let Some(k) = ["x", "y", "z"].iter().position(|axis| axis == name) {
                    if !matches!(*kind, "float" | "float32") {
                        bail!("PLY: vertex {name} is {kind}, expected float");
                    }
                    offsets[k] = Some(stride);
                }
                stride += size;
            }
            _ => {}
        }
    }
    if format != Some("binary_little_endian") {
        bail!("PLY format {format:?}: only binary_little_endian is read");
    }
    let count = count.ok_or_else(|| anyhow!("PLY has no vertex element"))?;
    let [Some(ox), Some(oy), Some(oz)] = offsets else { bail!("PLY vertex lacks x, y or z") };
    if body.len() < count * stride {
        bail!("PLY: {count} vertices need {} bytes, the file has {}", count * stride, body.len());
    }
    let f = |record: &[u8], at: usize| {
        f64::from(f32::from_le_bytes([record[at], record[at + 1], record[at + 2], record[at + 3]]))
    };
    Ok(body[..count * stride].chunks_exact(stride).map(|r| [f(r, ox), f(r, oy), f(r, oz)]).collect())
}

fn scalar_size(kind: &str) -> anyhow::Result<usize> {
    Ok(match kind {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        other => bail!("PLY: unknown property type {other:?}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ply(vertices: &[Vec3], extra_property: bool) -> Vec<u8> {
        let mut header = String::from("ply\nformat binary_little_endian 1.0\ncomment units: mm\n");
        header += &format!("element vertex {}\nproperty float x\n", vertices.len());
        if extra_property {
            header += "property uchar flag\n";
        }
        header +=
            "property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
        let mut bytes = header.into_bytes();
        for v in vertices {
            bytes.extend((v[0] as f32).to_le_bytes());
            if extra_property {
                bytes.push(7);
            }
            bytes.extend((v[1] as f32).to_le_bytes());
            bytes.extend((v[2] as f32).to_le_bytes());
        }
        bytes
    }

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
    fn reads_vertices_of_a_binary_ply_skipping_other_properties() {
        let vertices = [[1.5, -2.0, 3.25], [0.0, 10.0, -7.5]];
        assert_eq!(ply_vertices(&ply(&vertices, false)).expect("plain"), vertices);
        assert_eq!(ply_vertices(&ply(&vertices, true)).expect("with a flag"), vertices);
        let ascii = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n";
        assert!(format!("{:#}", ply_vertices(ascii).expect_err("ascii")).contains("binary_little_endian"));
        let short = ply(&vertices, false);
        assert!(
            format!("{:#}", ply_vertices(&short[..short.len() - 1]).expect_err("truncated")).contains("need 24 bytes")
        );
    }
}
