//! A running job's progress counted once per watch interval, however many clients watch it.
//!
//! Counting a job's tasks reads every one of its rows (`Store::progress`), and each `WatchJob`
//! stream asks every `watch_interval`: a hundred clients watching a 10⁵-task job would make the
//! database count 10⁷ rows per interval. Here the first asker of an interval counts, the others
//! wait for that count and share it, so the cost grows with the jobs watched, not the watchers.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use vint_store::Progress;

type Slot = Arc<tokio::sync::Mutex<Option<(Instant, Progress)>>>;

pub struct SharedProgress {
    max_age: Duration,
    jobs: Mutex<HashMap<String, Slot>>,
}

impl SharedProgress {
    /// Shares a count for `max_age` after it was taken.
    pub fn new(max_age: Duration) -> SharedProgress {
        SharedProgress { max_age, jobs: Mutex::new(HashMap::new()) }
    }

    /// The job's progress as counted within `max_age`, or as `count` counts it now (once, for
    /// every concurrent asker).
    pub async fn get<E, Fut>(&self, job_id: &str, count: impl FnOnce() -> Fut) -> Result<Progress, E>
    where
        Fut: Future<Output = Result<Progress, E>>,
    {
        let slot = self.slot(job_id);
        let mut held = slot.lock().await;
        if let Some((at, p)) = held.as_ref()
            && at.elapsed() < self.max_age
        {
            return Ok(p.clone());
        }
        let p = count().await?;
        *held = Some((Instant::now(), p.clone()));
        Ok(p)
    }

    /// The job's slot; a new one drops the slots nobody is using whose count is stale, so the map
    /// holds only jobs watched within the last `max_age`.
    fn slot(&self, job_id: &str) -> Slot {
        let mut jobs = self.jobs.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(slot) = jobs.get(job_id) {
            return slot.clone();
        }
        let max_age = self.max_age;
        jobs.retain(|_, slot| {
            Arc::strong_count(slot) > 1
                || slot.try_lock().map(|s| s.as_ref().is_some_and(|(at, _)| at.elapsed() < max_age)).unwrap_or(true)
        });
        jobs.entry(job_id.to_string()).or_default().clone()
    }

    #[cfg(test)]
    fn jobs_held(&self) -> usize {
        self.jobs.lock().unwrap_or_else(PoisonError::into_inner).len()
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicU64, Ordering};

    use super::*;

    fn counted(n: u64) -> Progress {
        Progress { samples: n, ..Progress::default() }
    }

    #[tokio::test]
    async fn concurrent_watchers_of_one_job_share_one_count_per_interval() {
        let shared = Arc::new(SharedProgress::new(Duration::from_millis(200)));
        let counts = Arc::new(AtomicU64::new(0));
        let ask = |shared: Arc<SharedProgress>, counts: Arc<AtomicU64>, job: &'static str| async move {
            shared
                .get(job, || async {
                    let n = counts.fetch_add(1, Ordering::SeqCst) + 1;
                    tokio::time::sleep(Duration::from_millis(20)).await;
                    Ok::<_, ()>(counted(n))
                })
                .await
                .unwrap()
        };
        let watchers: Vec<_> = (0..50).map(|_| tokio::spawn(ask(shared.clone(), counts.clone(), "j1"))).collect();
        for w in watchers {
            assert_eq!(w.await.unwrap().samples, 1, "every watcher got the one count");
        }
        assert_eq!(counts.load(Ordering::SeqCst), 1);
        assert_eq!(ask(shared.clone(), counts.clone(), "j2").await.samples, 2, "another job is counted apart");
        tokio::time::sleep(Duration::from_millis(250)).await;
        assert_eq!(ask(shared.clone(), counts.clone(), "j1").await.samples, 3, "a stale count is taken again");
        tokio::time::sleep(Duration::from_millis(250)).await;
        ask(shared.clone(), counts.clone(), "j3").await;
        assert_eq!(shared.jobs_held(), 1, "slots of jobs nobody watches any more are dropped");
    }

    #[tokio::test]
    async fn a_failed_count_is_not_shared() {
        let shared = SharedProgress::new(Duration::from_secs(60));
        assert_eq!(shared.get("j", || async { Err::<Progress, _>("database down") }).await, Err("database down"));
        assert_eq!(shared.get("j", || async { Ok::<_, &str>(counted(7)) }).await.map(|p| p.samples), Ok(7));
    }
}
