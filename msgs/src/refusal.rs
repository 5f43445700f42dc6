//! Why a node refused a write, in a form every face can act on. The words travel as the payload
//! (`text/plain`, as the contract promises a stock client) and the kind as the schema of its
//! encoding, `text/plain;limit_violation`: Channel Access answers the ECA code an IOC would,
//! a page or the command line can tell a limit violation from a disabled motor.

/// What kind of refusal a write met. The node's words (`Refusal::message`) say the details.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RefusalKind {
    /// No field has this name (or only in another case: keys are exact).
    UnknownField,
    /// The field cannot be written.
    ReadOnly,
    /// The payload holds no valid value for the field: malformed, of the wrong type, not
    /// finite, out of the type's range, not a menu choice, a key a link cannot follow.
    BadValue,
    /// The record cannot take the write now (a home in progress, a jog's backlash takeout, a
    /// status update): nothing changed.
    Busy,
    /// The record stored a corrected value instead (NTMF at least 2; STUP stays OFF) and did
    /// not process.
    Adjusted,
    /// The target is beyond the soft limits: the record took the write, set LVIO and did not
    /// move.
    LimitViolation,
    /// The motor's closed-loop control is off (CNEN Disable): nothing was sent to it.
    Disabled,
    /// The record is disabled (DISA = DISV) and the write would start a motion once it is
    /// enabled (a target, a jog or home button, SPMG Move or Go): nothing changed.
    RecordDisabled,
    /// A home toward a limit switch that is active.
    SwitchActive,
    /// The axis takes no writes but to DISP and STOP while DISP is not 0 (an IOC's "put
    /// disabled"): nothing changed.
    PutsDisabled,
    /// A target or position beyond what the driver's 32-bit raw position can hold.
    BeyondRawRange,
    /// The readback link (RDBL) the move depends on cannot be read.
    ReadbackUnreadable,
    /// A write to `sim/<axis>/...` of an axis with no simulator.
    NotSimulated,
    /// A plain jog of an axis that jogs only under a hold (the jog deadman).
    HoldRequired,
    /// The write's hold names no liveliness token of the axis's hold space.
    BadHold,
    /// Under access control, a confirmed write goes to the write key, not the field key.
    WriteKeyRequired,
    /// A write to a key with wildcards: a write names one field of one axis.
    Wildcard,
    /// The axis's controller reported an error, or a command to it was not sent (published on
    /// ERR with the vendor's code and meaning; not a write's refusal).
    Controller,
    /// A refusal whose kind the node did not say (a node of another make or version).
    Other,
}

impl RefusalKind {
    /// Every kind.
    pub const ALL: [RefusalKind; 19] = [
        RefusalKind::UnknownField,
        RefusalKind::ReadOnly,
        RefusalKind::BadValue,
        RefusalKind::Busy,
        RefusalKind::Adjusted,
        RefusalKind::LimitViolation,
        RefusalKind::Disabled,
        RefusalKind::RecordDisabled,
        RefusalKind::SwitchActive,
        RefusalKind::PutsDisabled,
        RefusalKind::BeyondRawRange,
        RefusalKind::ReadbackUnreadable,
        RefusalKind::NotSimulated,
        RefusalKind::HoldRequired,
        RefusalKind::BadHold,
        RefusalKind::WriteKeyRequired,
        RefusalKind::Wildcard,
        RefusalKind::Controller,
        RefusalKind::Other,
    ];

    /// Its name on the wire (the encoding's schema).
    pub fn name(self) -> &'static str {
        match self {
            RefusalKind::UnknownField => "unknown_field",
            RefusalKind::ReadOnly => "read_only",
            RefusalKind::BadValue => "bad_value",
            RefusalKind::Busy => "busy",
            RefusalKind::Adjusted => "adjusted",
            RefusalKind::LimitViolation => "limit_violation",
            RefusalKind::Disabled => "disabled",
            RefusalKind::RecordDisabled => "record_disabled",
            RefusalKind::SwitchActive => "switch_active",
            RefusalKind::PutsDisabled => "puts_disabled",
            RefusalKind::BeyondRawRange => "beyond_raw_range",
            RefusalKind::ReadbackUnreadable => "readback_unreadable",
            RefusalKind::NotSimulated => "not_simulated",
            RefusalKind::HoldRequired => "hold_required",
            RefusalKind::BadHold => "bad_hold",
            RefusalKind::WriteKeyRequired => "write_key_required",
            RefusalKind::Wildcard => "wildcard",
            RefusalKind::Controller => "controller",
            RefusalKind::Other => "other",
        }
    }

    /// The kind named `name`, if one is.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|kind| kind.name() == name)
    }

    /// Whether the record took the write and processed, but would not act on it (as an IOC's
    /// record does on a limit violation: the put succeeds, LVIO tells). Other refusals
    /// changed nothing, or only stored a corrected value.
    pub fn was_processed(self) -> bool {
        matches!(
            self,
            RefusalKind::LimitViolation
                | RefusalKind::Disabled
                | RefusalKind::SwitchActive
                | RefusalKind::BeyondRawRange
                | RefusalKind::ReadbackUnreadable
        )
    }

    /// The MIME type of a refusal of this kind: `text/plain;<name>`.
    pub fn mime(self) -> String {
        format!("{};{}", Refusal::MIME, self.name())
    }
}

impl std::fmt::Display for RefusalKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A refusal as a client receives it: its kind and the node's words.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    /// What kind of refusal.
    pub kind: RefusalKind,
    /// The node's words, naming the field and the fault.
    pub message: String,
}

impl Refusal {
    /// The base MIME type of every refusal.
    pub const MIME: &'static str = "text/plain";

    /// A refusal as an error reply or an ERR sample carries it: its encoding (the MIME type,
    /// whose schema names the kind) and its payload. A reply that names no known kind is
    /// `RefusalKind::Other`.
    pub fn from_wire(mime: &str, payload: &[u8]) -> Self {
        let kind = mime
            .split_once(';')
            .filter(|(base, _)| base.trim() == Self::MIME)
            .and_then(|(_, schema)| RefusalKind::from_name(schema.trim()))
            .unwrap_or(RefusalKind::Other);
        Self { kind, message: String::from_utf8_lossy(payload).into_owned() }
    }
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Refusal {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_goes_through_its_mime_type_and_back() {
        for kind in RefusalKind::ALL {
            let refusal = Refusal::from_wire(&kind.mime(), b"VAL: words");
            assert_eq!(refusal, Refusal { kind, message: "VAL: words".into() });
        }
        let mut names: Vec<&str> = RefusalKind::ALL.iter().map(|k| k.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), RefusalKind::ALL.len(), "a name names one kind");
    }

    #[test]
    fn a_refusal_that_names_no_kind_is_other() {
        for mime in ["text/plain", "text/plain;nonsense", "application/json;read_only", ""] {
            assert_eq!(Refusal::from_wire(mime, b"no").kind, RefusalKind::Other, "{mime}");
        }
    }
}
