//! Threads for a world's step, with results that do not depend on their number.
//!
//! A [`Threads`] holds a `rayon` pool of a chosen size (none for one thread). A world runs each
//! step inside its pool; code that can use several threads asks [`in_pool`] and otherwise
//! runs on the calling thread, so nothing uses the machine's cores unless a world (or the
//! plugin) was given them. Work is split so that no sum changes order with the thread
//! count: independent bodies step in parallel (each body's step is the same sequential
//! computation on any thread), and data-parallel loops use a fixed partition whose parts are
//! combined in part order. Results are bit-identical for every thread count; tests compare
//! the world's `state_hash` across counts.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Threads a new world starts with (0: every available core).
static DEFAULT_THREADS: AtomicUsize = AtomicUsize::new(0);

/// Sets the thread count new worlds start with (0, the initial value: every available core).
/// Worlds already built keep theirs (`SoftTissueWorld::set_threads` changes one).
pub fn set_default_threads(count: usize) {
    DEFAULT_THREADS.store(count, Ordering::Relaxed);
}

/// The thread count new worlds start with (0: every available core).
pub fn default_threads() -> usize {
    DEFAULT_THREADS.load(Ordering::Relaxed)
}

/// The cores this process may use (1 when unknown).
pub fn available_cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Whether the caller runs inside a pool of more than one thread (the only case where the
/// core splits work).
pub fn in_pool() -> bool {
    rayon::current_thread_index().is_some()
        && rayon::current_num_threads() > 1
        && !SEQUENTIAL.with(|s| s.get())
}

thread_local! {
    /// Set while [`sequential`] runs its work on this thread.
    static SEQUENTIAL: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` on the calling thread without splitting its work, even inside a pool: long work
/// given one of a pool's threads (a cut's preparation) leaves the others to the steps.
pub fn sequential<R>(f: impl FnOnce() -> R) -> R {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            SEQUENTIAL.with(|s| s.set(self.0));
        }
    }
    let _restore = Restore(SEQUENTIAL.with(|s| s.replace(true)));
    f()
}

/// A thread pool for world steps, or none (one thread: the caller's).
#[derive(Clone)]
pub struct Threads {
    pool: Option<Arc<rayon::ThreadPool>>,
    count: usize,
    /// Pool threads lent to long work beside the steps (a cut's preparation).
    lent: Arc<AtomicUsize>,
    /// Jobs ever lent a thread.
    lends: Arc<AtomicUsize>,
}

impl std::fmt::Debug for Threads {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Threads")
            .field("count", &self.count)
            .finish()
    }
}

/// A thread pool could not be started.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("could not start a pool of {threads} threads: {message}")]
pub struct ThreadsError {
    /// Threads asked for.
    pub threads: usize,
    /// What the system said.
    pub message: String,
}

impl Default for Threads {
    /// One thread (the caller's).
    fn default() -> Self {
        Threads::single()
    }
}

impl Threads {
    /// One thread: the caller's; no pool.
    pub fn single() -> Self {
        Threads {
            pool: None,
            count: 1,
            lent: Arc::new(AtomicUsize::new(0)),
            lends: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// `count` threads; 0 means every available core.
    pub fn new(count: usize) -> Result<Self, ThreadsError> {
        let count = if count == 0 { available_cores() } else { count };
        if count == 1 {
            return Ok(Threads::single());
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(count)
            .thread_name(|i| format!("soft-tissue-{i}"))
            .build()
            .map_err(|e| ThreadsError {
                threads: count,
                message: e.to_string(),
            })?;
        Ok(Threads {
            pool: Some(Arc::new(pool)),
            count,
            lent: Arc::new(AtomicUsize::new(0)),
            lends: Arc::new(AtomicUsize::new(0)),
        })
    }

    /// Number of threads.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Runs `job` on one of the pool's threads, beside the steps, if the pool has a thread
    /// to spare (at most `count - 1` are lent at once, so the steps keep one); `job` is
    /// given back otherwise. The job runs [`sequential`]ly: it does not split its work over
    /// the threads the steps use.
    pub fn lend<F: FnOnce() + Send + 'static>(&self, job: F) -> Result<(), F> {
        let Some(pool) = &self.pool else {
            return Err(job);
        };
        let limit = self.count - 1;
        if self
            .lent
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < limit).then_some(n + 1)
            })
            .is_err()
        {
            return Err(job);
        }
        self.lends.fetch_add(1, Ordering::AcqRel);
        let lent = self.lent.clone();
        pool.spawn(move || {
            struct Return(Arc<AtomicUsize>);
            impl Drop for Return {
                fn drop(&mut self) {
                    self.0.fetch_sub(1, Ordering::AcqRel);
                }
            }
            let _back = Return(lent);
            // A panic must not reach the pool (it would abort the process).
            if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| sequential(job))).is_err() {
                log::warn!("work lent a pool thread failed");
            }
        });
        Ok(())
    }

    /// Pool threads lent by [`Threads::lend`] now.
    pub fn lent(&self) -> usize {
        self.lent.load(Ordering::Acquire)
    }

    /// Jobs [`Threads::lend`] has lent a thread so far.
    pub fn lends(&self) -> usize {
        self.lends.load(Ordering::Acquire)
    }

    /// Runs `f` in the pool (on the calling thread without one).
    pub fn run<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        match &self.pool {
            Some(pool) => pool.install(f),
            None => f(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_thread_has_no_pool_and_runs_on_the_caller() {
        let t = Threads::new(1).unwrap();
        assert_eq!(t.count(), 1);
        let caller = std::thread::current().id();
        assert_eq!(t.run(|| std::thread::current().id()), caller);
        assert!(!t.run(in_pool));
    }

    #[test]
    fn a_pool_of_two_is_seen_inside_only() {
        let t = Threads::new(2).unwrap();
        assert_eq!(t.count(), 2);
        assert!(t.run(in_pool));
        assert!(!in_pool());
        assert_eq!(Threads::new(0).unwrap().count(), available_cores());
    }

    #[test]
    fn sequential_work_does_not_split_inside_a_pool() {
        let t = Threads::new(2).unwrap();
        assert_eq!(t.run(|| (sequential(in_pool), in_pool())), (false, true));
    }
}
