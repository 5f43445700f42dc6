//! Every interleaving of three threads, checked by loom
//! (`cargo test -p zmotor-inbox --features loom --release --test loom`): an axis's own task, a
//! Zenoh callback thread delivering two writes of one client, and another thread delivering
//! too. The inbox hands each thread's inputs over in the order it delivered them. The hand-off
//! zmotor used before (try the lock when nothing is queued, else queue for the axis's task)
//! does not: loom finds the interleaving where a newer write overtakes one already dequeued.
#![cfg(feature = "loom")]

use loom::sync::atomic::{AtomicUsize, Ordering};
use loom::sync::{Arc, Mutex};
use std::collections::VecDeque;
use zmotor_inbox::{Handler, Inbox};

/// Who sent an input, and its place in that sender's order.
type Input = (&'static str, u32);

#[derive(Default)]
struct Log(Vec<Input>);

impl Handler<Input> for Log {
    fn handle(&mut self, input: Input) {
        // Handling takes time (an axis publishes what a write changed): other threads run
        // meanwhile. loom switches threads only at such points.
        loom::thread::yield_now();
        self.0.push(input);
    }
}

/// Each sender's inputs were handled in the order it sent them.
fn assert_in_order(handled: &[Input]) {
    for sender in ["client", "other"] {
        let order: Vec<u32> = handled.iter().filter(|(s, _)| *s == sender).map(|(_, n)| *n).collect();
        assert!(order.windows(2).all(|w| w[0] < w[1]), "{sender}'s inputs out of order: {handled:?}");
    }
}

/// What both hand-offs are asked to do.
trait HandOff: Send + Sync + 'static {
    fn deliver(&self, input: Input);
    /// The axis task's turn: handle what is queued for it, if anything.
    fn task_turn(&self);
    fn handled(&self) -> Vec<Input>;
}

impl HandOff for Inbox<Log, Input> {
    fn deliver(&self, input: Input) {
        Inbox::deliver(self, input);
    }

    fn task_turn(&self) {
        // The task's own inputs (a tick) go through the inbox like any other.
        Inbox::deliver(self, ("task", 0));
    }

    fn handled(&self) -> Vec<Input> {
        self.inspect(|log| log.0.clone())
    }
}

/// The hand-off zmotor-zenoh's `AxisHandle` made before: a callback handles the input at once
/// when nothing is queued and the lock is free, else queues it; the task dequeues, counts the
/// queue down, then takes the lock.
#[derive(Default)]
struct OldHandOff {
    core: Mutex<Log>,
    queue: Mutex<VecDeque<Input>>,
    queued: AtomicUsize,
}

impl HandOff for OldHandOff {
    fn deliver(&self, input: Input) {
        if self.queued.load(Ordering::Acquire) == 0 {
            if let Ok(mut core) = self.core.try_lock() {
                core.handle(input);
                return;
            }
        }
        self.queued.fetch_add(1, Ordering::AcqRel);
        self.queue.lock().unwrap().push_back(input);
    }

    fn task_turn(&self) {
        let next = self.queue.lock().unwrap().pop_front();
        if let Some(input) = next {
            self.queued.fetch_sub(1, Ordering::AcqRel);
            self.core.lock().unwrap().handle(input);
        }
    }

    fn handled(&self) -> Vec<Input> {
        // What is still queued is handled after everything else, as the task would.
        let rest: Vec<Input> = self.queue.lock().unwrap().drain(..).collect();
        let mut handled = self.core.lock().unwrap().0.clone();
        handled.extend(rest);
        handled
    }
}

fn three_threads<H: HandOff>(make: fn() -> H) {
    loom::model(move || {
        let handoff = Arc::new(make());
        let client = {
            let handoff = handoff.clone();
            loom::thread::spawn(move || {
                handoff.deliver(("client", 1));
                handoff.deliver(("client", 2));
            })
        };
        let task = {
            let handoff = handoff.clone();
            loom::thread::spawn(move || handoff.task_turn())
        };
        handoff.deliver(("other", 1));
        client.join().unwrap();
        task.join().unwrap();
        let handled = handoff.handled();
        assert_eq!(handled.iter().filter(|(s, _)| *s != "task").count(), 3, "every input handled once");
        assert_in_order(&handled);
    });
}

#[test]
fn the_inbox_keeps_each_senders_order_in_every_interleaving() {
    three_threads(|| Inbox::new(Log::default()));
}

#[test]
#[should_panic(expected = "client's inputs out of order")]
fn the_old_hand_off_lets_a_newer_write_overtake_a_dequeued_one() {
    three_threads(OldHandOff::default);
}
