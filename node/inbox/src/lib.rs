//! zmotor-inbox: an ordered hand-off of inputs to one state that several threads feed (an
//! axis, fed by Zenoh's callback threads, by other axes of its node and by its own task).
//!
//! An input is handled at once on the thread that brings it when nobody is handling the state
//! (no hop to another thread before the first publication goes out), and otherwise queued for
//! the thread that is, which handles it before it lets go. So inputs are handled one at a
//! time, in the order they were delivered (an input delivered after another, on any thread, is
//! handled after it), and no thread ever waits for another's handling: a state whose handling
//! delivers to itself, or two that deliver to each other, cannot deadlock.
//!
//! The order is checked by loom over every interleaving of three threads
//! (`cargo test -p zmotor-inbox --features loom --release --test loom`), beside the hand-off
//! zmotor used before, which loom shows reordering.

use std::collections::VecDeque;

#[cfg(feature = "loom")]
use loom::sync::Mutex;
#[cfg(not(feature = "loom"))]
use std::sync::Mutex;

/// What handles the inputs of an inbox.
pub trait Handler<I> {
    /// Handle one input.
    fn handle(&mut self, input: I);
}

/// A state and the inputs waiting for it.
pub struct Inbox<S, I> {
    state: Mutex<S>,
    pending: Mutex<Pending<I>>,
}

/// The inputs not handled yet, and whether a thread is handling.
struct Pending<I> {
    inputs: VecDeque<I>,
    /// A thread is handling: it takes every input queued before it lets go.
    handling: bool,
}

impl<S: Handler<I>, I> Inbox<S, I> {
    /// An inbox in front of `state`.
    pub fn new(state: S) -> Self {
        let pending = Pending { inputs: VecDeque::new(), handling: false };
        Self { state: Mutex::new(state), pending: Mutex::new(pending) }
    }

    /// Hand `input` to the state: handled now on this thread if nobody is handling, queued for
    /// the thread that is otherwise.
    pub fn deliver(&self, input: I) {
        {
            let mut pending = lock(&self.pending);
            pending.inputs.push_back(input);
            if pending.handling {
                return;
            }
            pending.handling = true;
        }
        // This thread handles until the queue is empty. Should a handler panic, the guard lets
        // go, and whoever delivers next takes the queue over, in order.
        let guard = Handling(&self.pending);
        loop {
            let next = {
                let mut pending = lock(&self.pending);
                match pending.inputs.pop_front() {
                    Some(input) => input,
                    None => {
                        pending.handling = false;
                        std::mem::forget(guard);
                        return;
                    }
                }
            };
            lock(&self.state).handle(next);
        }
    }

    /// Look at the state between two inputs (this waits while one is being handled).
    pub fn inspect<R>(&self, look: impl FnOnce(&S) -> R) -> R {
        look(&lock(&self.state))
    }
}

/// Lets go of the handling if the handler panics.
struct Handling<'p, I>(&'p Mutex<Pending<I>>);

impl<I> Drop for Handling<'_, I> {
    fn drop(&mut self) {
        lock(self.0).handling = false;
    }
}

/// A lock, also after a handler panicked holding it (the state is still the best there is).
#[cfg(not(feature = "loom"))]
fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

#[cfg(feature = "loom")]
fn lock<T>(mutex: &Mutex<T>) -> loom::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

#[cfg(all(test, not(feature = "loom")))]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// Inputs (sender, sequence number) as they were handled; a handler that delivers to its
    /// own inbox on some inputs.
    #[derive(Default)]
    struct Log {
        handled: Vec<(usize, u32)>,
    }

    impl Handler<(usize, u32)> for Log {
        fn handle(&mut self, input: (usize, u32)) {
            self.handled.push(input);
        }
    }

    #[test]
    fn inputs_from_many_threads_are_each_handled_once_and_in_each_threads_order() {
        const THREADS: usize = 4;
        const EACH: u32 = 20_000;
        let inbox = Arc::new(Inbox::new(Log::default()));
        let senders: Vec<_> = (0..THREADS)
            .map(|sender| {
                let inbox = inbox.clone();
                std::thread::spawn(move || (0..EACH).for_each(|n| inbox.deliver((sender, n))))
            })
            .collect();
        senders.into_iter().for_each(|s| s.join().unwrap());
        let handled = inbox.inspect(|log| log.handled.clone());
        assert_eq!(handled.len(), THREADS * EACH as usize, "each input handled once");
        for sender in 0..THREADS {
            let order: Vec<u32> = handled.iter().filter(|(s, _)| *s == sender).map(|(_, n)| *n).collect();
            assert!(order.windows(2).all(|w| w[0] + 1 == w[1]), "sender {sender}'s inputs in order");
        }
    }

    /// A state that, handling an input, delivers the next one to itself (an axis writing to its
    /// own field through a link).
    struct Echo {
        inbox: std::sync::Weak<Inbox<Echo, u32>>,
        handled: Vec<u32>,
    }

    impl Handler<u32> for Echo {
        fn handle(&mut self, input: u32) {
            self.handled.push(input);
            if input < 100 {
                self.inbox.upgrade().unwrap().deliver(input + 1);
            }
        }
    }

    #[test]
    fn a_state_that_delivers_to_itself_does_not_deadlock() {
        let inbox = Arc::new_cyclic(|weak| Inbox::new(Echo { inbox: weak.clone(), handled: Vec::new() }));
        inbox.deliver(0);
        assert_eq!(inbox.inspect(|echo| echo.handled.clone()), (0..=100).collect::<Vec<_>>());
    }
}
