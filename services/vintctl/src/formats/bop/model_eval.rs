//! `models_eval/`: each model resampled so its vertices lie uniformly over its surface, which is
//! what the BOP toolkit measures pose errors on (ADD, ADD-S, MSSD, MSPD average or take extremes
//! over a model's vertices; VSD renders the mesh). A model's own vertices are where its modeller
//! needed them — a procedural box has its 8 corners, a cylinder its two rims — so an error
//! averaged over them weighs a few places of the surface and is not comparable with the field's
//! numbers, which use the BOP datasets' `models_eval` (MeshLab's uniform mesh resampling) or
//! PoseCNN's uniform `points.xyz`.
//!
//! The sampling, in full (docs/formats.md states it for users):
//! 1. Spacing `r` = `SPACING_MM`, widened to √(area / `MAX_AREA_PER_R2`) for a model so large that
//!    it would otherwise carry more than about 5,600 points.
//! 2. Candidates: the model's vertices (used by a triangle) first, then the corners of every
//!    triangle's pieces, cut by longest-edge bisection until no edge exceeds r/3, so every surface
//!    point is within r/(3√3) of a candidate (Jung's theorem).
//! 3. Poisson-disk thinning: candidates in a fixed pseudo-random order (the model's vertices
//!    before the pieces' corners; keyed by a hash of the model's file in `models/`, so a model gets
//!    the same points in every dataset) are kept when no kept point is closer than r. Kept points are thus at
//!    least r apart, and every candidate lies within r of one (every surface point within 1.2 r).
//!    Keeping vertices first keeps a box's corners and a cylinder's rims, and so the diameter.
//! 4. Triangles: each piece whose corners' nearest kept points are three different points gives
//!    the triangle of those three, wound as the original (duplicates dropped): the dual of the
//!    kept points' nearest-point regions on the surface.
//!
//! Every kept point is a point of the original surface (to float32). The mesh is for rendering
//! (VSD); it need not be watertight where regions meet awkwardly.

use std::collections::{HashMap, HashSet};
use std::hash::{BuildHasherDefault, Hasher};

use sha2::{Digest, Sha256};

use super::frames::Vec3;
use super::model::{Mesh, cross, distance, sub};

/// The nominal distance between neighbouring points, in mm. At 2 mm a 100 mm mug carries a few
/// thousand points: the mean over them (ADD) is converged far below a millimetre.
pub const SPACING_MM: f64 = 2.0;
/// `r` is at least √(area / this): a Poisson-disk set of spacing r covers about 0.7 points per r²,
/// so no model carries more than about 5,600 points (PoseCNN's YCB-Video `points.xyz` have 2,620).
pub const MAX_AREA_PER_R2: f64 = 8_000.0;
/// Candidates are the corners of triangle pieces no edge of which is longer than r / this.
const PIECES_PER_R: f64 = 3.0;

/// A model resampled for evaluation.
pub struct EvalModel {
    pub mesh: Mesh,
    /// The Poisson-disk spacing r (mm).
    pub spacing_mm: f64,
}

/// `model` (mm) resampled as the module documentation says; `seed_bytes` (the model's PLY in
/// `models/`) key the order candidates are visited in.
pub fn resample(model: &Mesh, seed_bytes: &[u8]) -> EvalModel {
    let area: f64 = model.triangles.iter().map(|t| triangle_area(&model.vertices, t)).sum();
    let spacing = SPACING_MM.max((area / MAX_AREA_PER_R2).sqrt());
    let key = order_key(seed_bytes);
    let mut kept = Kept::new(spacing);

    let mut used: Vec<usize> = model.triangles.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    used.sort_by_key(|&i| mix(key ^ i as u64));
    for &i in &used {
        kept.offer(model.vertices[i]);
    }
    let step = spacing / PIECES_PER_R;
    let corners = |t: &[usize; 3]| t.map(|i| model.vertices[i]);
    let mut order: Vec<usize> = (0..model.triangles.len()).collect();
    order.sort_by_key(|&i| mix(key.rotate_left(32) ^ i as u64));
    for &i in &order {
        // The corners were offered above; each cut adds one new point, its midpoint.
        bisect(corners(&model.triangles[i]), [(); 3], step, |p| kept.offer(p), |_| {});
    }

    let mut triangles = Vec::new();
    let mut seen = HashSet::new();
    for t in &model.triangles {
        let c = corners(t);
        let nearest = c.map(|p| kept.nearest(p));
        bisect(
            c,
            nearest,
            step,
            |p| kept.nearest(p),
            |t| {
                if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                    let mut sorted = t;
                    sorted.sort_unstable();
                    if seen.insert(sorted) {
                        triangles.push(t);
                    }
                }
            },
        );
    }
    let mut comments = model.comments.clone();
    comments.push(format!(
        "comment models_eval: Poisson-disk resampling of models/, spacing {spacing:.6} mm (docs/formats.md)"
    ));
    EvalModel { mesh: Mesh { comments, vertices: kept.points, triangles }, spacing_mm: spacing }
}

