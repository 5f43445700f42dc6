//! What a vendor's protocol is to the controller layer: pure code that turns driver commands
//! and polls into request frames, splits the byte stream into reply frames, and turns replies
//! into channel status. No I/O, no clock.

use crate::scale::Scale;
use zmotor_core::DeviceStatus;
use zmotor_msgs::DriverCommand;

/// What a protocol needs to know of the installation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProtocolOptions {
    /// How many of the controller's own units one record step is (an SMC100's millimetres, an
    /// MCS2's picometres); None for the protocol's default.
    pub units_per_step: Option<f64>,
    /// The controller's own names of its channels' axes, where it names them (an XPS's
    /// positioners, `GROUP.POSITIONER`); a channel not named has the protocol's default name.
    pub names: std::collections::BTreeMap<usize, String>,
    /// The script of a script controller, and what the launch file gives it.
    pub script: Option<crate::script_source::ScriptSource>,
}

/// Which of a controller's connections a request travels on. Most protocols use one; a
/// controller whose motion calls answer only once the motion ends (an XPS) gets a connection
/// of its own for each channel's motion, so that polls and stops go on meanwhile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Lane {
    /// The connection every exchange waits on, one request at a time.
    Main,
    /// The connection of the motion of one channel: requests are written without waiting,
    /// their replies read whenever they come.
    Motion(usize),
    /// The node's own key space, which a script reads and writes (`epics.get`/`epics.put`): a
    /// `KeyAccess` the runner carries out, answered by one `KeyReply` frame. No connection.
    Keys,
}

/// One exchange with the controller: the bytes to write, and whether one reply frame answers
/// them. `S` is the protocol's name for the step it is (`Protocol::Step`).
#[derive(Clone, Debug, PartialEq)]
pub struct Request<S> {
    /// The bytes, terminator or frame included.
    pub bytes: Vec<u8>,
    /// The controller answers with one reply frame (a query, or a command it acknowledges).
    pub answered: bool,
    /// Which step it is, handed back with the reply.
    pub step: S,
    /// The connection it goes on.
    pub lane: Lane,
}

impl<S> Request<S> {
    /// A request the controller answers.
    pub fn query(bytes: impl Into<Vec<u8>>, step: S) -> Self {
        Self { bytes: bytes.into(), answered: true, step, lane: Lane::Main }
    }

    /// A request the controller does not answer (a setter of a protocol whose setters are
    /// silent).
    pub fn silent(bytes: impl Into<Vec<u8>>, step: S) -> Self {
        Self { bytes: bytes.into(), answered: false, step, lane: Lane::Main }
    }

    /// A script's access to the node's key space, answered as any query.
    pub fn key(access: &crate::keys::KeyAccess, step: S) -> Self {
        Self { bytes: access.encode(), answered: true, step, lane: Lane::Keys }
    }

    /// A motion call of `channel` answered when the motion ends: written on the channel's
    /// motion connection and not waited for; its reply goes to `Protocol::reply` when it comes.
    pub fn motion(bytes: impl Into<Vec<u8>>, step: S, channel: usize) -> Self {
        Self { bytes: bytes.into(), answered: true, step, lane: Lane::Motion(channel) }
    }
}

/// What a request is for, as the controller layer sorts requests (`Protocol::purpose`): a
/// poll's requests are grouped by channel and may be cut short by a stop; a command's are not.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Purpose {
    /// Part of the poll of one channel.
    Poll {
        /// The channel polled.
        channel: usize,
    },
    /// Part of a poll of several channels in one request (a batched poll).
    PollMany,
    /// Part of a command to one channel.
    Command {
        /// The channel commanded.
        channel: usize,
    },
    /// Part of the initialisation of a new connection: a reading.
    Init,
    /// Part of the initialisation of a new connection that changes the controller (a servo
    /// switched on, a holding time): left out when the controller is only observed.
    Setup,
}

impl Purpose {
    /// The channel the request concerns, if one.
    pub fn channel(self) -> Option<usize> {
        match self {
            Purpose::Poll { channel } | Purpose::Command { channel } => Some(channel),
            Purpose::PollMany | Purpose::Init | Purpose::Setup => None,
        }
    }
}

