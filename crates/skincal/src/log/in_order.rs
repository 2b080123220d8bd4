//! Work handed to a thread pool as it comes and taken back in the order it was given: what the
//! readers use to decompress or parse a log's blocks while they read the next ones.

use std::collections::VecDeque;
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::OnceLock;

/// Results of work on the thread pool, oldest first.
pub(crate) struct InOrder<T> {
    pending: VecDeque<Receiver<std::thread::Result<T>>>,
}

impl<T: Send + 'static> InOrder<T> {
    pub(crate) fn new() -> Self {
        InOrder {
            pending: VecDeque::new(),
        }
    }

    /// Work given and not yet taken back.
    pub(crate) fn len(&self) -> usize {
        self.pending.len()
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Runs `work` on the readers' thread pool, after the work given before it.
    pub(crate) fn spawn(&mut self, work: impl FnOnce() -> T + Send + 'static) {
        let (done, result) = sync_channel(1);
        pool().spawn_fifo(move || {
            // A panic is this work's outcome, not the end of the process.
            let _ = done.send(std::panic::catch_unwind(std::panic::AssertUnwindSafe(work)));
        });
        self.pending.push_back(result);
    }

    /// The result of the oldest work, once it is done; `None` when none is pending, `Some(Err)`
    /// when it panicked.
    pub(crate) fn next(&mut self) -> Option<Result<T, Panicked>> {
        let result = self.pending.pop_front()?;
        Some(
            result
                .recv()
                .map_err(|_| Panicked)
                .and_then(|r| r.map_err(|_| Panicked)),
        )
    }
}

/// The readers' own pool, one thread per core. Its work never waits for anything, so a log can be
/// read from any thread: a reader on a worker of rayon's global pool (a caller's parallel loop
/// over logs) would otherwise wait for work that no free worker is left to run.
fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .thread_name(|i| format!("skincal-log-{i}"))
            .build()
            .expect("threads for reading logs")
    })
}

/// Work on the thread pool that stopped with a panic.
#[derive(Debug)]
pub(crate) struct Panicked;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_back_in_the_order_given_whatever_order_they_finish_in() {
        let mut work = InOrder::new();
        for i in 0..16u64 {
            // The first ones take longest.
            work.spawn(move || {
                std::thread::sleep(std::time::Duration::from_millis(16 - i));
                i
            });
        }
        work.spawn(|| panic!("a damaged block"));
        let mut got = Vec::new();
        while let Some(r) = work.next() {
            got.push(r.ok());
        }
        let mut expected: Vec<Option<u64>> = (0..16).map(Some).collect();
        expected.push(None);
        assert_eq!(got, expected);
        assert_eq!(work.len(), 0);
    }
}
