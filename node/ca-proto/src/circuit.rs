//! One client's TCP circuit, as a state machine: bytes in (`handle_input`), changes of the
//! network in (`handle_change`, `values_arrived`, `axis_gone`, `write_done`), bytes out (`poll_transmit`) and
//! requests to the network out (`poll_request`). The runner holds the values (`Directory`).

use crate::codec::{self, command, Header, MINOR_VERSION};
use crate::dbr::{self, Base, Class, DbrType, Snapshot};
use crate::directory::Directory;
use crate::names::{Pv, Target};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use zmotor_msgs::menus::severity;
use zmotor_msgs::{past_deadband, Field, Refusal, RefusalKind, Value, WriteClass};

/// ECA status codes (`caerr.h`): message number << 3 | severity.
pub(crate) mod status {
    /// Success.
    pub(crate) const NORMAL: u32 = 1;
    /// The write failed (refused, or nobody answered).
    pub(crate) const PUTFAIL: u32 = 160;
    /// A type the server cannot convert to.
    pub(crate) const BADTYPE: u32 = 114;
    /// No write access.
    pub(crate) const NO_WRITE_ACCESS: u32 = 376;
    /// No such channel on this circuit.
    pub(crate) const BAD_CHANNEL_ID: u32 = 410;
}

/// Access rights bits.
const READ: u32 = 1;
const WRITE: u32 = 2;

/// A request to the network.
#[derive(Clone, Debug, PartialEq)]
pub enum Request {
    /// Fetch an axis's values (then tell the circuit with `values_arrived`).
    Fetch {
        /// The axis.
        axis: String,
    },
    /// A confirmed write; `wait`: answered when the motion it starts has ended.
    Write {
        /// What is written.
        pv: Pv,
        /// The value as text.
        text: String,
        /// Whether to wait for the end of the motion (a put-callback of a drive field).
        wait: bool,
        /// Whether the motion is held by this circuit (a jog: it ends when the circuit does,
        /// as the jog deadman has it).
        hold: bool,
        /// How to answer the client, given back in `write_done`.
        answer: WriteAnswer,
    },
}

/// How a write ended, as the runner learnt it from the network.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum WriteEnd {
    /// The node took it.
    Done,
    /// The node refused it: its kind and words.
    Refused(Refusal),
    /// Nothing answered: `denied` when the axis is served but the network gave no answer (as
    /// access control does to a write it refuses), else the node is gone or too slow.
    Unanswered {
        /// The axis is served, and the write was met with silence.
        denied: bool,
        /// Why, in words.
        why: String,
    },
}

impl WriteEnd {
    /// The ECA code an IOC would answer. A refusal of the record's own processing (a limit
    /// violation, a motor disabled, a home against a switch) is a put the record took: it says
    /// ECA_NORMAL, and LVIO or MSTA tell the rest; a read-only field (or a write access control
    /// denies) is ECA_NOWTACCESS; every other failure ECA_PUTFAIL, as rsrv maps a failed
    /// dbPutField or put-notify.
    pub fn eca_code(&self) -> u32 {
        match self {
            WriteEnd::Done => status::NORMAL,
            WriteEnd::Refused(refusal) if refusal.kind.was_processed() => status::NORMAL,
            WriteEnd::Refused(Refusal { kind: RefusalKind::ReadOnly, .. }) => status::NO_WRITE_ACCESS,
            WriteEnd::Unanswered { denied: true, .. } => status::NO_WRITE_ACCESS,
            WriteEnd::Refused(_) | WriteEnd::Unanswered { .. } => status::PUTFAIL,
        }
    }

    fn words(&self) -> &str {
        match self {
            WriteEnd::Done => "",
            WriteEnd::Refused(refusal) => &refusal.message,
            WriteEnd::Unanswered { why, .. } => why,
        }
    }
}

