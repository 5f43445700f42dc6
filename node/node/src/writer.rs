//! Plain writes this node makes to keys: link outputs, directives, calc results (and the values
//! of its bridge records, published as its state). The node's own
//! subscribers do not hear its session (so publishing costs it no delivery to itself), so a
//! write to one of its own axes is handed to that axis here, and put on the network for
//! everyone else, as a post that must arrive (`event_posts.rs`): a write is a command, never
//! dropped for a congested link.

use crate::event_posts::{Destination, EventOutbox, EventPost};
use crate::input::{AxisInput, Written};
use crate::routes::{Routes, Space};
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, OnceLock, Weak};
use zenoh::bytes::Encoding;
use zenoh::key_expr::KeyExpr;
use zenoh::sample::Locality;
use zmotor_msgs::{KeyLayout, PayloadEncoding, StateMarker};

/// The node's plain writes.
#[derive(Clone)]
pub(crate) struct Writer {
    outbox: EventOutbox,
    /// The writes handed to the outbox and not sent yet (they go out in order).
    waiting: Arc<AtomicUsize>,
    fields: Space,
    /// The node's axes, once its router exists; weak, as the axes hold this writer.
    local: Arc<OnceLock<Weak<Routes>>>,
}

impl Writer {
    pub(crate) fn new(outbox: EventOutbox, layout: &KeyLayout) -> Self {
        let (waiting, local) = (Arc::default(), Arc::default());
        Self { outbox, waiting, fields: Space::Fields(layout.clone()), local }
    }

    /// The node's axes are `routes` from now on.
    pub(crate) fn reach(&self, routes: &Arc<Routes>) {
        let _ = self.local.set(Arc::downgrade(routes));
    }

    /// Write `value` (text) to `key`.
    pub(crate) fn put(&self, key: &str, value: String) {
        if let Some(routes) = self.local.get().and_then(Weak::upgrade) {
            for (space, wrap) in
                [(&self.fields, AxisInput::Write as fn(Written) -> AxisInput), (&Space::Sim, AxisInput::SimWrite)]
            {
                if let Some((handle, name)) = space.target(&routes, key) {
                    let payload = value.as_bytes().to_vec();
                    handle.deliver(wrap(Written { name, payload, encoding: PayloadEncoding::Text, hold: None }));
                }
            }
        }
        self.send(key, value, None);
    }

    /// Publish `value` (text) on `key` as this node's state (a bridge record's value: `marker`),
    /// not a write: nothing of this node takes it as one.
    pub(crate) fn put_state(&self, key: &str, value: String, marker: &StateMarker) {
        self.send(key, value, Some(marker.encode()));
    }

    fn send(&self, key: &str, value: String, attachment: Option<Vec<u8>>) {
        let key = match KeyExpr::try_from(key.to_string()) {
            Ok(key) => key,
            Err(e) => return tracing::warn!(key, "put failed: {e}"),
        };
        self.outbox.post(EventPost {
            key,
            payload: value.into_bytes(),
            encoding: Encoding::TEXT_PLAIN,
            attachment,
            stamp: None,
            // The node's own value holders and links follow keys on its session too.
            destination: Destination::Network(Locality::Any),
            replaceable: false,
            waiting: self.waiting.clone(),
        });
    }
}
