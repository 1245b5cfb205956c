//! The object models: vint's model PLY parsed (`Mesh`), moved into BOP's frame and written with
//! vertex normals, and their `models_info.json` entries: extents and diameter measured on the
//! vertices as the shipped file holds them (float32 millimetres).

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

/// A PLY's header: where its data starts, its comment lines and its other lines (trimmed).
fn header(bytes: &[u8]) -> anyhow::Result<(usize, Vec<&str>, Vec<&str>)> {
    const END: &[u8] = b"end_header\n";
    let end =
        bytes.windows(END.len()).position(|w| w == END).ok_or_else(|| anyhow!("PLY has no end_header"))? + END.len();
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| anyhow!("PLY header is not text"))?;
    let (comments, lines) =
        header.lines().map(str::trim).filter(|l| !l.is_empty()).partition(|l| l.starts_with("comment"));
    Ok((end, comments, lines))
}

/// `v` as a PLY of float32 coordinates holds it.
pub fn as_float32(v: Vec3) -> Vec3 {
    v.map(|x| f64::from(x as f32))
}

/// A triangle mesh as vint writes model PLYs (millimetres), with the header's comment lines.
pub struct Mesh {
    pub comments: Vec<String>,
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[usize; 3]>,
}

impl Mesh {
    /// The model PLY in vint's layout (binary little-endian, float `x y z`, then triangles); any
    /// other layout is refused rather than guessed at.
    pub fn parse(bytes: &[u8]) -> anyhow::Result<Mesh> {
        let (end, comments, lines) = header(bytes)?;
        let counts = match lines.as_slice() {
            [
                "ply",
                "format binary_little_endian 1.0",
                vertex,
                "property float x",
                "property float y",
                "property float z",
                face,
                "property list uchar int vertex_indices",
                "end_header",
            ] => vertex
                .strip_prefix("element vertex ")
                .and_then(|n| n.parse::<usize>().ok())
                .zip(face.strip_prefix("element face ").and_then(|n| n.parse::<usize>().ok())),
            _ => None,
        };
        let Some((n, m)) = counts else {
            bail!("the model PLY is not vint's layout (binary little-endian, float x y z, then triangles)");
        };
        let body = &bytes[end..];
        let vertex_bytes = n * 12;
        if Some(body.len()) != m.checked_mul(13).and_then(|f| f.checked_add(vertex_bytes)) {
            bail!("the model PLY holds {} data bytes, its header {n} vertices and {m} triangles", body.len());
        }
        let float = |at: usize| f64::from(f32::from_le_bytes([body[at], body[at + 1], body[at + 2], body[at + 3]]));
        let vertices: Vec<Vec3> = (0..n).map(|i| [0, 1, 2].map(|k| float(i * 12 + k * 4))).collect();
        let mut triangles = Vec::with_capacity(m);
        for f in body[vertex_bytes..].chunks_exact(13) {
            if f[0] != 3 {
                bail!("the model PLY has a face of {} vertices; only triangles are written", f[0]);
            }
            let index = |k: usize| {
                let i = i32::from_le_bytes([f[1 + 4 * k], f[2 + 4 * k], f[3 + 4 * k], f[4 + 4 * k]]);
                usize::try_from(i)
                    .ok()
                    .filter(|&i| i < n)
                    .ok_or_else(|| anyhow!("the model PLY names vertex {i} of {n}"))
            };
            triangles.push([index(0)?, index(1)?, index(2)?]);
        }
        Ok(Mesh { comments: comments.into_iter().map(str::to_string).collect(), vertices, triangles })
    }

    /// The same triangles in another frame: every vertex moved by `d` (mm), rounded to float32 as
    /// a PLY holds it.
    pub fn moved(self, d: Vec3) -> Mesh {
        if d == [0.0; 3] {
            return self;
        }
        let vertices = self.vertices.iter().map(|v| as_float32([v[0] + d[0], v[1] + d[1], v[2] + d[2]])).collect();
        Mesh { vertices, ..self }
    }

    /// The mesh as a PLY in vint's layout plus BOP's vertex normals (`nx ny nz` after `x y z`):
    /// each vertex's the angle-weighted sum of the normals of the triangles around it, normalized,
    /// as MeshLab computes the BOP datasets' (Thürrner and Wüthrich, "Computing vertex normals from
    /// polygonal facets", 1998). A vertex no triangle uses gets (0, 0, 0). Coordinates are written
    /// as float32, which every vertex read by `parse` already is.
    pub fn ply_with_normals(&self) -> Vec<u8> {
        let (n, m) = (self.vertices.len(), self.triangles.len());
        let mut normals = vec![[0.0f64; 3]; n];
        for ids in &self.triangles {
            let p = ids.map(|i| self.vertices[i]);
            let face_normal = unit(cross(sub(p[1], p[0]), sub(p[2], p[0])));
            for k in 0..3 {
                let (a, b) = (sub(p[(k + 1) % 3], p[k]), sub(p[(k + 2) % 3], p[k]));
                let angle = angle_between(a, b);
                for c in 0..3 {
                    normals[ids[k]][c] += angle * face_normal[c];
                }
            }
        }
        let mut out = String::from("ply\nformat binary_little_endian 1.0\n");
        for c in &self.comments {
            out.push_str(c);
            out.push('\n');
        }
        out.push_str("comment nx ny nz: angle-weighted vertex normals (as the BOP datasets' models)\n");
        out.push_str(&format!(
            "element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\n\
             element face {m}\nproperty list uchar int vertex_indices\nend_header\n"
        ));
        let mut out = out.into_bytes();
        for (v, normal) in self.vertices.iter().zip(&normals) {
            for x in v.iter().chain(&unit(*normal)) {
                out.extend_from_slice(&(*x as f32).to_le_bytes());
            }
        }
        for t in &self.triangles {
            out.push(3);
            for &i in t {
                // Indices come from `parse` (below n ≤ i32::MAX) or a resampling of one.
                out.extend_from_slice(&(i as i32).to_le_bytes());
            }
        }
        out
    }
}

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `v` scaled to length 1; the zero vector as it is (a degenerate triangle adds nothing).
fn unit(v: Vec3) -> Vec3 {
    let length = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if length > 0.0 { v.map(|x| x / length) } else { [0.0; 3] }
}