/// How a write's outcome is told to the client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteAnswer {
    /// A put-callback: a WRITE_NOTIFY reply.
    Notify {
        /// The request's id.
        ioid: u32,
        /// The type written.
        data_type: u16,
        /// The count written.
        count: u32,
        /// The write's number on its circuit.
        number: u64,
    },
    /// A plain write: an error message only if it failed.
    OnFailure {
        /// The request's header, quoted in the error.
        request: Header,
        /// The channel's client id.
        cid: u32,
        /// The write's number on its circuit.
        number: u64,
    },
}

impl WriteAnswer {
    /// The write's number on its circuit.
    fn number(&self) -> u64 {
        match self {
            WriteAnswer::Notify { number, .. } | WriteAnswer::OnFailure { number, .. } => *number,
        }
    }
}

struct Channel {
    cid: u32,
    pv: Pv,
}

struct Subscription {
    sid: u32,
    dbr: u16,
    /// The element count asked for (0: as many as there are).
    count: u32,
    mask: u16,
    /// Whether its first event went (it waits for its axis's values).
    posted: bool,
    /// The RBV last sent to a subscriber of DBE_LOG without DBE_VALUE (an archiver): the next
    /// goes once RBV has moved more than ADEL from it, as the record's ALST.
    archived: Option<f64>,
}

/// DBE_VALUE: the subscriber wants value changes past the monitor deadband (MDEL).
const VALUE_EVENT: u16 = 1;
/// DBE_LOG: the subscriber wants value changes past the archive deadband (ADEL).
const LOG_EVENT: u16 = 2;
/// DBE_VALUE and DBE_LOG: the subscriber wants value changes.
const VALUE_EVENTS: u16 = VALUE_EVENT | LOG_EVENT;
/// DBE_ALARM: the subscriber wants alarm changes.
const ALARM_EVENT: u16 = 4;
/// DBE_PROPERTY: the subscriber wants metadata changes.
const PROPERTY_EVENT: u16 = 8;

/// A read or subscription waiting for its axis's values.
struct Pending {
    sid: u32,
    data_type: u16,
    /// The element count asked for (0: as many as there are).
    count: u32,
    ioid: u32,
}

/// One client's circuit.
#[derive(Default)]
pub struct Circuit {
    inbox: Vec<u8>,
    channels: BTreeMap<u32, Channel>,
    subscriptions: BTreeMap<u32, Subscription>,
    pending_reads: Vec<Pending>,
    /// Writes sent and not yet answered that answer once taken (not at a motion's end), each
    /// numbered, with its axis: a read of the axis waits for those before it, as an IOC reads
    /// after it processed them.
    writing: Vec<(u64, String)>,
    /// The number of the last write taken from the client (each answer names its own).
    writes_sent: u64,
    /// Reads that came after such writes of their axis, each with the number of the last one.
    reads_after_writes: Vec<(Pending, u64)>,
    /// Subscriptions owed an alarm's event: one processing's SEVR, STAT and ACKS arrive apart,
    /// and make one event (`flush_alarms`), as an IOC posts one.
    alarms_due: BTreeSet<u32>,
    next_sid: u32,
    events_on: bool,
    /// Whether a change went unposted while events were off.
    missed: bool,
    transmit: Vec<u8>,
    requests: VecDeque<Request>,
    prefix: String,
}

impl Circuit {
    /// A circuit serving PV names under `prefix`.
    pub fn new(prefix: &str) -> Self {
        Self { prefix: prefix.to_string(), events_on: true, next_sid: 1, ..Self::default() }
    }

    /// Bytes from the client. An error means the circuit must be closed.
    pub fn handle_input(&mut self, bytes: &[u8], directory: &dyn Directory) -> Result<(), codec::FrameError> {
        self.flush_alarms(directory);
        self.inbox.extend_from_slice(bytes);
        let mut used = 0;
        while let Some((header, payload, length)) = codec::parse(&self.inbox[used..])? {
            let payload = payload.to_vec();
            used += length;
            self.handle_message(header, &payload, directory);
        }
        self.inbox.drain(..used);
        Ok(())
    }