/// Where the first reply frame of a byte stream ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// More bytes are needed.
    Incomplete,
    /// A frame of this many bytes (terminators included) is complete.
    Complete(usize),
    /// This many bytes before any frame are noise (line noise, a stray terminator): drop them.
    Junk(usize),
    /// A frame of this many bytes the controller sent unasked (a notification): handed to
    /// `Protocol::notice`, never taken for a reply.
    Notice(usize),
}

/// A request as it goes out (`Protocol::prepare`): what to write, if anything, and what
/// making it found.
#[derive(Debug)]
pub struct Prepared<S> {
    /// The request to write; none when there is nothing to send.
    pub request: Option<Request<S>>,
    /// What making it says, as a reply's events would.
    pub events: Vec<ReplyEvent<S>>,
}

/// What a reply says.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq)]
pub enum ReplyEvent<S> {
    /// The full status of a channel: its poll is complete.
    Status {
        /// The channel.
        channel: usize,
        /// Its status, in raw units (steps) and MSTA bits.
        status: DeviceStatus,
    },
    /// The controller reported an error, in its own words.
    ControllerError(VendorError),
    /// The controller refused this request: its error, and the rest of the command under way is
    /// not sent (a move whose speed was refused must not go at the previous speed).
    Refused(VendorError),
    /// Requests to send right after this one, before anything else (an error query after a
    /// setter, the next entry of an error queue).
    FollowUp(Vec<Request<S>>),
    /// What the controller says of itself at connection, for the log.
    Found(Finding),
}

/// What a controller says of itself when a connection is initialised.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq)]
pub enum Finding {
    /// Who it is (model, serial number, firmware), in its words.
    Identity(String),
    /// Its axes, by its names for them.
    Axes(Vec<String>),
    /// A channel's travel range, in the controller's units.
    Travel {
        /// The channel.
        channel: usize,
        /// The lowest position it takes.
        min: f64,
        /// The highest.
        max: f64,
    },
}

/// An error a controller reported.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VendorError {
    /// The channel it concerns, when the controller says; every channel otherwise.
    pub channel: Option<usize>,
    /// The vendor's code.
    pub code: String,
    /// What the vendor's code means.
    pub meaning: String,
}

