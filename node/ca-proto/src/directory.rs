//! What a circuit, and the answer to a search, ask of the values the runner holds.

use crate::dbr::Snapshot;
use crate::names::Pv;
use zmotor_msgs::BridgeRecord;

/// What a circuit asks of the values the runner holds.
pub trait Directory {
    /// Whether an axis is live now.
    fn is_live(&self, axis: &str) -> bool;
    /// The bridge record of that name live now, if one is.
    fn bridge_record(&self, name: &str) -> Option<BridgeRecord>;
    /// What a channel shows now; `None` until the axis's values have been fetched.
    fn snapshot(&self, pv: &Pv) -> Option<Snapshot>;
}
