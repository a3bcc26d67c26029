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

/// Runs `f(i)` for every `i` in `0..n`, each once, on the calling thread and the pool's
/// others: each thread takes pieces (runs of indices) from its share until none is left,
/// then from the others', and the caller then waits for the ones still running by
/// spinning, not by sleeping.
///
/// Rayon's loops end with the calling thread asleep on a latch whenever another thread
/// holds the last piece: the wake-up after it took 100–120 µs on the 2-core host, after
/// each of a sub-millisecond frame's loops (its tiles' last pieces came back at 255 µs of a
/// 375 µs trace pass: docs/benchmarks.md, step 116). Meant for a frame's loops of some tens
/// to a few thousand pieces of microseconds each; `f` may run loops of its own.
pub fn for_each_index(n: usize, f: impl Fn(usize) + Sync + Send) {
    for_each_index_with(n, || (), |_, i| f(i), |_| ());
}

/// [`for_each_index`] with a state of each thread's own: a thread that takes part makes one
/// with `init`, hands it to `f` with each index it runs, and gives it to `finish` when no
/// piece is left (a loop's counters summed per thread, not bumped in shared memory per
/// index; every thread's `finish` has run when this returns).
#[cfg(feature = "parallel")]
pub fn for_each_index_with<S>(
    n: usize,
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, usize) + Sync + Send,
    finish: impl Fn(S) + Sync + Send,
) {
    use std::sync::atomic::AtomicUsize;
    let threads = rayon::current_num_threads();
    if n <= 1 || threads == 1 {
        let mut state = init();
        (0..n).for_each(|i| f(&mut state, i));
        finish(state);
        return;
    }
    // Each thread owns an even share of the pieces (runs of consecutive indices) and takes
    // them from a counter of its own, on a cache line of its own; a thread whose share is
    // done takes the others' from their counters. A counter shared by every piece cost a
    // frame's loops a cache line moving between cores per piece, and big pieces left one
    // thread with the heavy tiles of a piece while the other waited.
    let slots = threads.min(n);
    let pieces = n.min(PIECES * slots);
    let next: Vec<Padded> = (0..slots).map(|k| Padded(AtomicUsize::new(k * pieces / slots))).collect();
    let finished = AtomicUsize::new(0);
    // Raised by a piece that panics: its indices never count as finished, and the caller
    // must not wait for them (the scope then hands the panic on).
    let failed = AtomicBool::new(false);
    struct Failed<'a>(&'a AtomicBool);
    impl Drop for Failed<'_> {
        fn drop(&mut self) {
            if std::thread::panicking() {
                self.0.store(true, Ordering::Release);
            }
        }
    }
    let take = |slot: usize| {
        let _failed = Failed(&failed);
        let (mut done, mut state) = (0, None);
        for k in (0..slots).map(|j| (slot + j) % slots) {
            let end = (k + 1) * pieces / slots;
            loop {
                let p = next[k].0.fetch_add(1, Ordering::Relaxed);
                if p >= end {
                    break;
                }
                let range = p * n / pieces..(p + 1) * n / pieces;
                done += range.len();
                let state = state.get_or_insert_with(&init);
                range.for_each(|i| f(state, i));
            }
        }
        if let Some(state) = state {
            finish(state);
        }
        finished.fetch_add(done, Ordering::Release);
    };
    let take = &take;
    rayon::in_place_scope(|s| {
        for slot in 1..slots {
            s.spawn(move |_| take(slot));
        }
        take(0);
        // Only pieces already running are left, each short: spin until they are done (a
        // helper job not yet started is run here by the scope's end, and finds nothing).
        while finished.load(Ordering::Acquire) < n && !failed.load(Ordering::Acquire) {
            std::hint::spin_loop();
        }
    });
}

/// Pieces per thread that [`for_each_index`] cuts a loop into, at most: the last piece
/// running bounds how long the other threads wait, and taking a piece is a locked add on
/// its counter, which waits for the thread's earlier stores to drain. With 1 024, a small
/// frame's loops over mostly idle tiles took a piece per tile, and 9 % of a 320×192 frame's
/// samples sat on those adds (docs/benchmarks.md, step 127).
#[cfg(feature = "parallel")]
const PIECES: usize = 256;

/// An atomic counter alone on its cache line (two lines: some cores fetch lines in pairs).
#[cfg(feature = "parallel")]
#[repr(align(128))]
struct Padded(std::sync::atomic::AtomicUsize);

/// [`for_each_index`] with a state of the loop's own (without the `parallel` feature there
/// is no pool: one state, one thread).
#[cfg(not(feature = "parallel"))]
pub fn for_each_index_with<S>(n: usize, init: impl Fn() -> S, f: impl Fn(&mut S, usize), finish: impl Fn(S)) {
    let mut state = init();
    (0..n).for_each(|i| f(&mut state, i));
    finish(state);
}

/// `f(0..n)` collected in order, computed as [`for_each_index`] runs them.
pub(crate) fn map_index<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    let mut out: Vec<T> = Vec::with_capacity(n);
    let cells = Disjoint::new(&mut out.spare_capacity_mut()[..n]);
    for_each_index(n, |i| {
        // SAFETY: index i is written by this call alone.
        unsafe { cells.at(i) }.write(f(i));
    });
    // SAFETY: every index below n was written (each ran once, all before `for_each_index`
    // returned; a panic in `f` leaves before this, leaking what was written).
    unsafe { out.set_len(n) };
    out
}

