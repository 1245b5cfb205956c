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

/// An object's symmetry list (BOP's form, in the units of `d`) re-expressed in the frame whose
/// coordinates are `x + d`: a symmetry `x ↦ R·x + t` becomes `x ↦ R·x + t + d − R·d`, a continuous
/// one's axis keeps its direction and its point moves by `d`; every number to 1e-9 (nanometres),
/// as the native records write them. `None` when the list is not in
/// BOP's form (`key` says which list: `symmetries_continuous` or `symmetries_discrete`).
pub fn moved_symmetries(key: &str, list: &serde_json::Value, d: Vec3) -> Option<serde_json::Value> {
    let nano = |x: f64| (x * 1e9).round() / 1e9 + 0.0;
    let numbers = |v: &serde_json::Value, n: usize| -> Option<Vec<f64>> {
        let l = v.as_array().filter(|l| l.len() == n)?;
        l.iter().map(serde_json::Value::as_f64).collect()
    };
    let moved = list
        .as_array()?
        .iter()
        .map(|s| {
            if key == "symmetries_continuous" {
                let offset = numbers(&s["offset"], 3)?;
                let mut s = s.clone();
                s["offset"] = serde_json::json!([0, 1, 2].map(|k| nano(offset[k] + d[k])));
                Some(s)
            } else {
                let mut m = numbers(s, 16)?;
                let r = [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]];
                let rd = Rigid { r, t: [0.0; 3] }.direction(d);
                for k in 0..3 {
                    m[4 * k + 3] += d[k] - rd[k];
                }
                Some(serde_json::json!(m.into_iter().map(nano).collect::<Vec<_>>()))
            }
        })
        .collect::<Option<Vec<_>>>()?;
    Some(serde_json::Value::Array(moved))
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

    #[test]
    fn a_moved_symmetry_maps_the_moved_points_as_the_original_maps_the_originals() {
        // Half turn about z through (0.01, 0.02, 0) in the old frame.
        let (c, d) = ([0.01, 0.02, 0.0], [0.3, -0.1, 0.05]);
        let flip = serde_json::json!([[
            -1.0,
            0.0,
            0.0,
            2.0 * c[0],
            0.0,
            -1.0,
            0.0,
            2.0 * c[1],
            0.0,
            0.0,
            1.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0
        ]]);
        let moved = moved_symmetries("symmetries_discrete", &flip, d).expect("bop form");
        let m: Vec<f64> = moved[0].as_array().unwrap().iter().filter_map(serde_json::Value::as_f64).collect();
        let apply = |m: &[f64], x: Vec3| {
            [0, 1, 2].map(|k| m[4 * k] * x[0] + m[4 * k + 1] * x[1] + m[4 * k + 2] * x[2] + m[4 * k + 3])
        };
        let old: Vec<f64> = flip[0].as_array().unwrap().iter().filter_map(serde_json::Value::as_f64).collect();
        let x = [0.04, -0.02, 0.07];
        let image = apply(&old, x);
        let (got, want) = (apply(&m, [x[0] + d[0], x[1] + d[1], x[2] + d[2]]), [0, 1, 2].map(|k| image[k] + d[k]));
        assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-8), "{got:?} {want:?}");
        let axis = serde_json::json!([{"axis": [0.0, 0.0, 1.0], "offset": c}]);
        let moved = moved_symmetries("symmetries_continuous", &axis, d).expect("bop form");
        assert_eq!(moved[0]["axis"], axis[0]["axis"]);
        let offset: Vec<f64> =
            moved[0]["offset"].as_array().unwrap().iter().filter_map(serde_json::Value::as_f64).collect();
        assert!(close([offset[0], offset[1], offset[2]], [c[0] + d[0], c[1] + d[1], c[2] + d[2]]));
        assert!(moved_symmetries("symmetries_discrete", &serde_json::json!([[1.0, 0.0]]), d).is_none());
    }
}
