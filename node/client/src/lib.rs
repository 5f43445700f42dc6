//! zmotor-client: what every client of zmotor axes does, over Zenoh. Sessions from a
//! configuration; the one confirmed write everyone sends, with its typed outcome (the value, a
//! completion, a refusal, the node vanished, no answer); reads, monitors that start with the
//! current values as camonitor's do, and the live axes at a glance; values shown as caget
//! shows them. The command line, the Channel Access gateway and the web screens are built on
//! it; a node is not.

mod monitor;
mod read;
mod session;
mod show;
mod summary;
mod write;

pub use monitor::{Event, Monitor, Update};
pub use read::{AxisReading, Reading, Selection};
pub use session::{free_local_endpoint, interrupted, open, open_waiting, zenoh_config, ConfigError, SessionError};
pub use show::show;
pub use summary::AxisSummary;
pub use write::{NoAnswer, SentWrite, WriteOptions, WriteOutcome};

use zenoh::bytes::Encoding;
use zenoh::liveliness::LivelinessToken;
use zenoh::query::ReplyError;
use zenoh::Session;
use zmotor_deploy::ZenohConfig;
use zmotor_msgs::{Field, KeyLayout, Refusal};

/// A client of the axes under one key prefix, on a Zenoh session.
#[derive(Clone)]
pub struct Client {
    session: Session,
    layout: KeyLayout,
}

/// A liveliness token in an axis's hold space: what a client holds its motions by (the jog
/// deadman). The motions it holds end when it is dropped, or when its holder dies.
pub struct HoldToken {
    key: String,
    _token: LivelinessToken,
}

impl HoldToken {
    /// The token's key, which a held write names.
    pub fn key(&self) -> &str {
        &self.key
    }
}

impl Client {
    /// A client session joined as `section` says, of the axes under its prefix.
    pub async fn connect(section: &ZenohConfig) -> Result<Self, SessionError> {
        Ok(Self::new(open(section).await?, KeyLayout::new(&section.prefix)))
    }

    /// A client of the axes `layout` names, on `session`.
    pub fn new(session: Session, layout: KeyLayout) -> Self {
        Self { session, layout }
    }

    /// Its session.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Its key layout.
    pub fn layout(&self) -> &KeyLayout {
        &self.layout
    }

    /// A plain put of `value` (text) to `axis`'s `field`, as a robot's publisher sends it: no
    /// answer; a refusal goes to the axis's ERR.
    pub async fn put(&self, axis: &str, field: Field, value: impl Into<String>) -> Result<(), zenoh::Error> {
        self.session.put(self.layout.field(axis, field), value.into()).encoding(Encoding::TEXT_PLAIN).await
    }

    /// Declare the token `holder` holds its motions of `axis` by.
    pub async fn hold(&self, axis: &str, holder: &str) -> Result<HoldToken, zenoh::Error> {
        let key = self.layout.hold(axis, holder);
        let token = self.session.liveliness().declare_token(&key).await?;
        Ok(HoldToken { key, _token: token })
    }
}

/// Whether an error reply is Zenoh's own word that a query's time ran out (`Timeout`, from the
/// session or from a router on the way), not a node's answer: a node refuses with a refusal's
/// type.
fn timed_out(error: &ReplyError) -> bool {
    !error.encoding().to_string().starts_with(Refusal::MIME) && *error.payload().to_bytes() == *b"Timeout"
}
