//! The pose errors and the scores built from them (docs/metrics.md), on plain numbers: no files,
//! no datasets.
//!
//! ADD and ADD-S are the BOP toolkit's `add` and `adi` (PoseCNN's definitions): the model's points
//! (the PLY's vertices) in both poses; ADD pairs each point with itself, ADD-S each ground-truth
//! posed point with the nearest estimated posed point. The AUC is the YCB-Video toolbox's
//! (PoseCNN, PVN3D): the area under the accuracy-over-threshold curve up to 100 mm as its VOCap
//! sums it, scaled to 0–100.

use super::kdtree::{KdTree, squared_distance};

/// A rigid transform from the model frame to the camera frame: x ↦ R x + t (millimetres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Row-major: `r[i][j]` is row i, column j.
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
}

impl Pose {
    pub fn apply(&self, x: &[f64; 3]) -> [f64; 3] {
        let r = &self.r;
        [
            r[0][0] * x[0] + r[0][1] * x[1] + r[0][2] * x[2] + self.t[0],
            r[1][0] * x[0] + r[1][1] * x[1] + r[1][2] * x[2] + self.t[1],
            r[2][0] * x[0] + r[2][1] * x[1] + r[2][2] * x[2] + self.t[2],
        ]
    }
}

/// ADD: the mean over model points x of ‖(R̂ x + t̂) − (R x + t)‖. Infinity for no points (a
/// model without vertices scores nothing rather than a perfect 0).
pub fn add(points: &[[f64; 3]], estimate: &Pose, truth: &Pose) -> f64 {
    mean(points.iter().map(|x| squared_distance(&estimate.apply(x), &truth.apply(x)).sqrt()), points.len())
}

/// ADD-S: the mean over model points x of the distance from the ground-truth posed point R x + t to
/// the nearest estimated posed point R̂ y + t̂ (y over all model points) — the BOP toolkit's `adi`,
/// which queries from the ground truth into the estimate. Exact (a k-d tree, not an
/// approximation).
pub fn adds(points: &[[f64; 3]], estimate: &Pose, truth: &Pose) -> f64 {
    let tree = KdTree::new(points.iter().map(|y| estimate.apply(y)).collect());
    mean(points.iter().map(|x| tree.nearest_squared(&truth.apply(x)).sqrt()), points.len())
}

fn mean(values: impl Iterator<Item = f64>, n: usize) -> f64 {
    if n == 0 {
        return f64::INFINITY;
    }
    values.sum::<f64>() / n as f64
}

/// The AUC's upper threshold: 10 cm, in millimetres.
pub const AUC_MAX_MM: f64 = 100.0;

/// The area under the accuracy–threshold curve for thresholds 0..`max`, ×100/`max` (0–100), as the
/// YCB-Video toolbox's VOCap computes it: with the n errors sorted and d_1 ≤ … ≤ d_k the ones ≤
/// `max`, d_0 = 0,
///   AUC = 100/max · [ Σ_{j=1..k} (d_j − d_{j−1}) · j/n + (max − d_k) · k/n ],
/// i.e. each step of the empirical accuracy curve is taken at its right end; this exceeds the
/// exact integral of the curve by 100·d_k/(n·max). Errors above `max` (and missing estimates,
/// infinite) count in n only. `None` for no errors.
pub fn auc(errors: &[f64], max: f64) -> Option<f64> {
    if errors.is_empty() {
        return None;
    }
    let n = errors.len() as f64;
    let mut within: Vec<f64> = errors.iter().copied().filter(|e| *e <= max).collect();
    within.sort_by(f64::total_cmp);
    let mut area = 0.0;
    let mut previous = 0.0;
    for (j, e) in within.iter().enumerate() {
        area += (e - previous) * (j + 1) as f64 / n;
        previous = *e;
    }
    area += (max - previous) * within.len() as f64 / n;
    Some(100.0 * area / max)
}

