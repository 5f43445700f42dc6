//! How a node tells a refusal: the node's words as `text/plain`, the kind as the encoding's
//! schema (`zmotor_msgs::Refusal`), on an error reply and on the axis's ERR.

use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::Wait;
use zmotor_msgs::RefusalKind;

/// The encoding of a refusal of `kind`.
pub(crate) fn encoding(kind: RefusalKind) -> Encoding {
    Encoding::TEXT_PLAIN.with_schema(kind.name())
}

/// Answer `query` with a refusal (sent without waiting: callbacks must not block).
pub(crate) fn refuse(query: &Query, kind: RefusalKind, message: String) {
    let _ = query.reply_err(message).encoding(encoding(kind)).wait();
}