/// `f` of each of `items`, in order, run as [`for_each_index`] runs its indices: a loop over
/// pieces that each own a stretch of some buffer (a crowd's moved instances, a few thousand
/// at a time), which rayon's loops end asleep when another thread holds the last piece.
pub(crate) fn map_owned<T: Send, R: Send>(items: Vec<T>, f: impl Fn(T) -> R + Sync + Send) -> Vec<R> {
    let mut items: Vec<Option<T>> = items.into_iter().map(Some).collect();
    let cells = Disjoint::new(&mut items);
    map_index(cells.len, |i| {
        // SAFETY: index i is taken by this call alone.
        let item = unsafe { cells.at(i) }.take();
        // (Each index runs once: every item is there to take.)
        item.map(&f)
    })
    .into_iter()
    .flatten()
    .collect()
}

/// A slice shared out to parallel work items that each touch elements of their own only
/// (a frame's tiles: disjoint pixel rectangles of one row-major image, which no split of the
/// slice into contiguous pieces can hand out).
pub(crate) struct Disjoint<'a, T> {
    at: *mut T,
    len: usize,
    of: std::marker::PhantomData<&'a mut [T]>,
}

// SAFETY: sharing the pointer shares the elements (`T: Send`, each reached by one thread at a
// time); that no two threads reach one element is each caller's promise at `Disjoint::at`.
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    /// The elements of `of`, to be handed out one or a run at a time.
    pub(crate) fn new(of: &'a mut [T]) -> Disjoint<'a, T> {
        Disjoint { at: of.as_mut_ptr(), len: of.len(), of: std::marker::PhantomData }
    }

    /// Element `i`.
    ///
    /// # Safety
    /// While the reference lives, nothing else reaches element `i`.
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn at(&self, i: usize) -> &mut T {
        assert!(i < self.len, "index {i} past {}", self.len);
        // SAFETY: in bounds (above); exclusive by the caller's promise.
        unsafe { &mut *self.at.add(i) }
    }

    /// Elements `start..start + len`.
    ///
    /// # Safety
    /// While the slice lives, nothing else reaches those elements.
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn run(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start.checked_add(len).is_some_and(|end| end <= self.len), "{start}+{len} past {}", self.len);
        // SAFETY: in bounds (above); exclusive by the caller's promise.
        unsafe { std::slice::from_raw_parts_mut(self.at.add(start), len) }
    }
}

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

    /// `work`'s result, run on a pool of four from a thread of its own, or a failed test if
    /// it has not returned after five minutes (a thread left waiting or spinning).
    fn on_pool_of_four<R: Send + 'static>(work: impl FnOnce() -> R + Send + 'static, returned: &str) -> R {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().expect("a pool of four");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(pool.install(work));
        });
        rx.recv_timeout(std::time::Duration::from_secs(300)).expect(returned)
    }

    /// Every index of a loop runs once, for sizes around the pieces' count and with loops
    /// nested in its pieces (on a pool of four, under a watchdog: a lost piece would leave
    /// the caller spinning); `map_index` and `map_owned` keep the order.
    #[test]
    fn every_index_runs_once_and_maps_in_order() {
        use std::sync::atomic::AtomicU32;
        let loops = || {
            let mut wrong = Vec::new();
            for n in [0, 1, 2, 3, 255, 256, 257, 1000, 4099] {
                let counts: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
                for_each_index(n, |i| {
                    counts[i].fetch_add(1, Ordering::Relaxed);
                });
                if counts.iter().any(|c| c.load(Ordering::Relaxed) != 1) {
                    wrong.push(n);
                }
                // Each item also sums a loop of its own.
                let mapped = map_index(n, |i| i * i + map_index(i % 7, |j| j + 1).iter().sum::<usize>());
                let expected: Vec<usize> = (0..n).map(|i| i * i + (1..=i % 7).sum::<usize>()).collect();
                if mapped != expected {
                    wrong.push(n);
                }
                // Pieces that own stretches of a buffer: each written once, results in order.
                let mut buffer = vec![0usize; n];
                let pieces: Vec<(usize, &mut [usize])> = buffer.chunks_mut(3).enumerate().collect();
                let sums = map_owned(pieces, |(k, run)| {
                    run.iter_mut().enumerate().for_each(|(j, v)| *v += 3 * k + j + 1);
                    run.iter().sum::<usize>()
                });
                let expected: Vec<usize> =
                    (0..n).collect::<Vec<_>>().chunks(3).map(|c| c.iter().map(|i| i + 1).sum()).collect();
                if buffer != (1..=n).collect::<Vec<_>>() || sums != expected {
                    wrong.push(n);
                }
            }
            wrong
        };
        let wrong = on_pool_of_four(loops, "the loops returned");
        assert!(wrong.is_empty(), "loops of these sizes went wrong: {wrong:?}");
    }

    /// A piece that panics on another thread than the caller's hands its panic to the
    /// caller, which must not wait for the indices it never finished (under a watchdog).
    #[test]
    fn a_panicking_piece_reaches_the_caller() {
        let run = || {
            let driver = rayon::current_thread_index();
            std::panic::catch_unwind(|| {
                for_each_index(4000, |_| {
                    if rayon::current_thread_index() != driver {
                        panic!("a helper's piece fails");
                    }
                    std::thread::sleep(std::time::Duration::from_micros(10));
                })
            })
            .is_err()
        };
        let panicked = on_pool_of_four(run, "the loop returned");
        assert!(panicked, "the helper's panic was lost");
    }

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
        let run = || {
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
        };
        let (sums, panicked, still_marked, after) = on_pool_of_four(run, "run_awake returned");
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
