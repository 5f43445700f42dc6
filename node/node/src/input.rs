//! What reaches one axis, from the network, from this node itself, or from its own task; and
//! how an axis is reached.

use zenoh::query::Query;
use zmotor_core::{DeviceStatus, InputLink};
use zmotor_msgs::{Hold, MalformedHold, PayloadEncoding};

/// One input of an axis, handled in the order it was delivered (`zmotor_inbox::Inbox`).
pub(crate) enum AxisInput {
    /// A plain write to a field.
    Write(Written),
    /// A query on a field key, the axis's keys or a write key: a read or a confirmed write.
    Query(Query),
    /// A plain write to a simulator key.
    SimWrite(Written),
    /// A plain write to a key with wildcards that covers the axis: refused.
    WildcardWrite(String),
    /// A delete of one of the axis's keys (the key): refused, a delete is not a write.
    Deleted(String),
    /// A read of simulator keys.
    SimQuery(Query),
    /// What the axis's controller reported for its channel, after how many motion commands.
    ControllerStatus(DeviceStatus, u64),
    /// The axis's controller reported an error, or did not send a command: for ERR.
    ControllerMessage(String),
    /// The axis's own time came: a poll, the end of a motion, DLY.
    Tick,
    /// An input link's key took a value.
    LinkUpdate(InputLink, f64),
    /// An input link's key's value found: read when the link connected or its source came back,
    /// or the state a source that came back posted.
    LinkRead(InputLink, f64),
    /// An input link's source is gone (the node serving its axis stopped).
    LinkLost(InputLink),
    /// The liveliness token a held motion depends on went.
    HoldReleased(String),
    /// The node is shutting down, or the axis's controller reloads its script: a moving axis
    /// stops.
    StopMotion,
}

/// A plain write to one key of an axis: the field (or simulator setting) named, the payload.
pub(crate) struct Written {
    pub(crate) name: String,
    pub(crate) payload: Vec<u8>,
    pub(crate) encoding: PayloadEncoding,
    /// The hold its attachment names, if any (one that names no token is refused).
    pub(crate) hold: Option<Result<Hold, MalformedHold>>,
}

/// How an input reaches an axis: its inbox, whatever the axis holds behind it.
pub(crate) trait Deliver: Send + Sync {
    /// Hand `input` to the axis: handled now if the axis is free, queued in order otherwise.
    fn deliver(&self, input: AxisInput);
}
