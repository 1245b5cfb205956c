//! Train / validation / test splits, by grasp: a grasp's views always share a split, so no view of
//! a test grasp was seen in training. Grasps of held-out objects or hands all go to `test` (an
//! unseen-object or unseen-hand benchmark); the others are dealt in a seeded order — each grasp's
//! rank derives from the job seed and its identity (`seed::split_rank`) — into exact counts by the
//! fractions (largest remainder), so a 10-grasp dataset at 0.8/0.1/0.1 gets 8/1/1.
//!
//! A split is a property of one dataset: adding grasps can move others, since the counts change.
//! It owns no I/O; the exports write its result.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::GraspId;
use crate::contract::Bound;
use crate::seed;

pub const TRAIN: Bound<f64> = Bound::new(0.0, 1.0, 0.8);
pub const VAL: Bound<f64> = Bound::new(0.0, 1.0, 0.1);
pub const TEST: Bound<f64> = Bound::new(0.0, 1.0, 0.1);
/// How far the fractions' sum may stray from 1 (they are written by hand, e.g. 0.7/0.2/0.1).
pub const SUM_TOLERANCE: f64 = 1e-6;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];
    /// Their names, as datasets write them (`dataset.json`, BOP's split folders, shard folders).
    pub const NAMES: [&'static str; 3] = ["train", "val", "test"];

    pub fn as_str(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

/// `[split]` of a spec.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SplitSettings {
    pub train: f64,
    pub val: f64,
    pub test: f64,
    /// Every grasp of these objects goes to `test`, and no other split sees them.
    pub held_out_objects: Vec<String>,
    /// Every grasp of these hands goes to `test`.
    pub held_out_hands: Vec<String>,
}

impl Default for SplitSettings {
    fn default() -> SplitSettings {
        SplitSettings {
            train: TRAIN.default,
            val: VAL.default,
            test: TEST.default,
            held_out_objects: Vec::new(),
            held_out_hands: Vec::new(),
        }
    }
}

impl SplitSettings {
    fn held_out(&self, g: &GraspId) -> bool {
        self.held_out_objects.contains(&g.object) || self.held_out_hands.contains(&g.hand)
    }
}

/// Each grasp's split under `job_seed`. Deterministic: the same grasps, seed and settings give
/// the same assignment whatever their order.
pub fn assign(grasps: &[GraspId], job_seed: u64, settings: &SplitSettings) -> BTreeMap<GraspId, Split> {
    let mut out = BTreeMap::new();
    let mut dealt: Vec<(u64, &GraspId)> = Vec::new();
    for g in grasps {
        if settings.held_out(g) {
            out.insert(g.clone(), Split::Test);
        } else {
            dealt.push((seed::split_rank(job_seed, &g.object, &g.hand, g.grasp_index), g));
        }
    }
    dealt.sort();
    dealt.dedup_by(|a, b| a.1 == b.1);
    let counts = counts(dealt.len(), [settings.train, settings.val, settings.test]);
    let mut splits = Split::ALL.iter().zip(counts).flat_map(|(s, n)| std::iter::repeat_n(*s, n));
    for (_, g) in dealt {
        // `counts` sums to the number dealt, so the iterator never runs dry; test is the fallback.
        out.insert(g.clone(), splits.next().unwrap_or(Split::Test));
    }
    out
}

/// `n` items dealt by `fractions` (normalised) into whole counts summing to `n`: floors first, the
/// rest one each to the largest remainders (ties to the earlier split).
fn counts(n: usize, fractions: [f64; 3]) -> [usize; 3] {
    let total: f64 = fractions.iter().sum();
    if n == 0 || total <= 0.0 {
        return [0, 0, n];
    }
    let exact = fractions.map(|f| f / total * n as f64);
    let mut counts = exact.map(|x| x.floor() as usize);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| (exact[b] - exact[b].floor()).total_cmp(&(exact[a] - exact[a].floor())).then(a.cmp(&b)));
    let mut left = n - counts.iter().sum::<usize>();
    for i in order.iter().cycle() {
        if left == 0 {
            break;
        }
        if fractions[*i] > 0.0 {
            counts[*i] += 1;
            left -= 1;
        }
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grasps(objects: &[&str], hands: &[&str], per_pair: u32) -> Vec<GraspId> {
        let mut out = Vec::new();
        for o in objects {
            for h in hands {
                for i in 0..per_pair {
                    out.push(GraspId { object: o.to_string(), hand: h.to_string(), grasp_index: i });
                }
            }
        }
        out
    }

    fn tally(a: &BTreeMap<GraspId, Split>) -> [usize; 3] {
        let mut t = [0; 3];
        for s in a.values() {
            t[*s as usize] += 1;
        }
        t
    }

    #[test]
    fn names_are_the_splits_as_str() {
        assert_eq!(Split::ALL.map(Split::as_str), Split::NAMES);
    }

    #[test]
    fn ten_grasps_at_the_default_fractions_split_eight_one_one() {
        let g = grasps(&["mug", "can"], &["trx3"], 5);
        assert_eq!(tally(&assign(&g, 7, &SplitSettings::default())), [8, 1, 1]);
    }

    #[test]
    fn the_assignment_depends_on_the_seed_not_on_the_order_of_grasps() {
        let g = grasps(&["mug", "can", "box"], &["trx3", "allegro"], 20);
        let mut reversed = g.clone();
        reversed.reverse();
        let s = SplitSettings::default();
        assert_eq!(assign(&g, 1, &s), assign(&reversed, 1, &s));
        assert_ne!(assign(&g, 1, &s), assign(&g, 2, &s), "another seed deals another split");
        assert_eq!(tally(&assign(&g, 1, &s)), [96, 12, 12]);
    }

    #[test]
    fn held_out_objects_and_hands_are_only_in_test() {
        let g = grasps(&["mug", "can", "box"], &["trx3", "allegro"], 10);
        let s = SplitSettings {
            held_out_objects: vec!["mug".into()],
            held_out_hands: vec!["allegro".into()],
            ..SplitSettings::default()
        };
        let a = assign(&g, 3, &s);
        for (grasp, split) in &a {
            if grasp.object == "mug" || grasp.hand == "allegro" {
                assert_eq!(*split, Split::Test, "{grasp}");
            }
        }
        // 20 grasps remain (can and box with trx3): 16 / 2 / 2 of them, plus 40 held out in test.
        assert_eq!(tally(&a), [16, 2, 42]);
    }

    #[test]
    fn counts_sum_to_n_and_skip_empty_splits() {
        for n in 0..50 {
            for f in [[0.8, 0.1, 0.1], [0.7, 0.3, 0.0], [1.0, 0.0, 0.0], [0.34, 0.33, 0.33]] {
                let c = counts(n, f);
                assert_eq!(c.iter().sum::<usize>(), n, "{n} {f:?}");
                for i in 0..3 {
                    if f[i] == 0.0 {
                        assert_eq!(c[i], 0, "{n} {f:?}");
                    }
                }
            }
        }
    }
}