/// The angle between two edges at a corner, in radians (0 for a zero-length edge).
fn angle_between(a: Vec3, b: Vec3) -> f64 {
    let (ua, ub) = (unit(a), unit(b));
    let dot = ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2];
    if ua == [0.0; 3] || ub == [0.0; 3] { 0.0 } else { dot.clamp(-1.0, 1.0).acos() }
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

pub fn distance(a: &Vec3, b: &Vec3) -> f64 {
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

    /// A closed cube of 8 shared corners and 12 outward triangles, in vint's layout.
    fn cube_ply() -> Vec<u8> {
        let mut ply = b"ply\nformat binary_little_endian 1.0\ncomment vint object model, units: mm\nelement vertex 8\n\
            property float x\nproperty float y\nproperty float z\nelement face 12\nproperty list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for i in 0..8 {
            for bit in [1, 2, 4] {
                ply.extend_from_slice(&(if i & bit == 0 { -10.0f32 } else { 10.0f32 }).to_le_bytes());
            }
        }
        let faces: [[i32; 3]; 12] = [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6], // z = -10, z = +10
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7], // y = -10, y = +10
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5], // x = -10, x = +10
        ];
        for f in faces {
            ply.push(3);
            for i in f {
                ply.extend_from_slice(&i.to_le_bytes());
            }
        }
        ply
    }

    #[test]
    fn a_cube_s_corner_normals_point_along_its_diagonals() {
        let ply = Mesh::parse(&cube_ply()).expect("vint's layout").ply_with_normals();
        let vertices = crate::eval::ply::vertices(&ply).expect("still a PLY");
        assert_eq!(vertices.len(), 8);
        let end = ply.windows(11).position(|w| w == b"end_header\n").expect("header") + 11;
        let header = std::str::from_utf8(&ply[..end]).expect("text");
        assert!(
            header.contains("property float nx\nproperty float ny\nproperty float nz\nelement face 12"),
            "{header}"
        );
        for (i, record) in ply[end..end + 8 * 24].chunks_exact(24).enumerate() {
            let f = |k: usize| f64::from(f32::from_le_bytes(record[k * 4..k * 4 + 4].try_into().expect("4 bytes")));
            let (p, nrm) = ([f(0), f(1), f(2)], [f(3), f(4), f(5)]);
            // Each corner has three faces and a right angle in each: the weighted sum is the diagonal.
            for k in 0..3 {
                assert!((nrm[k] - p[k].signum() / 3f64.sqrt()).abs() < 1e-6, "vertex {i}: {nrm:?} at {p:?}");
            }
        }
        assert_eq!(ply[ply.len() - 12 * 13..], cube_ply()[cube_ply().len() - 12 * 13..], "the triangles as they were");
        assert!(Mesh::parse(&ply).is_err(), "a PLY with normals already is not vint's layout");
    }

    #[test]
    fn a_moved_model_keeps_its_triangles_and_moves_each_vertex() {
        let mut ply = b"ply\nformat binary_little_endian 1.0\ncomment vint object model, units: mm\nelement vertex 3\n\
            property float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for v in [1.0f32, 2.0, 3.0, -4.0, 5.5, 0.0, 0.1, 0.0, 0.0] {
            ply.extend_from_slice(&v.to_le_bytes());
        }
        ply.extend_from_slice(&[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0]);
        let mesh = Mesh::parse(&ply).expect("vint's layout");
        let moved = Mesh::parse(&ply).expect("vint's layout").moved([40.0, 35.0, 15.0]);
        assert_eq!(moved.triangles, mesh.triangles);
        assert_eq!(moved.vertices[..2], [[41.0, 37.0, 18.0], [36.0, 40.5, 15.0]]);
        // Rounded as the written file holds it: what a reader of models/ gets back.
        let written = crate::eval::ply::vertices(&moved.ply_with_normals()).expect("still a PLY");
        assert_eq!(written, moved.vertices);
        assert_eq!(moved.vertices[2][0], f64::from((0.1f32 as f64 + 40.0) as f32));
    }
}
