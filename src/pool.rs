//! Running a stage's work on rayon's pool.
//!
//! A thread outside the pool that starts a parallel loop hands it to the pool's threads and
//! sleeps until they are done, and they sleep again after it: a stage made of several loops
//! (a frame's instances, sphere lists, tiles and shading) pays that hand-over for each. Run
//! on one of the pool's own threads, the stage's serial parts run there and each loop only
//! splits off work for the others (docs/benchmarks.md, step 75).

/// Runs `work` on a thread of rayon's pool (where it is already, directly), with the calling
/// thread's memory budget ([`crate::memory::with_budget`]).
#[cfg(feature = "parallel")]
pub(crate) fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        return work();
    }
    let budget = crate::memory::thread_budget();
    rayon::scope(|_| crate::memory::with_budget(budget, work))
}

/// Runs `work` (without the `parallel` feature there is no pool).
#[cfg(not(feature = "parallel"))]
pub(crate) fn on_pool<R>(work: impl FnOnce() -> R) -> R {
    work()
}

#[cfg(all(test, feature = "parallel"))]
mod tests {
    use super::*;

    /// Work handed to the pool runs on one of its threads, under the caller's own memory
    /// budget (a job's limit must hold for the frames it renders there). (Work started on the
    /// pool runs where it is: no test can tell that from `rayon::scope`, which runs it there
    /// too, so none claims to.)
    #[test]
    fn work_on_the_pool_keeps_the_callers_budget() {
        assert!(rayon::current_thread_index().is_none(), "a test runs outside the pool");
        let (budget, on) = crate::memory::with_budget(123_456, || {
            on_pool(|| (crate::memory::budget(), rayon::current_thread_index().is_some()))
        });
        assert_eq!((budget, on), (123_456, true));
    }
}