/// The kept points and a hash grid of cell 2r over them.
struct Kept {
    spacing: f64,
    points: Vec<Vec3>,
    cells: HashMap<u64, Vec<usize>, BuildHasherDefault<CellHasher>>,
}

impl Kept {
    fn new(spacing: f64) -> Kept {
        Kept { spacing, points: Vec::new(), cells: HashMap::default() }
    }

    fn cell(&self, p: Vec3) -> [i64; 3] {
        p.map(|x| (x / (2.0 * self.spacing)).floor() as i64)
    }

    /// A cell's key: its coordinates' low 21 bits each. Cells 2²¹ apart share a key, which costs
    /// only a few distance checks (every candidate's distance is measured), never a wrong answer.
    fn key(c: [i64; 3]) -> u64 {
        const LOW: i64 = (1 << 21) - 1;
        ((c[0] & LOW) | (c[1] & LOW) << 21 | (c[2] & LOW) << 42) as u64
    }

    /// The kept points of the cells that can hold one closer than r to `p`, cell by cell. Cells are
    /// 2r wide, so along each axis that is `p`'s cell and the neighbour on the side of the cell's
    /// half `p` lies in (both neighbours within a hair of the middle, against rounding): 8 cells,
    /// rarely more, where cells of r would need 27. (Loops, not iterator adapters: this is the
    /// export's hot path, and the dev build `scripts/setup.sh` makes leaves vint's code unoptimized.)
    fn around(&self, p: Vec3) -> impl Iterator<Item = &[usize]> {
        const MIDDLE_HAIR: f64 = 1e-6;
        let c = self.cell(p);
        // Per axis, the neighbour below and the one above, each when `p` lies in that half.
        let within = |axis: usize| p[axis] / (2.0 * self.spacing) - c[axis] as f64;
        let low = [0, 1, 2].map(|axis| if within(axis) < 0.5 + MIDDLE_HAIR { -1 } else { 0 });
        let high = [0, 1, 2].map(|axis| if within(axis) > 0.5 - MIDDLE_HAIR { 1 } else { 0 });
        let (mut cells, mut found): ([&[usize]; 27], usize) = ([&[]; 27], 0);
        for dx in low[0]..=high[0] {
            for dy in low[1]..=high[1] {
                for dz in low[2]..=high[2] {
                    if let Some(points) = self.cells.get(&Kept::key([c[0] + dx, c[1] + dy, c[2] + dz])) {
                        cells[found] = points;
                        found += 1;
                    }
                }
            }
        }
        cells.into_iter().take(found)
    }

    /// Keeps `p` when no kept point is closer than r.
    fn offer(&mut self, p: Vec3) {
        for cell in self.around(p) {
            for &k in cell {
                if distance(&self.points[k], &p) < self.spacing {
                    return;
                }
            }
        }
        let cell = self.cell(p);
        self.cells.entry(Kept::key(cell)).or_default().push(self.points.len());
        self.points.push(p);
    }

    /// The kept point nearest a candidate (the lowest index of equals). Every candidate was offered
    /// and is therefore within r of a kept point, which lies in a neighbouring cell.
    fn nearest(&self, p: Vec3) -> usize {
        let mut best = (f64::INFINITY, usize::MAX);
        for cell in self.around(p) {
            for &k in cell {
                let d = distance(&self.points[k], &p);
                if d < best.0 || (d == best.0 && k < best.1) {
                    best = (d, k);
                }
            }
        }
        best.1
    }
}

/// Cuts triangle `corners` (wound as it is) by longest-edge bisection until no edge is longer than
/// `step`, calling `midpoint` once for each cut's new point (its value labels that point) and
/// `piece` with each final piece's corner labels, wound as the triangle. Bisection adapts to the
/// triangle's shape, so a long sliver (a cylinder's side) is not cut along its width as finely as
/// along its length.
fn bisect<T: Copy>(
    corners: [Vec3; 3],
    labels: [T; 3],
    step: f64,
    mut midpoint: impl FnMut(Vec3) -> T,
    mut piece: impl FnMut([T; 3]),
) {
    let mut stack = vec![(corners, labels)];
    while let Some((t, l)) = stack.pop() {
        let edge = |k: usize| distance(&t[k], &t[(k + 1) % 3]);
        let k = (0..3).max_by(|&x, &y| edge(x).total_cmp(&edge(y))).unwrap_or(0);
        if edge(k) <= step {
            piece(l);
            continue;
        }
        // Cut edge (k, k+1) at its midpoint m: (t_k, m, t_k+2) and (m, t_k+1, t_k+2) keep the winding.
        let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
        let m = [0, 1, 2].map(|c| 0.5 * (t[k][c] + t[k1][c]));
        let lm = midpoint(m);
        stack.push(([m, t[k1], t[k2]], [lm, l[k1], l[k2]]));
        stack.push(([t[k], m, t[k2]], [l[k], lm, l[k2]]));
    }
}

fn triangle_area(vertices: &[Vec3], t: &[usize; 3]) -> f64 {
    let [a, b, c] = t.map(|i| vertices[i]);
    let n = cross(sub(b, a), sub(c, a));
    0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
}

