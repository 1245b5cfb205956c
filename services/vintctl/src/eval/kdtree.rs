//! Exact nearest-neighbour distances in 3-D, for ADD-S: a k-d tree stored as a permuted array
//! (the node of a range is its middle element; the halves on either side are its subtrees), so it
//! needs no pointers and no allocation beyond the points themselves.
//!
//! The search prunes a subtree only when the splitting plane alone is at least as far as the best
//! distance found so far, so the answer is the exact minimum — the same number a brute-force scan
//! computes, because both compute each candidate's squared distance the same way.

/// A point set that answers "how far is the nearest point to q?".
pub struct KdTree {
    points: Vec<[f64; 3]>,
    /// The splitting axis of the node at the same index (meaningless at leaves).
    axes: Vec<u8>,
}

impl KdTree {
    pub fn new(mut points: Vec<[f64; 3]>) -> KdTree {
        let mut axes = vec![0u8; points.len()];
        build(&mut points, &mut axes);
        KdTree { points, axes }
    }

    /// The squared distance from `q` to the nearest point; infinity for an empty set.
    pub fn nearest_squared(&self, q: &[f64; 3]) -> f64 {
        let mut best = f64::INFINITY;
        search(&self.points, &self.axes, q, &mut best);
        best
    }
}

pub fn squared_distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

fn build(points: &mut [[f64; 3]], axes: &mut [u8]) {
    if points.len() <= 1 {
        return;
    }
    // Splitting along the widest extent keeps cells compact for flat or elongated models (a
    // can's lid, a marker), where cycling axes would cut slivers.
    let axis = widest_axis(points);
    let mid = points.len() / 2;
    points.select_nth_unstable_by(mid, |a, b| a[axis].total_cmp(&b[axis]));
    axes[mid] = axis as u8;
    let (left, rest) = points.split_at_mut(mid);
    let (axes_left, axes_rest) = axes.split_at_mut(mid);
    build(left, axes_left);
    build(&mut rest[1..], &mut axes_rest[1..]);
}

fn widest_axis(points: &[[f64; 3]]) -> usize {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let spread = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    if spread[0] >= spread[1] && spread[0] >= spread[2] {
        0
    } else if spread[1] >= spread[2] {
        1
    } else {
        2
    }
}

fn search(points: &[[f64; 3]], axes: &[u8], q: &[f64; 3], best: &mut f64) {
    if points.is_empty() {
        return;
    }
    let mid = points.len() / 2;
    let node = &points[mid];
    *best = best.min(squared_distance(node, q));
    if points.len() == 1 {
        return;
    }
    let axis = usize::from(axes[mid]);
    let offset = q[axis] - node[axis];
    let (left, right) = (&points[..mid], &points[mid + 1..]);
    let (axes_left, axes_right) = (&axes[..mid], &axes[mid + 1..]);
    let ((near, near_axes), (far, far_axes)) =
        if offset < 0.0 { ((left, axes_left), (right, axes_right)) } else { ((right, axes_right), (left, axes_left)) };
    search(near, near_axes, q, best);
    // Every point across the plane is at least |offset| away along this axis alone.
    if offset * offset < *best {
        search(far, far_axes, q, best);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (no dependency): xorshift64*.
    struct Rng(u64);

    impl Rng {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }

        fn point(&mut self, scale: f64) -> [f64; 3] {
            [(self.uniform() - 0.5) * scale, (self.uniform() - 0.5) * scale, (self.uniform() - 0.5) * scale]
        }
    }

    fn brute_force(points: &[[f64; 3]], q: &[f64; 3]) -> f64 {
        points.iter().map(|p| squared_distance(p, q)).fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn nearest_equals_brute_force_exactly_on_random_clouds() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for n in [1usize, 2, 3, 7, 64, 1000] {
            let points: Vec<[f64; 3]> = (0..n).map(|_| rng.point(100.0)).collect();
            let tree = KdTree::new(points.clone());
            for _ in 0..300 {
                let q = rng.point(140.0);
                assert_eq!(tree.nearest_squared(&q), brute_force(&points, &q), "n = {n}, q = {q:?}");
            }
        }
    }

    #[test]
    fn duplicate_and_coplanar_points_are_found() {
        // A flat grid with every point twice: many ties on every axis.
        let mut points = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                points.push([f64::from(i), f64::from(j), 0.0]);
                points.push([f64::from(i), f64::from(j), 0.0]);
            }
        }
        let tree = KdTree::new(points.clone());
        let mut rng = Rng(7);
        for _ in 0..500 {
            let q = [rng.uniform() * 12.0 - 1.0, rng.uniform() * 12.0 - 1.0, rng.uniform() - 0.5];
            assert_eq!(tree.nearest_squared(&q), brute_force(&points, &q));
        }
        assert_eq!(tree.nearest_squared(&[3.0, 4.0, 0.0]), 0.0);
    }

    #[test]
    fn an_empty_set_is_infinitely_far() {
        assert_eq!(KdTree::new(Vec::new()).nearest_squared(&[0.0, 0.0, 0.0]), f64::INFINITY);
    }
}
