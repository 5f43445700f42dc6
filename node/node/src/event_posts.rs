//! The posts that must arrive (`Delivery::Event`, refusals on ERR, the node's writes), and the
//! answers to writes: sent from a thread of their own with congestion control Block, so a slow
//! link makes them wait, never drops them; the tick workers only hand them over, and never wait
//! for a link. A write's answer goes behind its axis's posts, so a writer that follows the fields
//! finds what the write did once it has the answer (a Channel Access read after a put-callback). Each is sent (a null move's DMOV 0
//! and 1 are two samples). An axis's stream samples queue behind its events while any wait on a
//! congested link (an axis's posts arrive in order; once the congestion has passed, the axis
//! holds them back instead); while one waits, its key's next replaces it (a slow link gets
//! each readback's last value, as a Channel Access server's queue does for a slow client).

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use zenoh::bytes::{Encoding, ZBytes};
use zenoh::key_expr::KeyExpr;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::Locality;
use zenoh::time::Timestamp;
use zenoh::{Session, Wait};

use crate::streamed::Congestion;

/// One sample: an axis's post (marked, stamped, for other sessions) or a write.
pub(crate) struct EventPost {
    pub(crate) key: KeyExpr<'static>,
    pub(crate) payload: Vec<u8>,
    pub(crate) encoding: Encoding,
    pub(crate) attachment: Option<Vec<u8>>,
    pub(crate) stamp: Option<Timestamp>,
    pub(crate) destination: Destination,
    /// A stream sample, which its key's next stream sample replaces while it waits.
    pub(crate) replaceable: bool,
    /// The posts of its axis not sent yet, this one among them.
    pub(crate) waiting: Arc<AtomicUsize>,
}

/// Where a sample goes.
pub(crate) enum Destination {
    /// Put on its key, to these sessions.
    Network(Locality),
    /// The answer to a query.
    Answer(Query),
    /// A query's refusal (an error reply).
    Refusal(Query),
}

/// The posts a round keeps room for once sent (a thousand axes' events of a poll).
const ROUND_ROOM: usize = 1024;

#[derive(Default)]
struct Pending {
    /// In the order they were posted; `None` where a stream sample was replaced.
    posts: Vec<Option<EventPost>>,
    /// Where each key's waiting stream sample is in `posts`.
    at: HashMap<KeyExpr<'static>, usize>,
    /// The sender waits for posts: the next post must wake it (a wake is a system call; a
    /// sender at work takes every queued post on its next round without one).
    sender_waits: bool,
    closing: bool,
}