/// Hashes a cell key with `mix`: std's SipHash guards against keys chosen by an adversary, which a
/// model's own cells are not, at several times the cost.
#[derive(Default)]
struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = mix(self.0 ^ u64::from(*b));
        }
    }

    fn write_u64(&mut self, x: u64) {
        self.0 = mix(self.0 ^ x);
    }
}

/// The first 8 bytes of the bytes' SHA-256.
fn order_key(bytes: &[u8]) -> u64 {
    let digest = Sha256::digest(bytes);
    let mut first = [0u8; 8];
    first.copy_from_slice(&digest[..8]);
    u64::from_le_bytes(first)
}

/// SplitMix64's finalizer (Steele, Lea and Flood 2014): a bijection that scatters nearby inputs.
fn mix(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed, outward-wound box of half-extents `h`, as 8 corners and 12 triangles.
    fn box_mesh(h: Vec3) -> Mesh {
        let vertices = (0..8).map(|i| [0, 1, 2].map(|k| if i & (1 << k) == 0 { -h[k] } else { h[k] })).collect();
        let triangles = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        Mesh { comments: vec![], vertices, triangles }
    }

    /// How far `p` is from the box's surface.
    fn off_box(p: Vec3, h: Vec3) -> f64 {
        let outside = (0..3).map(|k| (p[k].abs() - h[k]).max(0.0).powi(2)).sum::<f64>().sqrt();
        let inside = (0..3).map(|k| h[k] - p[k].abs()).fold(f64::INFINITY, f64::min);
        if outside > 0.0 { outside } else { inside }
    }

    /// The signed volume the triangles enclose (positive when wound outward).
    fn volume(mesh: &Mesh) -> f64 {
        mesh.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| mesh.vertices[i]);
                let n = cross(b, c);
                (a[0] * n[0] + a[1] * n[1] + a[2] * n[2]) / 6.0
            })
            .sum()
    }

    #[test]
    fn a_box_is_resampled_on_its_surface_evenly_with_its_corners() {
        let h = [30.0, 20.0, 10.0];
        let model = box_mesh(h);
        let eval = resample(&model, b"box");
        let (points, r) = (&eval.mesh.vertices, eval.spacing_mm);
        assert_eq!(r, SPACING_MM);
        for p in points {
            assert!(off_box(*p, h) < 1e-9, "{p:?} is off the surface");
        }
        for corner in &model.vertices {
            assert!(points.contains(corner), "corner {corner:?} was not kept");
        }
        // At least r apart; and every surface point (a 1 mm lattice over each face) within 1.25 r.
        for (i, a) in points.iter().enumerate() {
            for b in &points[i + 1..] {
                assert!(distance(a, b) >= r, "{a:?} and {b:?} are {} apart", distance(a, b));
            }
        }
        let mut farthest = 0.0f64;
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in [-1.0, 1.0] {
                let steps = |k: usize| (0..=(2.0 * h[k]) as usize).map(move |s| s as f64 - h[k]);
                for a in steps(u) {
                    for b in steps(v) {
                        let mut p = [0.0; 3];
                        (p[axis], p[u], p[v]) = (side * h[axis], a, b);
                        let nearest = points.iter().map(|q| distance(q, &p)).fold(f64::INFINITY, f64::min);
                        farthest = farthest.max(nearest);
                    }
                }
            }
        }
        assert!(farthest <= 1.25 * r, "a surface point is {farthest} mm from every sample");
        // Area 2·(60·40 + 60·20 + 40·20) = 8800 mm²: a maximal Poisson-disk set holds 0.6–1.2 per r².
        let per_r2 = points.len() as f64 * r * r / 8800.0;
        assert!((0.6..1.2).contains(&per_r2), "{} points: {per_r2} per r²", points.len());
        // The triangles enclose the box, wound outward, to within a thin sliver along its edges.
        let v = volume(&eval.mesh);
        assert!((v / 48_000.0 - 1.0).abs() < 0.03, "the resampled box encloses {v} mm³ of 48000");
    }

    #[test]
    fn resampling_is_keyed_by_the_model_alone_and_widens_for_large_models() {
        let model = box_mesh([30.0, 20.0, 10.0]);
        let (a, b) = (resample(&model, b"box"), resample(&model, b"box"));
        assert_eq!(a.mesh.vertices, b.mesh.vertices);
        assert_eq!(a.mesh.triangles, b.mesh.triangles);
        let other = resample(&model, b"another file");
        assert_ne!(a.mesh.vertices, other.mesh.vertices, "another key visits candidates in another order");
        // A 1 m cube: 6 m² would take ~1.5 M points at 2 mm.
        let big = resample(&box_mesh([500.0; 3]), b"big");
        assert!((big.spacing_mm - (6e6 / MAX_AREA_PER_R2).sqrt()).abs() < 1e-9, "{}", big.spacing_mm);
        assert!(big.mesh.vertices.len() < 8_000, "{} points", big.mesh.vertices.len());
    }
}
