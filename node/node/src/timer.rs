//! Deadlines kept with the operating system's timer precision. Tokio's timer counts whole
//! milliseconds and rounds a deadline up, so a motion ending at t would be reported up to two
//! milliseconds late; this thread sleeps until the earliest deadline (the kernel's high-resolution
//! timer, tens of microseconds) and only wakes the task it belongs to, which does the work.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;
use tokio::sync::Notify;

/// One deadline: when, and whom to wake.
struct Entry {
    at: Instant,
    /// Breaks ties in arrival order.
    seq: u64,
    wake: Arc<Notify>,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.seq) == (other.at, other.seq)
    }
}

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.at, self.seq).cmp(&(other.at, other.seq))
    }
}

#[derive(Default)]
struct Queue {
    due: BinaryHeap<Reverse<Entry>>,
    seq: u64,
    stopped: bool,
}

/// The deadlines of a node's tasks and the thread that keeps them; the thread ends when the
/// last handle is dropped.
#[derive(Clone)]
pub(crate) struct Timer {
    shared: Arc<(Mutex<Queue>, Condvar)>,
    _owner: Arc<Stopper>,
}

/// Stops the thread when the last `Timer` goes.
struct Stopper(Arc<(Mutex<Queue>, Condvar)>);

impl Drop for Stopper {
    fn drop(&mut self) {
        let (queue, wakeup) = &*self.0;
        queue.lock().unwrap_or_else(|e| e.into_inner()).stopped = true;
        wakeup.notify_one();
    }
}

impl Timer {
    /// Start the thread.
    pub(crate) fn start() -> std::io::Result<Self> {
        let shared: Arc<(Mutex<Queue>, Condvar)> = Arc::default();
        let keeper = shared.clone();
        std::thread::Builder::new().name("zmotor-timer".into()).spawn(move || keep(&keeper))?;
        Ok(Self { _owner: Arc::new(Stopper(shared.clone())), shared })
    }

    /// Wake `wake` at `at` (at once if it has passed). A task schedules each deadline once;
    /// a wake-up for a deadline it no longer has is harmless: it looks and sleeps again.
    pub(crate) fn wake_at(&self, at: Instant, wake: Arc<Notify>) {
        let (queue, wakeup) = &*self.shared;
        let mut queue = queue.lock().unwrap_or_else(|e| e.into_inner());
        queue.seq += 1;
        let seq = queue.seq;
        let earliest = queue.due.peek().is_none_or(|Reverse(first)| at < first.at);
        queue.due.push(Reverse(Entry { at, seq, wake }));
        if earliest {
            wakeup.notify_one();
        }
    }
}

fn keep(shared: &(Mutex<Queue>, Condvar)) {
    let (queue, wakeup) = shared;
    let mut queue = queue.lock().unwrap_or_else(|e| e.into_inner());
    loop {
        if queue.stopped {
            return;
        }
        let now = Instant::now();
        while queue.due.peek().is_some_and(|Reverse(first)| first.at <= now) {
            if let Some(Reverse(entry)) = queue.due.pop() {
                entry.wake.notify_one();
            }
        }
        queue = match queue.due.peek().map(|Reverse(first)| first.at - now) {
            Some(wait) => wakeup.wait_timeout(queue, wait).unwrap_or_else(|e| e.into_inner()).0,
            None => wakeup.wait(queue).unwrap_or_else(|e| e.into_inner()),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_deadline_wakes_its_task_on_time_and_in_order() {
        let timer = Timer::start().unwrap();
        let (early, late) = (Arc::new(Notify::new()), Arc::new(Notify::new()));
        let start = Instant::now();
        timer.wake_at(start + Duration::from_millis(30), late.clone());
        timer.wake_at(start + Duration::from_millis(10), early.clone());
        early.notified().await;
        let first = start.elapsed();
        late.notified().await;
        let second = start.elapsed();
        assert!(first >= Duration::from_millis(10), "woken before its deadline: {first:?}");
        assert!(second >= Duration::from_millis(30), "woken before its deadline: {second:?}");
    }
}
