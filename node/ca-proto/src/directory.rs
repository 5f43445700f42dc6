//! What a circuit, and the answer to a search, ask of the values the runner holds.

use crate::dbr::Snapshot;
use crate::names::{Pv, Target, ABLE_SUFFIX};
use zmotor_msgs::BridgeRecord;
use zmotor_msgs::Field;

/// What a circuit asks of the values the runner holds.
pub trait Directory {
    /// Whether an axis is live now.
    fn is_live(&self, axis: &str) -> bool;
    /// The bridge record of that name live now, if one is.
    fn bridge_record(&self, name: &str) -> Option<BridgeRecord>;
    /// What a channel shows now; `None` until the axis's values have been fetched.
    fn snapshot(&self, pv: &Pv) -> Option<Snapshot>;
}

/// The channel `name` asks for under `prefix` as `directory` has the records now: a live
/// axis's, else a live bridge record's value or type.
pub(crate) fn resolve(prefix: &str, name: &str, directory: &dyn Directory) -> Option<Pv> {
    let pv = Pv::parse(prefix, name)?;
    if directory.is_live(&pv.axis) {
        return Some(pv);
    }
    // `<R>_able` of no live axis R may be a record of that name.
    let (record, target) = match pv.target {
        Target::Able => (format!("{}{ABLE_SUFFIX}", pv.axis), Target::Field(Field::VAL)),
        target => (pv.axis, target),
    };
    let kind = directory.bridge_record(&record)?;
    let target = match target {
        Target::Field(Field::VAL) => Target::BridgeValue(kind),
        Target::RecordType => Target::BridgeType(kind),
        _ => return None,
    };
    Some(Pv { axis: record, target })
}
