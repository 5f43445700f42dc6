//! The liveliness tokens that held motions depend on (the jog deadman, "hold to move"): one
//! liveliness subscriber per token an axis watches; a token that goes, or that is not there
//! shortly after the write that named it, is reported so the axis ends what it held.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};
use zenoh::pubsub::Subscriber;
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

/// How long a token named by a write may take to be seen; one not seen by then is taken as
/// gone (its client named a token it does not hold, or vanished at once).
const FIRST_SIGHT: Duration = Duration::from_millis(500);

/// The tokens one axis watches.
pub(crate) struct Holds {
    session: Session,
    runtime: tokio::runtime::Handle,
    released: UnboundedSender<String>,
    watched: HashMap<String, Subscriber<()>>,
}

impl Holds {
    /// Watching nothing yet; released tokens arrive on the receiver.
    pub(crate) fn new(session: &Session, runtime: tokio::runtime::Handle) -> (Self, UnboundedReceiver<String>) {
        let (released, receiver) = unbounded_channel();
        (Self { session: session.clone(), runtime, released, watched: HashMap::new() }, receiver)
    }

    /// Watch `token` (already watched: nothing to do).
    pub(crate) fn watch(&mut self, token: &str) {
        if self.watched.contains_key(token) {
            return;
        }
        let seen = Arc::new(AtomicBool::new(false));
        let (released, name, seen_here) = (self.released.clone(), token.to_string(), seen.clone());
        let subscriber = self.session.liveliness().declare_subscriber(token).history(true).callback(move |sample| {
            match sample.kind() {
                SampleKind::Put => seen_here.store(true, Ordering::Release),
                SampleKind::Delete => {
                    let _ = released.send(name.clone());
                }
            }
        });
        match subscriber.wait() {
            Ok(subscriber) => {
                self.watched.insert(token.to_string(), subscriber);
            }
            Err(e) => {
                // A hold that cannot be watched holds nothing: end it now rather than never.
                tracing::error!(token, "cannot watch the hold's token: {e}");
                let _ = self.released.send(token.to_string());
                return;
            }
        }
        let (released, name) = (self.released.clone(), token.to_string());
        self.runtime.spawn(async move {
            tokio::time::sleep(FIRST_SIGHT).await;
            if !seen.load(Ordering::Acquire) {
                tracing::warn!(token = %name, "the hold's token is not there: what it held ends");
                let _ = released.send(name);
            }
        });
    }

    /// Stop watching `token`.
    pub(crate) fn forget(&mut self, token: &str) {
        self.watched.remove(token);
    }
}