/// The share (0–100) of errors strictly below their own threshold (`fraction` × the object's
/// diameter); `None` for no errors.
pub fn within_percent(errors_and_diameters: &[(f64, f64)], fraction: f64) -> Option<f64> {
    if errors_and_diameters.is_empty() {
        return None;
    }
    let hits = errors_and_diameters.iter().filter(|(e, d)| *e < fraction * d).count();
    Some(100.0 * hits as f64 / errors_and_diameters.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    fn rot_z(angle: f64) -> [[f64; 3]; 3] {
        let (s, c) = angle.sin_cos();
        [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    }

    fn rot_x(angle: f64) -> [[f64; 3]; 3] {
        let (s, c) = angle.sin_cos();
        [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
    }

    fn matmul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
            }
        }
        m
    }

    /// The rim points of a cylinder about z: `rings` circles of `around` points, radius 30 mm,
    /// height 80 mm.
    fn cylinder(around: usize, rings: usize) -> Vec<[f64; 3]> {
        let mut points = Vec::new();
        for ring in 0..rings {
            let z = -40.0 + 80.0 * ring as f64 / (rings - 1) as f64;
            for k in 0..around {
                let a = std::f64::consts::TAU * k as f64 / around as f64;
                points.push([30.0 * a.cos(), 30.0 * a.sin(), z]);
            }
        }
        points
    }

    fn box_corners() -> Vec<[f64; 3]> {
        let mut points = Vec::new();
        for x in [-20.0, 20.0] {
            for y in [-35.0, 35.0] {
                for z in [-50.0, 50.0] {
                    points.push([x, y, z]);
                }
            }
        }
        points
    }

    fn pose(r: [[f64; 3]; 3], t: [f64; 3]) -> Pose {
        Pose { r, t }
    }

    #[test]
    fn the_true_pose_scores_zero() {
        let truth = pose(matmul(&rot_z(0.4), &rot_x(1.1)), [10.0, -20.0, 400.0]);
        assert_eq!(add(&box_corners(), &truth, &truth), 0.0);
        assert_eq!(adds(&box_corners(), &truth, &truth), 0.0);
        assert_eq!(adds(&cylinder(36, 5), &truth, &truth), 0.0);
    }

    #[test]
    fn a_pure_translation_by_d_gives_add_d() {
        let truth = pose(rot_x(0.3), [0.0, 0.0, 500.0]);
        let estimate = pose(rot_x(0.3), [3.0, 4.0, 500.0]); // 5 mm away
        assert!((add(&box_corners(), &estimate, &truth) - 5.0).abs() < 1e-12);
        // The nearest estimated corner of a 40 mm box 5 mm off is the same corner.
        assert!((adds(&box_corners(), &estimate, &truth) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn a_turn_about_the_cylinder_axis_is_free_for_adds_but_not_for_add() {
        let points = cylinder(36, 5);
        let truth = pose(rot_x(0.7), [5.0, 5.0, 450.0]);
        // One step of the point pattern (10°): every posed point lands on another one.
        let step = std::f64::consts::TAU / 36.0;
        let estimate = pose(matmul(&rot_x(0.7), &rot_z(step)), truth.t);
        let e_adds = adds(&points, &estimate, &truth);
        let e_add = add(&points, &estimate, &truth);
        assert!(e_adds < 1e-9, "ADD-S {e_adds}");
        // Each point moves along a 30 mm chord of 10°: 2·30·sin(5°).
        let chord = 60.0 * (step / 2.0).sin();
        assert!((e_add - chord).abs() < 1e-9, "ADD {e_add} vs {chord}");
        // Half a step: ADD-S is the distance to the nearest neighbour on the rim, well below ADD.
        let half = pose(matmul(&rot_x(0.7), &rot_z(step / 2.0)), truth.t);
        let (s, a) = (adds(&points, &half, &truth), add(&points, &half, &truth));
        assert!((s - 60.0 * (step / 4.0).sin()).abs() < 1e-9 && a > s, "ADD-S {s}, ADD {a}");
    }

    #[test]
    fn adds_queries_from_the_ground_truth_into_the_estimate() {
        let points = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [100.0, 0.0, 0.0]];
        let truth = pose(IDENTITY, [0.0, 0.0, 0.0]);
        // Moved by +10 mm, the estimate's posed points are 10, 20, 110: from the truth's 0 the
        // nearest is 10 (10 mm), from 10 itself (0), from 100 it is 110 (10): mean 20/3.
        let shifted = pose(IDENTITY, [10.0, 0.0, 0.0]);
        assert!((adds(&points, &shifted, &truth) - 20.0 / 3.0).abs() < 1e-12);
        // A direction-sensitive case: an estimate (not a rotation; the metric does not care) that
        // squeezes x tenfold poses the points at 0, 1, 10. From the truth's 0, 10, 100 the
        // nearest are 0, 10, 10: mean 90/3 = 30. The reverse query (from 0, 1, 10 into the
        // truth) would give 1/3.
        let squeeze = Pose { r: [[0.1, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], t: [0.0, 0.0, 0.0] };
        assert!((adds(&points, &squeeze, &truth) - 30.0).abs() < 1e-12);
    }

    #[test]
    fn auc_of_known_error_lists() {
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-9;
        // All perfect: the curve is 1 everywhere.
        assert!(close(auc(&[0.0, 0.0, 0.0], 100.0), 100.0));
        // All beyond 10 cm or missing: 0.
        assert!(close(auc(&[150.0, f64::INFINITY], 100.0), 0.0));
        // One error of 50 mm: accuracy 1 from 50 mm on, and VOCap counts the first step at its
        // right end too: 100/100 · [(50 − 0)·1 + (100 − 50)·1] = 100 (the exact integral is 50).
        assert!(close(auc(&[50.0], 100.0), 100.0));
        // Two errors 20 and 60 mm: [20·½ + 40·1 + 40·1] = 90.
        assert!(close(auc(&[60.0, 20.0], 100.0), 90.0));
        // Add a missing one (n = 3): [20·⅓ + 40·⅔ + 40·⅔] = 60.
        assert!(close(auc(&[60.0, f64::INFINITY, 20.0], 100.0), 60.0));
        // Ties take the first step's accuracy over the tied width: [50·½ + 0 + 50·1] = 75.
        assert!(close(auc(&[50.0, 50.0], 100.0), 75.0));
        // An error exactly at the limit still counts: [100·1 + 0] = 100.
        assert!(close(auc(&[100.0], 100.0), 100.0));
        assert_eq!(auc(&[], 100.0), None);
    }

    #[test]
    fn auc_equals_the_exact_integral_plus_the_last_step() {
        // Independent form: ∫₀^max acc(τ) dτ = Σ max(0, max − e_i)/n, plus 100·d_k/(n·max).
        let errors = [3.5, 17.0, 99.0, 0.25, 140.0, f64::INFINITY, 42.0, 42.0, 61.0];
        let n = errors.len() as f64;
        let exact: f64 = errors.iter().map(|e| (100.0 - e).max(0.0)).sum::<f64>() / n;
        let last = errors.iter().copied().filter(|e| *e <= 100.0).fold(0.0, f64::max);
        let expected = exact + 100.0 * last / (n * 100.0);
        assert!((auc(&errors, 100.0).unwrap() - expected).abs() < 1e-9);
    }

    #[test]
    fn success_is_strictly_below_the_fraction_of_the_diameter() {
        let errors = [(9.9, 100.0), (10.0, 100.0), (4.0, 50.0), (f64::INFINITY, 100.0)];
        assert_eq!(within_percent(&errors, 0.1), Some(50.0));
        assert_eq!(within_percent(&errors, 0.05), Some(0.0));
        assert_eq!(within_percent(&[], 0.1), None);
    }
}
