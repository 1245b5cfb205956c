//! Rigid transforms between the frames a BOP export mixes: world, camera (OpenCV), object model,
//! palm and hand links. Native poses are `{p, q}` with `q = [w, x, y, z]` in metres; the export
//! writes millimetres, so the unit change happens where a translation is written, not here.

pub type Vec3 = [f64; 3];
pub type Mat3 = [[f64; 3]; 3];

/// `x ↦ r·x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub r: Mat3,
    pub t: Vec3,
}

impl Rigid {
    /// A body's pose in its parent: position `p` and unit quaternion `q = [w, x, y, z]`
    /// (normalised here, so a quaternion rounded in JSON still gives a rotation).
    pub fn from_pose(p: Vec3, q: [f64; 4]) -> Rigid {
        Rigid { r: quat_to_matrix(q), t: p }
    }

    /// First `self`, then `next`: `x ↦ next(self(x))`.
    pub fn then(&self, next: &Rigid) -> Rigid {
        Rigid { r: mat_mul(&next.r, &self.r), t: next.point(self.t) }
    }

    pub fn point(&self, x: Vec3) -> Vec3 {
        let d = self.direction(x);
        [d[0] + self.t[0], d[1] + self.t[1], d[2] + self.t[2]]
    }

    /// A direction (a normal) turns but does not move.
    pub fn direction(&self, v: Vec3) -> Vec3 {
        let r = &self.r;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }
}

pub fn quat_to_matrix(q: [f64; 4]) -> Mat3 {
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    let [w, x, y, z] = if n > 0.0 { q.map(|c| c / n) } else { [1.0, 0.0, 0.0, 0.0] };
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, cell) in row.iter_mut().enumerate() {
            *cell = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Row-major, as BOP stores `cam_R_*` (9 numbers).
pub fn row_major(m: &Mat3) -> [f64; 9] {
    [m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn a_quarter_turn_about_z_maps_x_to_y() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let turn = Rigid::from_pose([1.0, 2.0, 3.0], [h, 0.0, 0.0, h]);
        assert!(close(turn.direction([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]));
        assert!(close(turn.point([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0]));
        // An unnormalised quaternion means the same rotation.
        let scaled = Rigid::from_pose([0.0; 3], [2.0 * h, 0.0, 0.0, 2.0 * h]);
        assert!(close(scaled.direction([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0]));
        assert!(close(scaled.direction([0.0, 1.0, 0.0]), [-1.0, 0.0, 0.0]));
    }

    #[test]
    fn composing_palm_to_world_then_world_to_camera_equals_applying_both_in_turn() {
        // q for 120° about (1,1,1)/√3: cyclic x→y→z.
        let palm_to_world = Rigid::from_pose([0.1, -0.2, 0.3], [0.5, 0.5, 0.5, 0.5]);
        let world_to_camera = Rigid::from_pose([0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0]); // 180° about x
        let p = [0.01, 0.02, -0.03];
        let composed = palm_to_world.then(&world_to_camera);
        assert!(close(composed.point(p), world_to_camera.point(palm_to_world.point(p))));
        // Worked by hand: cyclic turn (x,y,z)→(z,x,y) gives (-0.03, 0.01, 0.02), plus p_palm
        // (0.07, -0.19, 0.32); 180° about x gives (0.07, 0.19, -0.32), plus t (0.07, 0.19, 0.18).
        assert!(close(composed.point(p), [0.07, 0.19, 0.18]));
        assert!(close(composed.direction([1.0, 0.0, 0.0]), [0.0, -1.0, 0.0]));
    }

    #[test]
    fn row_major_reads_rows_first() {
        let m = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]];
        assert_eq!(row_major(&m), [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    }
}
