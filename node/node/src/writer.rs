//! Plain writes this node makes to keys: link outputs, directives, calc results. The node's own
//! subscribers do not hear its session (so publishing costs it no delivery to itself), so a
//! write to one of its own axes is handed to that axis here, and put on the network for
//! everyone else.

use crate::input::{AxisInput, Written};
use crate::routes::{Routes, Space};
use std::sync::{Arc, OnceLock, Weak};
use zenoh::bytes::Encoding;
use zenoh::{Session, Wait};
use zmotor_msgs::{KeyLayout, PayloadEncoding};

/// The node's plain writes.
#[derive(Clone)]
pub(crate) struct Writer {
    session: Session,
    fields: Space,
    /// The node's axes, once its router exists; weak, as the axes hold this writer.
    local: Arc<OnceLock<Weak<Routes>>>,
}

impl Writer {
    pub(crate) fn new(session: &Session, layout: &KeyLayout) -> Self {
        Self { session: session.clone(), fields: Space::Fields(layout.clone()), local: Arc::default() }
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
        if let Err(e) = self.session.put(key, value).encoding(Encoding::TEXT_PLAIN).wait() {
            tracing::warn!(key, "put failed: {e}");
        }
    }
}