/// Why a controller's options cannot be given again while it runs.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ReloadError {
    /// The protocol has nothing to reload.
    #[error("{0} has nothing to reload (only a script controller does)")]
    Unsupported(&'static str),
    /// The new script does not load; the old one runs on.
    #[error("{0}; the running script is kept")]
    Script(#[from] crate::script_source::ScriptError),
}

/// A reply that cannot be understood.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unexpected reply to {request}: {reply:?} ({why})")]
pub struct ReplyError {
    /// The request, as text.
    pub request: String,
    /// The reply, as text.
    pub reply: String,
    /// What was wrong with it.
    pub why: &'static str,
}

impl ReplyError {
    /// A reply to `request` that the protocol cannot use.
    pub fn new<S>(request: &Request<S>, reply: &[u8], why: &'static str) -> Self {
        Self { request: printable(&request.bytes), reply: printable(reply), why }
    }
}

/// Why a driver command cannot be sent; nothing is sent then.
#[non_exhaustive]
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CommandError {
    /// The controller has nothing that does it.
    #[error("{protocol} cannot {what}")]
    Unsupported {
        /// The protocol.
        protocol: &'static str,
        /// What it cannot do.
        what: &'static str,
    },
    /// A value the controller cannot represent: refused, never clamped or wrapped.
    #[error("{what} {value} is outside what the controller takes")]
    OutOfRange {
        /// What the value is.
        what: &'static str,
        /// The value.
        value: f64,
    },
}

/// A vendor's wire protocol (see the module documentation). Channels are the controller's own
/// axis numbers as the launch file gives them.
pub trait Protocol: Send {
    /// The protocol's own name for each request: which reading of a poll, which step of a
    /// command or of the initialisation. Handed back with the reply, it tells `reply` what the
    /// reply is.
    type Step: Copy + Eq + std::fmt::Debug + Send;

    /// The protocol's name, as launch files write it.
    fn name(&self) -> &'static str;

    /// What a request of `step` is for, as the controller layer sorts requests.
    fn purpose(step: Self::Step) -> Purpose;

    /// Where the first reply frame in `buffer` ends.
    #[must_use]
    fn frame(&self, buffer: &[u8]) -> Frame;

    /// What a new connection sends before the channels are polled.
    #[must_use = "the requests are to be sent"]
    fn init(&mut self, channels: &[usize]) -> Vec<Request<Self::Step>>;

    /// One complete poll of `channels`: every reading a channel's status needs, batched into
    /// fewer requests where the controller allows it.
    #[must_use = "the requests are to be sent"]
    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Self::Step>>;

    /// The requests that carry out one driver command on `channel`, in order.
    #[must_use = "the requests are to be sent"]
    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Self::Step>>, CommandError>;

    /// Whether the controller refuses to move `channel` until it is referenced: the layer then
    /// refuses a move or a jog of a channel whose last status lacks HOMED, before sending
    /// anything, and says how to reference it.
    fn moves_need_reference(&self, channel: usize) -> bool {
        let _ = channel;
        false
    }

    /// A query no other reply of the protocol can be taken for (an identity, answered as the
    /// initialisation read it), with which the layer finds the controller's replies again
    /// after a failed exchange: a reply later than its request's timeout would otherwise be
    /// taken for the next request's, and a protocol whose replies do not name their request (no
    /// echo, no address) would read one value as another. None where every reply names its
    /// request, or before the identity is known. On a line of several units, each call may ask
    /// another (a unit that went silent must not take the line down).
    fn sync(&mut self) -> Option<Request<Self::Step>> {
        None
    }

    /// Whether `frame` is the reply to the last `sync` query; every frame before it is stale.
    fn is_sync_reply(&self, _frame: &[u8]) -> bool {
        false
    }

    /// The controller is only observed (`observe = true`, beside the IOC that drives it): from
    /// now on its polls leave out the readings that clear what the controller keeps for its
    /// other clients (a done flag, an error register or queue), or read it without clearing.
    fn observe_only(&mut self) {}

    /// Whether motion calls go on connections of their own (`Lane::Motion`): the runner then
    /// opens one for each channel beside the main one.
    fn motion_lanes(&self) -> bool {
        false
    }

    /// The request as it goes out, asked just before it is written: a protocol whose requests
    /// are made by code that must run in turn (a script's call) makes them then. Most send
    /// the request as it was queued.
    fn prepare(&mut self, request: Request<Self::Step>) -> Prepared<Self::Step> {
        Prepared { request: Some(request), events: Vec::new() }
    }

    /// Whether `options`, given again while the controller runs (a script re-read), can be
    /// used: a protocol that takes nothing new says so; a script that does not load is refused
    /// with its file and line. Nothing changes yet.
    fn check_reload(&self, options: &ProtocolOptions) -> Result<(), ReloadError> {
        let _ = options;
        Err(ReloadError::Unsupported(self.name()))
    }

    /// Use `options` (checked by `check_reload`) from the next request on.
    fn reload(&mut self, options: &ProtocolOptions) {
        let _ = options;
    }

    /// How many of the controller's units one record step of `channel` is, as the protocol
    /// knows it now (read at connection where the controller tells).
    fn scale(&self, channel: usize) -> Scale;

    /// What a notification the controller sent unasked says (see `Frame::Notice`).
    fn notice(&mut self, frame: &[u8]) -> Vec<ReplyEvent<Self::Step>> {
        let _ = frame;
        Vec::new()
    }

    /// What the reply `frame` to `request` says.
    fn reply(&mut self, request: &Request<Self::Step>, frame: &[u8])
        -> Result<Vec<ReplyEvent<Self::Step>>, ReplyError>;
}

/// Frames that end with a terminator (`\r`, `\r\n`, `\n`): the length of the first line.
pub fn line_frame(buffer: &[u8], terminator: &[u8]) -> Frame {
    match buffer.windows(terminator.len()).position(|w| w == terminator) {
        Some(at) => Frame::Complete(at + terminator.len()),
        None => Frame::Incomplete,
    }
}

/// A frame's bytes without the trailing terminator, as text (replies are ASCII; anything
/// else is replaced).
pub(crate) fn line_text(frame: &[u8], terminator: &[u8]) -> String {
    let body = frame.strip_suffix(terminator).unwrap_or(frame);
    String::from_utf8_lossy(body).into_owned()
}

/// Bytes as readable text for messages: control bytes escaped.
pub(crate) fn printable(bytes: &[u8]) -> String {
    bytes.iter().flat_map(|b| std::ascii::escape_default(*b)).map(char::from).collect()
}

/// What a protocol keeps of `channel` among `states`, made (as its default) the first time.
pub(crate) fn state_of<T: Default>(states: &mut Vec<(usize, T)>, channel: usize) -> &mut T {
    let at = match states.iter().position(|(c, _)| *c == channel) {
        Some(at) => at,
        None => {
            states.push((channel, T::default()));
            states.len() - 1
        }
    };
    &mut states[at].1
}

/// `bit` of `bits` set or cleared.
pub(crate) fn set_bit(bits: &mut u32, bit: u32, on: bool) {
    if on {
        *bits |= bit;
    } else {
        *bits &= !bit;
    }
}

/// A step count as a controller counts it: C-style NINT, in 32 bits. A value beyond is
/// refused, never clamped (a clamped target drives the carriage somewhere nobody asked).
pub(crate) fn whole_steps(what: &'static str, steps: f64) -> Result<i32, CommandError> {
    let rounded = steps.round();
    if rounded.is_finite() && rounded >= f64::from(i32::MIN) && rounded <= f64::from(i32::MAX) {
        Ok(rounded as i32)
    } else {
        Err(CommandError::OutOfRange { what, value: steps })
    }
}

/// The identities a connection's initialisation read (each unit's answer to its identity query;
/// a controller alone on its connection is unit 0), asked again, in turn, to find the replies
/// again after a failure (`Protocol::sync`): a unit gone silent must not take the line down.
#[derive(Clone, Debug, Default)]
pub(crate) struct UnitIdentities {
    identities: Vec<(usize, String)>,
    /// The unit the last sync asked.
    asked: usize,
}

impl UnitIdentities {
    /// Forget them: a new connection reads them afresh.
    pub(crate) fn clear(&mut self) {
        self.identities.clear();
    }

    /// `unit` answered `identity`.
    pub(crate) fn read(&mut self, unit: usize, identity: &str) {
        self.identities.retain(|(u, _)| *u != unit);
        self.identities.push((unit, identity.to_string()));
        self.identities.sort();
    }

    /// The unit to ask next, after the one asked last; none before any identity is known.
    pub(crate) fn next(&mut self) -> Option<usize> {
        let next = self.identities.iter().position(|(u, _)| *u > self.asked).unwrap_or(0);
        self.asked = self.identities.get(next)?.0;
        Some(self.asked)
    }

    /// Whether `text` is the identity of the unit asked last.
    pub(crate) fn is_answer(&self, text: &str) -> bool {
        self.identities.iter().any(|(u, id)| *u == self.asked && id == text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_cut_at_their_terminator() {
        assert_eq!(line_frame(b"#01P=+5\r#0", b"\r"), Frame::Complete(8));
        assert_eq!(line_frame(b"#01P=+5", b"\r"), Frame::Incomplete);
        assert_eq!(line_frame(b"1TP2.5\r\n", b"\r\n"), Frame::Complete(8));
        assert_eq!(line_frame(b"1TP2.5\r", b"\r\n"), Frame::Incomplete);
        assert_eq!(line_text(b"1TP2.5\r\n", b"\r\n"), "1TP2.5");
        assert_eq!(printable(b"\x02a\r"), "\\x02a\\r");
    }

    #[test]
    fn step_counts_round_half_away_from_zero_and_are_refused_beyond_32_bits() {
        assert_eq!((whole_steps("p", 2.5), whole_steps("p", -2.5)), (Ok(3), Ok(-3)));
        assert!(matches!(whole_steps("p", 3e9), Err(CommandError::OutOfRange { .. })));
        assert!(whole_steps("p", f64::NAN).is_err());
    }
}
