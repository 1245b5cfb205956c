//! A (object, hand) pair's trial budget and how it splits into grasp tasks. Its own module, below
//! both the spec (which states a budget) and the planner (which splits it into tasks), so that
//! neither imports the other for it.

/// A pair's trial budget and its split into grasp tasks (chunks). Without a quota every one of
/// the `trials` counts and chunk `c` runs trials `c·chunk_size ..` (`chunk_size` of them). With a
/// quota of `accepted` grasps (the paper's "until 2,500 successful grasps"), the pair aims at
/// `n = min(accepted, trials)` grasps: chunk `c` owns `quota(c)` of them (`chunk_size` but the
/// last) and a share of the trial indices in proportion, `⌊trials·k/n⌋` for its first and one
/// past its last grasp slot `k`, and stops once its quota is accepted. The shares tile
/// `0..trials`, so the pair never runs more than `trials` trials, and which trials a chunk runs
/// depends only on the spec — not on how many other chunks accepted, nor on the workers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairBudget {
    pub trials: u32,
    pub accepted: Option<u32>,
    pub chunk_size: u32,
}

impl PairBudget {
    /// Grasps the pair aims at (at most this many become samples): every trial without a quota.
    pub fn grasps(&self) -> u32 {
        self.accepted.map_or(self.trials, |a| a.min(self.trials)).max(1)
    }

    pub fn chunks(&self) -> u32 {
        self.grasps().div_ceil(self.chunk_size.max(1))
    }

    /// Chunk `c`'s quota of accepted grasps: `None` without a quota.
    pub fn quota(&self, c: u32) -> Option<u32> {
        self.accepted.map(|_| self.slots(c).len() as u32)
    }

    fn slots(&self, c: u32) -> std::ops::Range<u32> {
        let start = c.saturating_mul(self.chunk_size).min(self.grasps());
        start..start.saturating_add(self.chunk_size).min(self.grasps())
    }

    /// First trial index of grasp slot `k`.
    fn trial_of_slot(&self, k: u32) -> u32 {
        (u64::from(self.trials) * u64::from(k) / u64::from(self.grasps())) as u32
    }

    /// The trial indices chunk `c` may run.
    pub fn trials(&self, c: u32) -> std::ops::Range<u32> {
        let slots = self.slots(c);
        self.trial_of_slot(slots.start)..self.trial_of_slot(slots.end)
    }

    /// The most trials one chunk may run.
    pub fn max_task_trials(&self) -> u32 {
        let per_slot = u64::from(self.trials).div_ceil(u64::from(self.grasps()));
        u32::try_from(per_slot.saturating_mul(u64::from(self.chunk_size))).unwrap_or(u32::MAX).min(self.trials)
    }

    /// The chunk whose trials hold `grasp_index` (the last chunk for an index past them all).
    pub fn chunk_of(&self, grasp_index: u32) -> u32 {
        let (mut low, mut high) = (0, self.chunks().saturating_sub(1));
        while low < high {
            let middle = low + (high - low).div_ceil(2);
            if self.trials(middle).start <= grasp_index { low = middle } else { high = middle - 1 }
        }
        low
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_quota_chunks_run_consecutive_trials() {
        let b = PairBudget { trials: 10, accepted: None, chunk_size: 4 };
        assert_eq!(b.chunks(), 3);
        assert_eq!((0..3).map(|c| b.trials(c)).collect::<Vec<_>>(), vec![0..4, 4..8, 8..10]);
        assert_eq!((0..3).map(|c| b.quota(c)).collect::<Vec<_>>(), vec![None, None, None]);
    }

    #[test]
    fn a_quota_splits_the_trial_budget_in_proportion_and_tiles_it() {
        for (trials, accepted, chunk_size) in [(10_000, 2_500, 64), (7, 3, 2), (5, 9, 2), (1_000, 999, 7), (3, 1, 1)] {
            let b = PairBudget { trials, accepted: Some(accepted), chunk_size };
            let target = accepted.min(trials);
            let ranges: Vec<_> = (0..b.chunks()).map(|c| b.trials(c)).collect();
            assert_eq!(ranges.first().map(|r| r.start), Some(0));
            assert_eq!(ranges.last().map(|r| r.end), Some(trials), "{b:?}");
            assert!(ranges.windows(2).all(|w| w[0].end == w[1].start), "{b:?}: {ranges:?}");
            let quotas: Vec<u32> = (0..b.chunks()).map(|c| b.quota(c).unwrap()).collect();
            assert_eq!(quotas.iter().sum::<u32>(), target, "{b:?}");
            for (c, (r, q)) in ranges.iter().zip(&quotas).enumerate() {
                assert!(r.len() as u32 >= *q, "{b:?}: chunk {c} has {} trials for a quota of {q}", r.len());
                assert!(r.len() as u32 <= b.max_task_trials(), "{b:?}");
                for g in r.clone() {
                    assert_eq!(b.chunk_of(g), c as u32, "{b:?}: trial {g}");
                }
            }
        }
    }
}