#[derive(Default)]
struct Shared {
    pending: Mutex<Pending>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Pending> {
        self.pending.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// The node's sender of posts that must arrive.
pub(crate) struct EventPosts {
    outbox: EventOutbox,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl EventPosts {
    pub(crate) fn start(session: Session, congestion: Arc<Congestion>) -> std::io::Result<Self> {
        let shared = Arc::new(Shared::default());
        let outbox = EventOutbox { shared: shared.clone(), session, congestion };
        let sender = outbox.clone();
        let thread = std::thread::Builder::new().name("zmotor-events".into()).spawn(move || sender.send_queued())?;
        Ok(Self { outbox, thread: Some(thread) })
    }

    /// Where the axes hand their posts.
    pub(crate) fn outbox(&self) -> EventOutbox {
        self.outbox.clone()
    }

    /// Send what waits, then stop (blocks until sent: at most Zenoh's wait before it closes a
    /// congested link for each).
    pub(crate) fn finish(mut self) {
        self.close();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }

    fn close(&self) {
        self.outbox.shared.lock().closing = true;
        self.outbox.shared.wake.notify_one();
    }
}

impl Drop for EventPosts {
    fn drop(&mut self) {
        self.close();
    }
}

/// Hands posts to the node's event sender.
#[derive(Clone)]
pub(crate) struct EventOutbox {
    shared: Arc<Shared>,
    session: Session,
    congestion: Arc<Congestion>,
}

impl EventOutbox {
    /// Send `post` now, on this thread, if no link was seen congested lately and its axis has
    /// nothing waiting (a put then finds room at once: a hand-over would cost every event tens
    /// of microseconds); queue it for the sender thread otherwise.
    pub(crate) fn post(&self, post: EventPost) {
        self.post_at(post, std::time::Instant::now());
    }

    /// `post`, the clock read just before at `start`; returns the clock as read after a put, none
    /// after a post queued (the queue's lock may have waited on the sender: not read, not known).
    pub(crate) fn post_at(&self, post: EventPost, start: std::time::Instant) -> Option<std::time::Instant> {
        if post.waiting.load(Ordering::Acquire) == 0 && !self.congestion.recent_at(self.congestion.at(start)) {
            Some(self.congestion.timed(start, || self.put(post)))
        } else {
            self.shared.queue(post);
            None
        }
    }

    /// The sender thread: take what waits, send it in order, until closed and empty. The queue
    /// and the round being sent swap places, so neither grows again from nothing each round.
    fn send_queued(&self) {
        let mut posts = Vec::new();
        loop {
            {
                let mut pending = self.shared.lock();
                if pending.posts.is_empty() {
                    // Nothing left to send: the room a backlog (a stalled link, a starved node)
                    // made goes back. (Not between rounds: while rounds stay large, each would
                    // allocate it anew.)
                    posts.shrink_to(ROUND_ROOM);
                    pending.posts.shrink_to(ROUND_ROOM);
                    pending.at.shrink_to(ROUND_ROOM);
                }
                while pending.posts.is_empty() && !pending.closing {
                    pending.sender_waits = true;
                    pending = self.shared.wake.wait(pending).unwrap_or_else(PoisonError::into_inner);
                }
                pending.sender_waits = false;
                if pending.posts.is_empty() {
                    return;
                }
                pending.at.clear();
                std::mem::swap(&mut pending.posts, &mut posts);
            }
            for post in posts.drain(..).flatten() {
                let waiting = post.waiting.clone();
                self.congestion.sending(|| self.put(post));
                waiting.fetch_sub(1, Ordering::AcqRel);
            }
        }
    }

    fn put(&self, post: EventPost) {
        let sent = match post.destination {
            Destination::Network(locality) => self
                .session
                .put(post.key, post.payload)
                .encoding(post.encoding)
                .congestion_control(CongestionControl::Block)
                .allowed_destination(locality)
                .attachment(post.attachment.map(ZBytes::from))
                .timestamp(post.stamp)
                .wait(),
            Destination::Answer(query) => query
                .reply(post.key, post.payload)
                .encoding(post.encoding)
                .attachment(post.attachment.map(ZBytes::from))
                .timestamp(post.stamp)
                .wait(),
            Destination::Refusal(query) => query.reply_err(post.payload).encoding(post.encoding).wait(),
        };
        if let Err(e) = sent {
            tracing::warn!("an event post failed: {e}");
        }
    }
}

impl Shared {
    /// Queue `post`, replacing its key's stream sample not sent yet if it is one too.
    fn queue(&self, post: EventPost) {
        let mut pending = self.lock();
        let next = pending.posts.len();
        let replaced = match post.replaceable {
            true => pending.at.insert(post.key.clone(), next),
            false => None,
        };
        match replaced {
            // Its axis's count already holds the replaced post.
            Some(replaced) => pending.posts[replaced] = None,
            None => {
                post.waiting.fetch_add(1, Ordering::AcqRel);
            }
        }
        pending.posts.push(Some(post));
        let wake = std::mem::take(&mut pending.sender_waits);
        drop(pending);
        if wake {
            self.wake.notify_one();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zenoh::time::{TimestampId, NTP64};

    fn post(key: &str, payload: &str, replaceable: bool, waiting: &Arc<AtomicUsize>) -> EventPost {
        EventPost {
            key: KeyExpr::try_from(key.to_string()).unwrap(),
            payload: payload.as_bytes().to_vec(),
            encoding: Encoding::TEXT_PLAIN,
            attachment: None,
            stamp: Some(Timestamp::new(NTP64(0), TimestampId::rand())),
            destination: Destination::Network(Locality::Remote),
            replaceable,
            waiting: waiting.clone(),
        }
    }

    fn queued(shared: &Shared) -> Vec<(String, String)> {
        let pending = shared.lock();
        let posts = pending.posts.iter().flatten();
        posts.map(|p| (p.key.to_string(), String::from_utf8(p.payload.clone()).unwrap())).collect()
    }

    #[test]
    fn events_are_each_kept_in_order_and_a_waiting_stream_sample_gives_way_to_its_keys_next() {
        let (shared, waiting) = (Shared::default(), Arc::new(AtomicUsize::new(0)));
        shared.queue(post("m/DMOV", "0", false, &waiting));
        shared.queue(post("m/RBV", "1", true, &waiting));
        shared.queue(post("m/DMOV", "1", false, &waiting));
        shared.queue(post("m/RBV", "2", true, &waiting));
        shared.queue(post("m/ERR", "refused", false, &waiting));
        shared.queue(post("m/ERR", "refused again", false, &waiting));
        let expected =
            [("m/DMOV", "0"), ("m/DMOV", "1"), ("m/RBV", "2"), ("m/ERR", "refused"), ("m/ERR", "refused again")];
        let expected: Vec<(String, String)> = expected.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        assert_eq!(queued(&shared), expected);
        assert_eq!(waiting.load(Ordering::Acquire), 5, "the axis counts what it waits for, not what was replaced");
    }
}
