//! Running a frame's work on rayon's pool, with the pool's other threads kept awake.
//!
//! A thread outside the pool that starts a parallel loop hands it to the pool's threads and
//! sleeps until they are done, and they sleep again after it: a stage made of several loops
//! (a frame's instances, sphere lists, tiles and shading) pays that hand-over for each. Run
//! on one of the pool's own threads, the stage's serial parts run there and each loop only
//! splits off work for the others (docs/benchmarks.md, step 75). Between the loops those
//! others still fall asleep, and waking one took 67 µs on average on the 2-core host
//! (`perf sched latency`, a 10 000-car crowd: about six sleeps a frame); [`run_awake`] keeps them
//! taking work instead for as long as the frame runs (step 78).

#[cfg(feature = "parallel")]
use std::sync::atomic::{AtomicBool, Ordering};

/// How long a kept-awake thread looks for work without finding any before it gives up and
/// lets rayon put it to sleep: longer than a frame's serial stretches between its loops,
/// short enough that a thread kept waiting elsewhere (see [`keep_taking_work`]) soon
/// resumes.
#[cfg(feature = "parallel")]
const IDLE: std::time::Duration = std::time::Duration::from_micros(500);

#[cfg(feature = "parallel")]
thread_local! {
    /// Whether this thread is inside [`run_awake`]'s work or one of its waiting loops.
    static AWAKE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    /// The flag that stops the threads kept awake for the [`run_awake`] whose work runs on
    /// this thread (see [`rest`]).
    static STOP: std::cell::RefCell<Option<std::sync::Arc<AtomicBool>>> = const { std::cell::RefCell::new(None) };
}

/// Runs `work` — a frame's posing, transform update and render, say — on a thread of rayon's
/// pool (where it is already, directly; with the calling thread's memory budget,
/// [`crate::memory::with_budget`]) while the pool's other threads keep looking for work instead of
/// sleeping between its parallel loops: each loop's pieces are taken at once, not after a
/// wake-up. They spin (use a core each) until `work` returns, until it calls [`rest`] (a GPU
/// frame does after its submit, before it waits for the device), or after half a millisecond
/// without work. Within `run_awake` (or without the `parallel` feature) it just runs `work`.
///
/// A 10 000-car crowd's frame on two cores: 5–8 % faster than posing, updating and rendering
/// from the calling thread (docs/benchmarks.md, step 78); one car's frame alike. On the GPU
/// backend the host's part of such a frame (posing, update and the render up to its submit)
/// fell by about a quarter (step 87).
#[cfg(feature = "parallel")]
pub fn run_awake<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    if AWAKE.get() {
        return work();
    }
    let budget = crate::memory::thread_budget();
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let done = &*stop;
    rayon::scope(|s| {
        let driver = rayon::current_thread_index();
        for _ in 1..rayon::current_num_threads() {
            s.spawn(move |_| keep_taking_work(done, driver));
        }
        // Set however `work` ends (a panic included), so that the others stop.
        struct Done<'a>(&'a AtomicBool);
        impl Drop for Done<'_> {
            fn drop(&mut self) {
                self.0.store(true, Ordering::Release);
                AWAKE.set(false);
                STOP.set(None);
            }
        }
        let _done = Done(done);
        AWAKE.set(true);
        STOP.set(Some(std::sync::Arc::clone(&stop)));
        crate::memory::with_budget(budget, work)
    })
}

/// Runs `work` (without the `parallel` feature there is no pool).
#[cfg(not(feature = "parallel"))]
pub fn run_awake<R>(work: impl FnOnce() -> R) -> R {
    work()
}

/// Lets the threads kept awake for the enclosing [`run_awake`] sleep for the rest of its
/// work: for work about to wait on something else that needs the cores (a GPU frame after
/// its submit, whose driver may run on the CPU), where a spinning thread would only take a
/// core from it. Outside `run_awake` (or without the `parallel` feature) it does nothing.
#[cfg(feature = "parallel")]
pub fn rest() {
    STOP.with_borrow(|stop| {
        if let Some(stop) = stop {
            stop.store(true, Ordering::Release);
        }
    });
}