    /// Bytes to send the client, if any.
    #[must_use]
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        (!self.transmit.is_empty()).then(|| std::mem::take(&mut self.transmit))
    }

    /// A request to the network, if any.
    #[must_use]
    pub fn poll_request(&mut self) -> Option<Request> {
        self.requests.pop_front()
    }

    /// A field of an axis (or its message) changed: answer the reads that waited for the
    /// axis's values and post to the subscriptions it concerns.
    pub fn handle_change(&mut self, axis: &str, changed: Target, directory: &dyn Directory) {
        self.tell(axis, Some(changed), directory);
    }

    /// An axis's values arrived whole: answer the reads that waited for them and post to the
    /// subscriptions not posted yet.
    pub fn values_arrived(&mut self, axis: &str, directory: &dyn Directory) {
        self.tell(axis, None, directory);
    }

    fn tell(&mut self, axis: &str, changed: Option<Target>, directory: &dyn Directory) {
        let waiting = std::mem::take(&mut self.pending_reads);
        for pending in waiting {
            let pv = self.channels.get(&pending.sid).map(|c| c.pv.clone());
            match pv.filter(|pv| pv.axis == axis).and_then(|pv| self.snapshot(&pv, directory)) {
                Some(snapshot) => self.send_read(&pending, &snapshot),
                None => self.pending_reads.push(pending),
            }
        }
        // An acknowledgement's change is an alarm event, as dbAccess posts it (DBE_ALARM).
        let alarm = matches!(changed, Some(Target::Field(field)) if field.is_alarm_state());
        let metadata = |pv: &Pv| matches!(changed, Some(Target::Field(field)) if pv.metadata_from().contains(&field));
        // Each subscription concerned, and whether its event carries a value change (the first,
        // or one past the deadbands), as against an alarm's or metadata's alone.
        let mut concerned = Vec::new();
        let mut alarms_due = Vec::new();
        for (subid, s) in &self.subscriptions {
            let Some(pv) = self.channels.get(&s.sid).map(|c| &c.pv).filter(|pv| pv.axis == axis) else { continue };
            let class = match s.dbr {
                // Alarm and acknowledgement, with the value as text.
                dbr::DBR_STSACK_STRING => Class::Status,
                code => DbrType::from_code(code).map_or(Class::Plain, |d| d.class),
            };
            let value = !s.posted
                || (changed.is_some_and(|c| pv.shows(c))
                    && s.mask & VALUE_EVENTS != 0
                    && !Self::within_archive_deadband(s, pv, directory));
            let property = metadata(pv) && (s.mask & PROPERTY_EVENT != 0 || class >= Class::Graphic);
            let alarmed = alarm && s.mask & ALARM_EVENT != 0 && class >= Class::Status;
            if value || (property && !alarm) {
                concerned.push((*subid, value));
            } else if alarmed || property {
                // STAT and SEVR are metadata of every channel too: an alarm's change is owed.
                alarms_due.push(*subid);
            }
        }
        if !self.events_on {
            self.missed |= !concerned.is_empty() || !alarms_due.is_empty();
            return;
        }
        self.alarms_due.extend(alarms_due);
        for (subid, value) in concerned {
            // An event now carries the alarm as it stands: none is owed after it.
            self.alarms_due.remove(&subid);
            self.post(subid, directory, value);
        }
    }

    /// Whether alarm events are owed: `flush_alarms` soon (one processing's alarm changes come
    /// within a few milliseconds of each other).
    #[must_use]
    pub fn alarms_due(&self) -> bool {
        !self.alarms_due.is_empty()
    }

    /// Post the alarm events owed (`alarms_due`), each with the alarm as it stands now: call it
    /// once one processing's changes are handled, and before answering a request.
    pub fn flush_alarms(&mut self, directory: &dyn Directory) {
        for subid in std::mem::take(&mut self.alarms_due) {
            if self.subscriptions.contains_key(&subid) {
                self.post(subid, directory, false);
            }
        }
    }

    /// Post every subscription's current value again (after events were held back, or when
    /// the runner lost changes).
    pub fn repost(&mut self, directory: &dyn Directory) {
        self.alarms_due.clear();
        if !self.events_on {
            self.missed = true;
            return;
        }
        let all: Vec<u32> = self.subscriptions.keys().copied().collect();
        for subid in all {
            self.post(subid, directory, true);
        }
    }

    /// An axis went away: its channels are disconnected.
    pub fn axis_gone(&mut self, axis: &str) {
        let gone: Vec<u32> = self.channels.iter().filter(|(_, c)| c.pv.axis == axis).map(|(sid, _)| *sid).collect();
        for sid in gone {
            if let Some(channel) = self.channels.remove(&sid) {
                self.send(Header::new(command::SERVER_DISCONN, 0, 0, channel.cid, 0), &[]);
            }
            self.subscriptions.retain(|_, s| s.sid != sid);
            self.pending_reads.retain(|p| p.sid != sid);
            self.reads_after_writes.retain(|(p, _)| p.sid != sid);
        }
    }

    /// A write ended: answered, and the reads of its axis that came after it answered now.
    pub fn write_done(&mut self, answer: WriteAnswer, end: WriteEnd, directory: &dyn Directory) {
        self.flush_alarms(directory);
        self.writing.retain(|(number, _)| *number != answer.number());
        self.answer_write(answer, end);
        let held = std::mem::take(&mut self.reads_after_writes);
        for (pending, after) in held {
            let Some(pv) = self.channels.get(&pending.sid).map(|c| c.pv.clone()) else { continue };
            if self.writing.iter().any(|(n, axis)| *n <= after && *axis == pv.axis) {
                self.reads_after_writes.push((pending, after));
                continue;
            }
            match self.snapshot(&pv, directory) {
                Some(snapshot) => self.send_read(&pending, &snapshot),
                None => {
                    self.requests.push_back(Request::Fetch { axis: pv.axis.clone() });
                    self.pending_reads.push(pending);
                }
            }
        }
    }

    /// Tell the client how a write ended.
    fn answer_write(&mut self, answer: WriteAnswer, end: WriteEnd) {
        let code = end.eca_code();
        match answer {
            WriteAnswer::Notify { ioid, data_type, count, .. } => {
                self.send(Header::new(command::WRITE_NOTIFY, data_type, count, code, ioid), &[]);
            }
            WriteAnswer::OnFailure { .. } if code == status::NORMAL => {}
            WriteAnswer::OnFailure { request, cid, .. } => self.error(request, cid, code, end.words()),
        }
    }

    fn handle_message(&mut self, header: Header, payload: &[u8], directory: &dyn Directory) {
        match header.command {
            command::VERSION => self.send(Header::new(command::VERSION, 0, MINOR_VERSION.into(), 0, 0), &[]),
            command::ECHO => self.send(Header::new(command::ECHO, 0, 0, 0, 0), &[]),
            command::EVENTS_OFF => self.events_on = false,
            command::EVENTS_ON => {
                self.events_on = true;
                if std::mem::take(&mut self.missed) {
                    self.repost(directory);
                }
            }
            command::CREATE_CHAN => self.create_channel(header, payload, directory),
            command::READ_NOTIFY => self.read(header, directory),
            command::EVENT_ADD => self.subscribe(header, payload, directory),
            command::EVENT_CANCEL if self.subscriptions.remove(&header.p2).is_some() => {
                let reply = Header::new(command::EVENT_ADD, header.data_type, header.count, header.p1, header.p2);
                self.send(reply, &[]);
            }
            command::CLEAR_CHANNEL => {
                let sid = header.p1;
                self.channels.remove(&sid);
                self.subscriptions.retain(|_, s| s.sid != sid);
                self.pending_reads.retain(|p| p.sid != sid);
                self.reads_after_writes.retain(|(p, _)| p.sid != sid);
                self.send(Header::new(command::CLEAR_CHANNEL, 0, 0, header.p1, header.p2), &[]);
            }
            command::WRITE | command::WRITE_NOTIFY => self.write(header, payload),
            command::SEARCH => {
                if let Some(reply) = crate::search::reply(&self.prefix, header, payload, 0, directory) {
                    self.transmit.extend_from_slice(&reply);
                }
            }
            // CLIENT_NAME, HOST_NAME and anything else: nothing to answer.
            _ => {}
        }
    }

    fn create_channel(&mut self, header: Header, payload: &[u8], directory: &dyn Directory) {
        let cid = header.p1;
        let name = codec::text(payload);
        let Some(pv) = crate::directory::resolve(&self.prefix, &name, directory) else {
            self.send(Header::new(command::CREATE_CH_FAIL, 0, 0, cid, 0), &[]);
            return;
        };
        let sid = self.next_sid;
        self.next_sid = self.next_sid.wrapping_add(1).max(1);
        let rights = if pv.writable() { READ | WRITE } else { READ };
        let (native, count) = (pv.native(), pv.count());
        if directory.snapshot(&pv).is_none() {
            self.requests.push_back(Request::Fetch { axis: pv.axis.clone() });
        }
        self.channels.insert(sid, Channel { cid, pv });
        self.send(Header::new(command::ACCESS_RIGHTS, 0, 0, cid, rights), &[]);
        self.send(Header::new(command::CREATE_CHAN, native.code(), count, cid, sid), &[]);
    }

    fn read(&mut self, header: Header, directory: &dyn Directory) {
        let pending = Pending { sid: header.p1, data_type: header.data_type, count: header.count, ioid: header.p2 };
        let Some(channel) = self.channels.get(&pending.sid) else {
            return self.error(header, 0, status::BAD_CHANNEL_ID, "no such channel");
        };
        let last = self.writing.iter().filter(|(_, axis)| *axis == channel.pv.axis).map(|(n, _)| *n).max();
        if let Some(last) = last {
            // Read once the writes before it are taken, as an IOC serves a circuit in order.
            return self.reads_after_writes.push((pending, last));
        }
        match self.snapshot(&channel.pv, directory) {
            Some(snapshot) => self.send_read(&pending, &snapshot),
            None => {
                self.requests.push_back(Request::Fetch { axis: channel.pv.axis.clone() });
                self.pending_reads.push(pending);
            }
        }
    }

    fn send_read(&mut self, pending: &Pending, snapshot: &Snapshot) {
        let Some(pv) = self.channels.get(&pending.sid).map(|c| &c.pv) else { return };
        let base = DbrType::from_code(pending.data_type).map_or(Base::String, |d| d.base);
        let elements = snapshot.elements(base, pending.count, pv.count());
        match self.encode(pv, pending.data_type, snapshot, elements) {
            Some(bytes) => {
                let reply =
                    Header::new(command::READ_NOTIFY, pending.data_type, elements, status::NORMAL, pending.ioid);
                self.send(reply, &bytes);
            }
            None => {
                let reply = Header::new(command::READ_NOTIFY, pending.data_type, 0, status::BADTYPE, pending.ioid);
                self.send(reply, &[]);
            }
        }
    }

    fn subscribe(&mut self, header: Header, payload: &[u8], directory: &dyn Directory) {
        let (sid, subid) = (header.p1, header.p2);
        let Some(channel) = self.channels.get(&sid) else {
            return self.error(header, 0, status::BAD_CHANNEL_ID, "no such channel");
        };
        let mask = payload.get(12..14).map_or(VALUE_EVENTS | ALARM_EVENT, |m| u16::from_be_bytes([m[0], m[1]]));
        let axis = channel.pv.axis.clone();
        let subscription =
            Subscription { sid, dbr: header.data_type, count: header.count, mask, posted: false, archived: None };
        self.subscriptions.insert(subid, subscription);
        self.post(subid, directory, true);
        if !self.subscriptions.get(&subid).is_some_and(|s| s.posted) {
            self.requests.push_back(Request::Fetch { axis });
        }
    }

    /// Send `subid` its channel's value now; `value_change` when the event is for the value (the
    /// first, a change past the deadbands, a repost), not an alarm's or metadata's alone: only
    /// such an event moves an archiver's last value, as only they move the record's ALST.
    fn post(&mut self, subid: u32, directory: &dyn Directory, value_change: bool) {
        let Some(subscription) = self.subscriptions.get(&subid) else { return };
        let (dbr, requested) = (subscription.dbr, subscription.count);
        let Some(pv) = self.channels.get(&subscription.sid).map(|c| &c.pv) else { return };
        let Some(snapshot) = self.snapshot(pv, directory) else { return };
        let base = DbrType::from_code(dbr).map_or(Base::String, |d| d.base);
        let elements = snapshot.elements(base, requested, pv.count());
        let Some(bytes) = self.encode(pv, dbr, &snapshot, elements) else { return };
        let archives = Self::archives_readback(pv);
        self.send(Header::new(command::EVENT_ADD, dbr, elements, status::NORMAL, subid), &bytes);
        if let Some(subscription) = self.subscriptions.get_mut(&subid) {
            subscription.posted = true;
            if value_change && archives && subscription.mask & VALUE_EVENT == 0 {
                subscription.archived = snapshot.value.as_f64();
            }
        }
    }

    /// Whether ADEL governs `pv`'s archive events: the record's archive deadband is RBV's.
    fn archives_readback(pv: &Pv) -> bool {
        pv.target == Target::Field(Field::RBV)
    }

    /// Whether a new RBV is to be held back from `s`, a subscriber of archive events only: it
    /// has moved no more than ADEL from the last one sent. (The node posts RBV past MDEL; an
    /// archiver sees those of them past ADEL, as from an IOC when MDEL <= ADEL.)
    fn within_archive_deadband(s: &Subscription, pv: &Pv, directory: &dyn Directory) -> bool {
        if s.mask & VALUE_EVENT != 0 || !Self::archives_readback(pv) {
            return false;
        }
        let adel = Pv { axis: pv.axis.clone(), target: Target::Field(Field::ADEL) };
        let adel = directory.snapshot(&adel).and_then(|a| a.value.as_f64()).unwrap_or(0.0);
        let rbv = directory.snapshot(pv).and_then(|r| r.value.as_f64());
        match (s.archived, rbv) {
            (Some(last), Some(rbv)) => !past_deadband(adel, last, rbv),
            _ => false,
        }
    }

    /// What `pv` shows now: the directory's snapshot, NAME being the record's name as this
    /// circuit's clients know it (the prefix and the axis, as an IOC's record name), RTYP its
    /// record's type.
    fn snapshot(&self, pv: &Pv, directory: &dyn Directory) -> Option<Snapshot> {
        let mut snapshot = directory.snapshot(pv)?;
        match pv.target {
            Target::Field(Field::NAME) | Target::FieldChars(Field::NAME) => {
                snapshot.value = Value::Text(format!("{}{}", self.prefix, pv.axis));
            }
            Target::RecordType | Target::BridgeType(_) => snapshot.value = Value::Text(pv.record_type().into()),
            _ => {}
        }
        Some(snapshot)
    }

    /// The DBR encoding of `elements` of a snapshot, or `None` for a type not served.
    fn encode(&self, pv: &Pv, data_type: u16, snapshot: &Snapshot, elements: u32) -> Option<Vec<u8>> {
        match data_type {
            dbr::DBR_CLASS_NAME => {
                let mut bytes = pv.record_type().as_bytes().to_vec();
                bytes.resize(dbr::STRING_SIZE, 0);
                Some(bytes)
            }
            dbr::DBR_STSACK_STRING => {
                let mut bytes = Vec::new();
                let (ackt, acks) = snapshot.acknowledgement;
                for word in [snapshot.status, snapshot.severity, ackt, acks] {
                    bytes.extend_from_slice(&word.to_be_bytes());
                }
                bytes.extend(snapshot.encode(DbrType { base: Base::String, class: Class::Plain }, 1));
                Some(bytes)
            }
            code => DbrType::from_code(code).map(|dbr| snapshot.encode(dbr, elements)),
        }
    }

    fn write(&mut self, header: Header, payload: &[u8]) {
        let Some(channel) = self.channels.get(&header.p1) else {
            return self.error(header, 0, status::BAD_CHANNEL_ID, "no such channel");
        };
        let (channel_pv, cid) = (channel.pv.clone(), channel.cid);
        let mut pv = channel_pv.clone();
        // An alarm's acknowledgement, on any channel of the record one may write (as rsrv checks
        // the channel's access): a write of ACKT or ACKS.
        let acknowledges = match header.data_type {
            dbr::DBR_PUT_ACKT => Some(Field::ACKT),
            dbr::DBR_PUT_ACKS => Some(Field::ACKS),
            _ => None,
        };
        if let Some(field) = acknowledges {
            pv = Pv { axis: pv.axis, target: Target::Field(field) };
        }
        self.writes_sent += 1;
        let number = self.writes_sent;
        let answer = if header.command == command::WRITE_NOTIFY {
            WriteAnswer::Notify { ioid: header.p2, data_type: header.data_type, count: header.count, number }
        } else {
            WriteAnswer::OnFailure { request: header, cid, number }
        };
        if !channel_pv.writable() {
            let message = format!("{}: read-only", channel_pv.name(&self.prefix));
            return self.answer_write(answer, WriteEnd::Refused(Refusal { kind: RefusalKind::ReadOnly, message }));
        }
        if !channel_pv.has_motor_alarm() && acknowledges.is_some() {
            // `_able` and bridge records are records of their own, with no alarm to acknowledge.
            return self.answer_write(answer, WriteEnd::Done);
        }
        let written = match acknowledges {
            // putAcks acknowledges whatever severity is at least ACKS: above INVALID too.
            Some(Field::ACKS) => dbr::written_text(Base::Enum.code(), payload, pv.native())
                .map(|text| text.parse::<u16>().map_or(text, |severity| severity.min(severity::INVALID).to_string())),
            Some(_) => dbr::written_text(Base::Enum.code(), payload, pv.native()),
            // A long string written as characters: the text up to its NUL.
            None if matches!(pv.target, Target::FieldChars(_)) && header.data_type == Base::Char.code() => {
                let count = usize::try_from(header.count).unwrap_or(usize::MAX).min(payload.len());
                Ok(codec::text(&payload[..count]))
            }
            None => dbr::written_text(header.data_type, payload, pv.native()),
        };
        match written {
            Ok(text) => {
                // A put-callback of a command is answered when the motion it starts has ended.
                let wait = matches!(answer, WriteAnswer::Notify { .. })
                    && matches!(pv.target, Target::Field(f) if f.write_class() == Some(WriteClass::Drive) && !f.acknowledges_alarms());
                let hold = matches!(pv.target, Target::Field(f) if f.is_jog());
                if !wait {
                    self.writing.push((number, pv.axis.clone()));
                }
                self.requests.push_back(Request::Write { pv, text, wait, hold, answer });
            }
            Err(e) => {
                let refusal = Refusal { kind: RefusalKind::BadValue, message: e.to_string() };
                self.answer_write(answer, WriteEnd::Refused(refusal));
            }
        }
    }

    /// An ERROR message about `request`.
    fn error(&mut self, request: Header, cid: u32, code: u32, message: &str) {
        let mut payload = codec::encode(request, &[]);
        payload.truncate(16);
        payload.extend(codec::name_payload(message));
        self.send(Header::new(command::ERROR, 0, 0, cid, code), &payload);
    }

    fn send(&mut self, header: Header, payload: &[u8]) {
        self.transmit.extend(codec::encode(header, payload));
    }
}