/// Does nothing: without the `parallel` feature no thread is kept awake.
#[cfg(not(feature = "parallel"))]
pub fn rest() {}

/// On one of the pool's threads: runs the pool's pending work, one piece at a time, until
/// `done` or until none has come for [`IDLE`]. A thread that picks this job up while it
/// waits inside other work must soon return to that work: so it returns at once on the
/// driving thread (`driver`, which may take it while it waits for a loop's pieces) and on
/// one already kept awake, and after [`IDLE`] elsewhere (rayon shows no thread what it is
/// running below).
#[cfg(feature = "parallel")]
fn keep_taking_work(done: &AtomicBool, driver: Option<usize>) {
    if rayon::current_thread_index() == driver || AWAKE.get() {
        return;
    }
    AWAKE.set(true);
    let mut idle = std::time::Instant::now();
    let mut polls = 0u32;
    while !done.load(Ordering::Acquire) {
        match rayon::yield_now() {
            Some(rayon::Yield::Executed) => polls = 0,
            _ => {
                // The clock is read once in 64 empty polls (each is a sweep of the queues).
                polls += 1;
                if polls == 1 {
                    idle = std::time::Instant::now();
                } else if polls % 64 == 0 && idle.elapsed() > IDLE {
                    break;
                }
                std::hint::spin_loop();
            }
        }
    }
    AWAKE.set(false);
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
            run_awake(|| (crate::memory::budget(), rayon::current_thread_index().is_some()))
        });
        assert_eq!((budget, on), (123_456, true));
    }

    /// The threads kept awake take the work's nested loops (the sums come out right) and stop
    /// when it ends, a panicking one included: the panic reaches the caller, the driving
    /// thread is no longer marked as inside `run_awake` (else later frames would run without
    /// the others kept awake), and the pool still works. Run under a watchdog: threads that
    /// never stopped would hang `run_awake`'s scope.
    #[test]
    fn kept_awake_threads_stop_with_the_work() {
        use rayon::prelude::*;
        let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().expect("a pool of four");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let result = pool.install(|| {
                let sums: Vec<u64> = (0..40u64)
                    .map(|round| {
                        run_awake(|| {
                            (0..2000u64)
                                .into_par_iter()
                                .map(|i| (0..i % 7).into_par_iter().map(|j| j + round).sum::<u64>())
                                .sum()
                        })
                    })
                    .collect();
                let panicked =
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_awake(|| panic!("the work fails"))));
                let after = run_awake(|| (0..1000u64).into_par_iter().sum::<u64>());
                (sums, panicked.is_err(), AWAKE.get(), after)
            });
            let _ = tx.send(result);
        });
        let (sums, panicked, still_marked, after) =
            rx.recv_timeout(std::time::Duration::from_secs(300)).expect("run_awake returned");
        let expected: Vec<u64> =
            (0..40u64).map(|r| (0..2000u64).map(|i| (0..i % 7).map(|j| j + r).sum::<u64>()).sum()).collect();
        assert_eq!(sums, expected);
        assert!(panicked && !still_marked);
        assert_eq!(after, 499_500);
    }

    /// [`rest`] raises the flag the kept-awake threads of the `run_awake` it is called in
    /// poll (the one that stops them when the work ends), and only that one: outside it
    /// there is none to raise. Whether the threads then leave is not timed here: on a loaded
    /// host they also leave whenever they are kept off a core for longer than [`IDLE`].
    #[test]
    fn resting_raises_the_kept_awake_threads_flag() {
        let flag = || STOP.with_borrow(|s| s.as_ref().map(|f| f.load(Ordering::Acquire)));
        // On a pool's thread, where `run_awake` runs its work and keeps its flag.
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().expect("a pool of two");
        let (during, ended, again) = pool.install(|| {
            let during = run_awake(|| {
                let before = flag();
                rest();
                (before, flag())
            });
            rest();
            (during, flag(), run_awake(flag))
        });
        assert_eq!(during, (Some(false), Some(true)));
        assert_eq!(ended, None, "a flag kept after the work ended");
        assert_eq!(again, Some(false), "the next work starts with its own flag down");
    }
}
