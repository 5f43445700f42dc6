//! Newport SMC100CC / SMC100PP and CONEX-CC: ASCII over a serial line (SMC100: RS-232 at 57600
//! 8N1 into the first controller, up to 31 controllers daisy-chained behind it on RS-485;
//! CONEX-CC: a USB virtual COM port, 921600 8N1), every line ended by `\r\n` both ways. A
//! request is `<address><CMD><argument>`: `1PA12.500000` moves controller 1 to 12.5 mm. The
//! channel is the controller's address, 1 to 31 (a CONEX-CC alone is address 1); a channel
//! outside is refused and never polled. As the EPICS drivers SMC100Driver.cpp and AG_CONEX.cpp
//! do, with their known faults mended (noted below).
//!
//! **Replies.** Only queries are answered, as `<address><CMD><value>` (the echo drops the
//! `?`): `1TP12.4999`, `1TS000033`, `1SR12.5`. Setters (`PA`, `VA`, `OR`, `MM`, `SR`, ...) are
//! silent: they are sent as `Request::silent`, and every command this driver builds ends with
//! `TE` (the last command error, `@` for none), whose letter becomes
//! `ReplyEvent::ControllerError` with the manual's meaning (`H`: "Command not allowed in NOT
//! REFERENCED state"). Every reply must start with the echo of its request, or it is a
//! `ReplyError` (another controller's reply, a garbled line).
//!
//! **Units.** The controller works in millimetres (its stage's "preset units"), the record in
//! steps: `ProtocolOptions::units_per_step` is millimetres per record step, default
//! [`DEFAULT_UNITS_PER_STEP`] = 0.0001 mm (0.1 µm; the record's MRES must be the same).
//! Positions, speeds and accelerations are multiplied by it and sent with six decimals, as
//! the EPICS driver's `%f`; positions read back are divided by it. A value the controller
//! cannot take (beyond ±1e12, not finite, a speed that rounds to zero) is
//! `CommandError::OutOfRange`, never clamped.
//!
//! **Record commands.**
//! - Move: `VA<speed>`, `AC<acceleration>`, then `PA<target>` or `PR<distance>`, then `TE`.
//! - Jog: the SMC100 has no move at constant velocity (its jog is the SMC-RC keypad's), so, as
//!   the EPICS driver does, a jog is a move to the controller's software limit in its
//!   direction: `VA<|speed|>`, `AC<acceleration>`, `SR?` (or `SL?` going down), then, from
//!   the reply, `PA<limit>` and `TE`. The EPICS driver sends a signed `VA` for a downward jog,
//!   which the controller refuses; here the speed is always positive, and the limit is cut to
//!   six decimals towards zero so that the target is never beyond it.
//! - Home (either direction: the stage's own home search, HT and OH, decides): `OR` is only
//!   taken in NOT REFERENCED, so the driver asks `TS` first. Not referenced: `OR`, `TE`.
//!   Referenced (READY or DISABLE): `RS` (a reset, back to NOT REFERENCED, as the EPICS CONEX
//!   driver does before every home), and `OR` follows from the first poll that finds the
//!   controller back in NOT REFERENCED, rather than after a fixed sleep; the status says
//!   moving meanwhile. The reset also restores what the controller keeps in EEPROM (software
//!   limits, gains) over what was set since. Nothing is homed or moved at initialisation or
//!   after a reconnection: a new connection forgets any home still waiting.
//! - Stop: `ST` (the controller decelerates at its current `AC`), `TE`.
//! - Enable: `MM1` / `MM0` (READY ↔ DISABLE), `TE`.
//! - High / low limit: nothing is sent, as the EPICS driver sends none. The controller keeps
//!   its own software limits (`SR`/`SL`, set by the lab with Newport's tools), which a jog
//!   reads; the record's DHLM/DLLM refuse a target before it is sent. Writing the record's
//!   limits would reconfigure the controller behind the lab's back (and the record's "no
//!   limits", both 0, would make SR = SL = 0: every move refused).
//! - Gains: `KP` / `KI` / `KD` = gain × 1e6 (the EPICS CONEX driver's scale; it writes the D
//!   gain to KI, mended here), `TE`. The controller takes gains outside READY only (the
//!   EPICS CONEX driver disables the servo around them, which would stop a motion): disable
//!   first, or `TE` reports the refusal.
//! - Set position: refused (`CommandError::Unsupported`): the controller has no command that
//!   redefines its position. Encoder ratio: nothing to send (the encoder is the stage's).
//! - Raw text: sent as written with `\r\n`; a reply is awaited when it is a query (ends with
//!   `?`, or `TB`, `TE`, `TH`, `TP`, `TS`, `VE`, `ZT`), and taken as it comes.
//!
//! **Poll and status.** Per channel `TS` (four hex digits of positioner errors, two of
//! controller state), then `TP` (position): EPICS reads `TP` first, and a motion that ends
//! between the two leaves its last steps out of the poll that says it is over. MSTA: DONE unless HOMING, MOVING or JOGGING/TRACKING
//! (the EPICS SMC100 driver reports a home as done at once, mended here); HOMED in READY,
//! DISABLE, MOVING and JOGGING; POSITION (the drive enabled, which CNEN mirrors) in every state
//! but DISABLE and CONFIGURATION, NOT REFERENCED included (it takes a home);
//! HOME in READY from HOMING (as EPICS: homed and not moved since); PLUS_LS / MINUS_LS from the
//! positive / negative end-of-run bits, whatever else is set (EPICS only sees them alone);
//! SLIP_STALL on a following error; PROBLEM on any other positioner error bit, the ESP stage
//! error state, or a state code the manual does not list; GAIN_SUPPORT always. DIRECTION is the
//! direction of the position's change while moving. The encoder is the stage's and is what TP
//! reads: encoder position = position, PRESENT unset. A positioner error bit that appears is
//! also reported once as `ReplyEvent::ControllerError` (code: the four hex digits).
//!
//! **Left out.** The keypad jog and CONEX-CC tracking modes (reported, never started), the
//! CONFIGURATION state's settings (home type and speed, stage parameters: raw text can reach
//! them), the SMC100PP's stepper specifics, and the CONEX-AGP/AGAP and DL variants.

use crate::protocol::{
    line_frame, line_text, CommandError, Frame, Protocol, Purpose, ReplyError, ReplyEvent, Request, VendorError,
};
use crate::scale::{ControllerUnit, Scale, ScaleSource};
use std::ops::RangeInclusive;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::Unit;
use zmotor_msgs::{DriverCommand, Gain};

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "newport_smc100";

/// The line terminator, both ways.
pub(crate) const TERMINATOR: &[u8] = b"\r\n";

/// Millimetres per record step unless the launch file says otherwise.
pub(crate) const DEFAULT_UNITS_PER_STEP: f64 = 0.0001;

/// The addresses a controller can have on the RS-485 chain.
pub(crate) const ADDRESSES: RangeInclusive<usize> = 1..=31;

/// The controller takes numbers of magnitude below this.
pub(crate) const LARGEST_VALUE: f64 = 1e12;

/// What a record gain of 1 is in the controller's KP, KI and KD.
pub(crate) const GAIN_SCALE: f64 = 1e6;

/// The controller state codes the driver tells apart (the last two hex digits of `TS`).
pub(crate) mod state {
    /// NOT REFERENCED with an ESP stage error (CONEX-CC: no parameters in memory).
    pub(crate) const NOT_REFERENCED_ESP_STAGE_ERROR: u8 = 0x10;
    /// READY after a home search.
    pub(crate) const READY_FROM_HOMING: u8 = 0x32;
}

/// Positioner error bits (the first four hex digits of `TS`).
pub(crate) mod errors {
    /// The stage is on its negative end-of-run switch.
    pub(crate) const NEGATIVE_END_OF_RUN: u16 = 0x0001;
    /// The stage is on its positive end-of-run switch.
    pub(crate) const POSITIVE_END_OF_RUN: u16 = 0x0002;
    /// Following error.
    pub(crate) const FOLLOWING_ERROR: u16 = 0x0020;
    /// Every bit that is a fault (all but the end-of-run switches).
    pub(crate) const FAULTS: u16 = 0x03FC;
}

/// What a state code means for motion, as a family of states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum StateClass {
    /// Not homed since power-up, reset, a failed home or an end of run: only `OR` moves it.
    NotReferenced,
    /// Stage parameters being edited.
    Configuration,
    /// A home search.
    Homing,
    /// A move.
    Moving,
    /// Homed, servo on, at rest.
    Ready,
    /// Homed, servo off.
    Disable,
    /// A keypad jog (SMC100) or tracking (CONEX-CC).
    Jogging,
}

/// The family of a state code; None for a code the manual does not list.
pub(crate) fn state_class(code: u8) -> Option<StateClass> {
    match code {
        0x0A..=0x11 => Some(StateClass::NotReferenced),
        0x14 => Some(StateClass::Configuration),
        0x1E | 0x1F => Some(StateClass::Homing),
        0x28 => Some(StateClass::Moving),
        0x32..=0x38 => Some(StateClass::Ready),
        0x3C..=0x3F => Some(StateClass::Disable),
        0x46 | 0x47 => Some(StateClass::Jogging),
        _ => None,
    }
}

/// What a TE error letter means, as the manual words it.
pub(crate) fn error_meaning(code: char) -> Option<&'static str> {
    Some(match code {
        '@' => "No error",
        'A' => "Unknown message code or floating point controller address",
        'B' => "Controller address not correct",
        'C' => "Parameter missing or out of range",
        'D' => "Command not allowed",
        'E' => "Home sequence already started",
        'F' => "ESP stage name unknown",
        'G' => "Displacement out of limits",
        'H' => "Command not allowed in NOT REFERENCED state",
        'I' => "Command not allowed in CONFIGURATION state",
        'J' => "Command not allowed in DISABLE state",
        'K' => "Command not allowed in READY state",
        'L' => "Command not allowed in HOMING state",
        'M' => "Command not allowed in MOVING state",
        'N' => "Current position out of software limit",
        'P' => "Command not allowed in TRACKING state",
        'S' => "Communication time-out",
        'U' => "Error during EEPROM access",
        'V' => "Error during command execution",
        'W' => "Command not allowed for PP version",
        'X' => "Command not allowed for CC version",
        _ => return None,
    })
}

/// The positioner faults set in `bits`, in words.
pub(crate) fn fault_names(bits: u16) -> String {
    const NAMES: [(u16, &str); 8] = [
        (0x0200, "80 W output power exceeded"),
        (0x0100, "DC voltage too low"),
        (0x0080, "wrong ESP stage"),
        (0x0040, "homing time-out"),
        (errors::FOLLOWING_ERROR, "following error"),
        (0x0010, "short circuit detection"),
        (0x0008, "RMS current limit"),
        (0x0004, "peak current limit"),
    ];
    let names: Vec<&str> = NAMES.iter().filter(|(bit, _)| bits & bit != 0).map(|(_, name)| *name).collect();
    names.join(", ")
}

/// The MSTA bits of a `TS` reply (see the module documentation).
pub(crate) fn msta_of(error_bits: u16, state_code: u8) -> u32 {
    use StateClass::*;
    let class = state_class(state_code);
    let moving = matches!(class, Some(Homing | Moving | Jogging));
    let mut bits = msta::GAIN_SUPPORT;
    for (on, bit) in [
        (!moving, msta::DONE),
        (moving, msta::MOVING),
        (matches!(class, Some(Ready | Disable | Moving | Jogging)), msta::HOMED),
        // The drive is enabled (CNEN follows) in every state but DISABLE and CONFIGURATION:
        // a controller not referenced yet takes a home, so the record must not see it disabled.
        (matches!(class, Some(NotReferenced | Ready | Moving | Homing | Jogging)), msta::POSITION),
        (state_code == state::READY_FROM_HOMING, msta::HOME),
        (error_bits & errors::POSITIVE_END_OF_RUN != 0, msta::PLUS_LS),
        (error_bits & errors::NEGATIVE_END_OF_RUN != 0, msta::MINUS_LS),
        (error_bits & errors::FOLLOWING_ERROR != 0, msta::SLIP_STALL),
        (
            error_bits & errors::FAULTS != 0 || class.is_none() || state_code == state::NOT_REFERENCED_ESP_STAGE_ERROR,
            msta::PROBLEM,
        ),
    ] {
        if on {
            bits |= bit;
        }
    }
    bits
}

/// A number as the driver writes it: six decimals, as C's `%f`.
pub(crate) fn decimal(value: f64) -> String {
    format!("{value:.6}")
}

/// A request of the SMC100.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// `TE` at initialisation: an error stored before this connection, read and dropped.
    StaleError,
    /// A query of a poll or of a command, whose reply the protocol reads.
    Query {
        /// The controller asked.
        channel: usize,
        /// What it reads.
        query: Query,
    },
    /// A setter of a command: silent.
    Setter {
        /// The controller commanded.
        channel: usize,
    },
    /// Raw text: the user's own exchange, whatever the controller says.
    Raw {
        /// The controller it goes with.
        channel: usize,
    },
}

/// What a query reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Query {
    /// `TS` of a poll: the positioner errors and the controller state.
    State,
    /// `TP` of a poll, after its `TS`: the position.
    Position,
    /// `TE` after a command: its error letter.
    Error,
    /// `TS` before a home: is a reset needed first?
    HomeState,
    /// `SR?` or `SL?`: where a jog runs to.
    JogLimit,
}

/// A motion waiting for a reply before it can go on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    /// A jog, for the software limit it runs to.
    Jog,
    /// A home, for the state that says whether a reset must come first.
    Home,
    /// A home, for the controller to be back from its reset (NOT REFERENCED) to send `OR`.
    HomeAfterReset,
}

/// What the protocol keeps of one controller.
#[derive(Clone, Copy, Debug, Default)]
struct ChannelState {
    /// The MSTA bits of this poll's `TS`, waiting for the position its `TP` reads next.
    polled: Option<u32>,
    /// The status reported last.
    reported: DeviceStatus,
    /// The fault bits of the last `TS`: a fault is reported once, when it appears.
    faults: u16,
    pending: Option<Pending>,
}

/// The SMC100 / CONEX-CC protocol (see the module documentation).
#[derive(Debug)]
pub(crate) struct Smc100 {
    units_per_step: f64,
    /// Where `units_per_step` comes from.
    source: ScaleSource,
    /// Indexed by address.
    channels: Vec<ChannelState>,
}

impl Smc100 {
    /// A protocol at `units_per_step` millimetres per record step (None: the default). A value
    /// that is not a positive number cannot scale anything: the default is used, and said.
    pub(crate) fn new(units_per_step: Option<f64>) -> Self {
        let (units_per_step, source) = match units_per_step {
            None => (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault),
            Some(u) if u.is_finite() && u > 0.0 => (u, ScaleSource::Installation),
            Some(u) => {
                tracing::warn!(
                    "{NAME}: units_per_step {u} is not a positive number; using {DEFAULT_UNITS_PER_STEP} mm"
                );
                (DEFAULT_UNITS_PER_STEP, ScaleSource::ProtocolDefault)
            }
        };
        Self { units_per_step, source, channels: vec![ChannelState::default(); ADDRESSES.end() + 1] }
    }

    /// Steps as millimetres, if the controller can take them.
    fn millimetres(&self, what: &'static str, steps: f64) -> Result<f64, CommandError> {
        let mm = steps * self.units_per_step;
        if mm.is_finite() && mm.abs() < LARGEST_VALUE {
            Ok(mm)
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    /// A speed or acceleration in steps as a positive rate in millimetres that survives six
    /// decimals.
    fn rate(&self, what: &'static str, steps: f64) -> Result<f64, CommandError> {
        let mm = self.millimetres(what, steps)?;
        if (mm * 1e6).round() >= 1.0 {
            Ok(mm)
        } else {
            Err(CommandError::OutOfRange { what, value: steps })
        }
    }

    fn speed_and_acceleration(
        &self,
        channel: usize,
        velocity: f64,
        acceleration: f64,
    ) -> Result<Vec<Request<Step>>, CommandError> {
        let speed = self.rate("velocity", velocity.abs())?;
        let acceleration = self.rate("acceleration", acceleration)?;
        Ok(vec![
            setter(channel, &format!("VA{}", decimal(speed))),
            setter(channel, &format!("AC{}", decimal(acceleration))),
        ])
    }

    /// The requests of `command`, and what it leaves waiting.
    fn requests(
        &self,
        channel: usize,
        command: &DriverCommand,
    ) -> Result<(Vec<Request<Step>>, Option<Pending>), CommandError> {
        let mut requests = match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let (what, verb) = if *relative { ("distance", "PR") } else { ("target", "PA") };
                let mm = self.millimetres(what, *position)?;
                let mut requests = self.speed_and_acceleration(channel, *max_velocity, *acceleration)?;
                requests.push(setter(channel, &format!("{verb}{}", decimal(mm))));
                requests
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let mut requests = self.speed_and_acceleration(channel, *max_velocity, *acceleration)?;
                let limit = if *max_velocity > 0.0 { "SR?" } else { "SL?" };
                requests.push(Request::query(line(channel, limit), Step::Query { channel, query: Query::JogLimit }));
                return Ok((requests, Some(Pending::Jog)));
            }
            DriverCommand::Home { .. } => {
                let ask = Request::query(line(channel, "TS"), Step::Query { channel, query: Query::HomeState });
                return Ok((vec![ask], Some(Pending::Home)));
            }
            DriverCommand::Stop { .. } => vec![setter(channel, "ST")],
            DriverCommand::SetPosition { .. } => {
                return Err(CommandError::Unsupported { protocol: NAME, what: "redefine its position" })
            }
            DriverCommand::Enable { on } => vec![setter(channel, if *on { "MM1" } else { "MM0" })],
            DriverCommand::SetGain { gain, value } => {
                let scaled = value * GAIN_SCALE;
                if !(scaled.is_finite() && (0.0..LARGEST_VALUE).contains(&scaled)) {
                    return Err(CommandError::OutOfRange { what: "gain", value: *value });
                }
                let verb = match gain {
                    Gain::Proportional => "KP",
                    Gain::Integral => "KI",
                    Gain::Derivative => "KD",
                };
                vec![setter(channel, &format!("{verb}{}", decimal(scaled)))]
            }
            DriverCommand::Raw { text } => {
                let bytes = format!("{text}\r\n").into_bytes();
                let step = Step::Raw { channel };
                let request =
                    if raw_is_query(text) { Request::query(bytes, step) } else { Request::silent(bytes, step) };
                return Ok((vec![request], None));
            }
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::Poll => return Ok((Vec::new(), None)),
        };
        requests.push(error_query(channel));
        Ok((requests, None))
    }

    /// A fault among `error_bits` of `channel`'s `TS` that was not there before, to report once.
    fn new_fault(&mut self, channel: usize, error_bits: u16) -> Option<ReplyEvent<Step>> {
        let memory = &mut self.channels[channel];
        let faults = error_bits & errors::FAULTS;
        let appeared = faults & !memory.faults;
        memory.faults = faults;
        (appeared != 0).then(|| {
            ReplyEvent::ControllerError(VendorError {
                channel: Some(channel),
                code: format!("{error_bits:04X}"),
                meaning: fault_names(faults),
            })
        })
    }

    /// A poll's `TS`: the channel's state, kept for its `TP`; a fault newly reported, and the
    /// `OR` of a home once its reset is over.
    fn on_poll_state(&mut self, channel: usize, error_bits: u16, state_code: u8) -> Vec<ReplyEvent<Step>> {
        let mut bits = msta_of(error_bits, state_code);
        let mut events = Vec::new();
        if self.channels[channel].pending == Some(Pending::HomeAfterReset) {
            self.channels[channel].pending = None;
            if state_class(state_code) == Some(StateClass::NotReferenced) {
                events.push(ReplyEvent::FollowUp(vec![setter(channel, "OR"), error_query(channel)]));
                // The home search starts now: the motion is not over.
                bits = (bits | msta::MOVING) & !msta::DONE;
            } else {
                events.push(ReplyEvent::ControllerError(VendorError {
                    channel: Some(channel),
                    code: "RS".to_string(),
                    meaning: format!("the controller did not reset (state {state_code:02X}): the home was not started"),
                }));
            }
        }
        self.channels[channel].polled = Some(bits);
        events.extend(self.new_fault(channel, error_bits));
        events
    }

    /// A poll's `TP`, read after its `TS` (a poll that finds a motion over has the final
    /// position): the channel's status.
    fn on_poll_position(&mut self, channel: usize, position: f64) -> Vec<ReplyEvent<Step>> {
        let memory = &mut self.channels[channel];
        let Some(mut bits) = memory.polled.take() else {
            return Vec::new();
        };
        if bits & msta::MOVING != 0 && position > memory.reported.position {
            bits |= msta::DIRECTION;
        }
        let status = DeviceStatus { position, encoder_position: position, velocity: 0.0, msta: bits, readback: None };
        memory.reported = status;
        vec![ReplyEvent::Status { channel, status }]
    }

    /// The state before a home: `OR` at once when not referenced, else a reset first.
    fn on_home_state(&mut self, channel: usize, state_code: u8) -> Vec<ReplyEvent<Step>> {
        if self.channels[channel].pending != Some(Pending::Home) {
            // A stop or another command came since: the home is called off.
            return Vec::new();
        }
        let referenced = matches!(state_class(state_code), Some(StateClass::Ready | StateClass::Disable));
        if referenced {
            self.channels[channel].pending = Some(Pending::HomeAfterReset);
            vec![ReplyEvent::FollowUp(vec![setter(channel, "RS")])]
        } else {
            // Not referenced, or a state in which the controller's own refusal says why not.
            self.channels[channel].pending = None;
            vec![ReplyEvent::FollowUp(vec![setter(channel, "OR"), error_query(channel)])]
        }
    }

    /// The software limit a jog runs to: the move there.
    fn on_jog_limit(&mut self, channel: usize, limit: f64) -> Vec<ReplyEvent<Step>> {
        if self.channels[channel].pending != Some(Pending::Jog) {
            return Vec::new();
        }
        self.channels[channel].pending = None;
        // Six decimals towards zero: never a hair beyond the limit, which the controller refuses.
        let target = (limit * 1e6).trunc() / 1e6;
        vec![ReplyEvent::FollowUp(vec![setter(channel, &format!("PA{}", decimal(target))), error_query(channel)])]
    }
}

impl Default for Smc100 {
    fn default() -> Self {
        Self::new(None)
    }
}

/// `<address><command>` as one request line.
fn line(channel: usize, command: &str) -> Vec<u8> {
    format!("{channel}{command}\r\n").into_bytes()
}

fn setter(channel: usize, command: &str) -> Request<Step> {
    Request::silent(line(channel, command), Step::Setter { channel })
}

fn error_query(channel: usize) -> Request<Step> {
    Request::query(line(channel, "TE"), Step::Query { channel, query: Query::Error })
}

/// Whether raw text is a query the controller answers.
fn raw_is_query(text: &str) -> bool {
    let compact: String = text.chars().filter(|c| !c.is_whitespace()).collect();
    let command = compact.trim_start_matches(|c: char| c.is_ascii_digit()).to_ascii_uppercase();
    command.ends_with('?') || ["TB", "TE", "TH", "TP", "TS", "VE", "ZT"].iter().any(|q| command.starts_with(q))
}

/// The echo a reply to `request` starts with: its address and two-letter command.
fn echo_of(request: &Request<Step>) -> String {
    let text = line_text(&request.bytes, TERMINATOR);
    let digits = text.chars().take_while(char::is_ascii_digit).count();
    text.chars().take(digits + 2).collect::<String>().to_ascii_uppercase()
}

/// The positioner error bits and state code of a `TS` value: six hex digits.
fn parse_state(value: &str) -> Option<(u16, u8)> {
    if value.len() != 6 || !value.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    Some((u16::from_str_radix(&value[..4], 16).ok()?, u8::from_str_radix(&value[4..], 16).ok()?))
}

impl Protocol for Smc100 {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    /// In its NOT REFERENCED states the controller takes no move (error H, "Command not
    /// allowed in NOT REFERENCED state"); HOMED is off exactly there.
    fn moves_need_reference(&self, _channel: usize) -> bool {
        true
    }

    fn scale(&self, _channel: usize) -> Scale {
        // The stage's unit: mm on a linear stage, degrees on a rotary one.
        let unit = ControllerUnit::Physical { linear: Unit::MM, rotary: Unit::DEG };
        Scale { units_per_step: self.units_per_step, unit, source: self.source }
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::StaleError => Purpose::Init,
            Step::Query { channel, query: Query::Position | Query::State } => Purpose::Poll { channel },
            Step::Query { channel, query: Query::Error | Query::HomeState | Query::JogLimit }
            | Step::Setter { channel }
            | Step::Raw { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        // A reply starts with its controller's address: anything before is noise (a NUL after
        // the motor power comes back, what is left of a garbled line, a stray terminator).
        match buffer.iter().take_while(|b| !b.is_ascii_digit()).count() {
            0 => line_frame(buffer, TERMINATOR),
            noise => Frame::Junk(noise),
        }
    }

    fn init(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        // Nothing a previous connection left waiting goes on (no home after a reconnection);
        // an error stored before now is read and dropped, so that the first command's TE is
        // its own. Nothing moves, nothing is reset.
        self.channels.fill(ChannelState::default());
        channels
            .iter()
            .filter(|c| ADDRESSES.contains(c))
            .map(|&c| Request::query(line(c, "TE"), Step::StaleError))
            .collect()
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels.iter().filter(|c| ADDRESSES.contains(c)) {
            // `TS` before `TP` (as EPICS the other way round): the poll that finds a motion
            // over then reads the position after it ended, so DMOV 1 has the final readback.
            for (query, letters) in [(Query::State, "TS"), (Query::Position, "TP")] {
                requests.push(Request::query(line(channel, letters), Step::Query { channel, query }));
            }
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        if !ADDRESSES.contains(&channel) {
            return Err(CommandError::OutOfRange { what: "controller address", value: channel as f64 });
        }
        let (requests, pending) = self.requests(channel, command)?;
        if !requests.is_empty() {
            // Whatever goes out supersedes a jog or home still waiting for a reply.
            self.channels[channel].pending = pending;
        }
        Ok(requests)
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let read = match request.step {
            Step::Query { channel, query } => Some((channel, query)),
            Step::StaleError => None,
            // A setter is not answered; raw text is the user's own exchange: whatever the
            // controller says.
            Step::Setter { .. } | Step::Raw { .. } => return Ok(Vec::new()),
        };
        let text = line_text(frame, TERMINATOR);
        let value = text
            .strip_prefix(echo_of(request).as_str())
            .map(str::trim)
            .ok_or_else(|| ReplyError::new(request, frame, "not the echo of the request"))?;
        let Some((channel, query)) = read.filter(|(channel, _)| ADDRESSES.contains(channel)) else {
            // The error read at initialisation was left from before: dropped.
            return Ok(Vec::new());
        };
        match query {
            Query::Position => {
                let mm: f64 = value.parse().map_err(|_| ReplyError::new(request, frame, "not a position"))?;
                if !mm.is_finite() {
                    return Err(ReplyError::new(request, frame, "not a position"));
                }
                // A millionth of a step drops the noise of decimal millimetres in binary.
                Ok(self.on_poll_position(channel, (mm / self.units_per_step * 1e6).round() / 1e6))
            }
            Query::State | Query::HomeState => {
                let (error_bits, state_code) =
                    parse_state(value).ok_or_else(|| ReplyError::new(request, frame, "not six hex digits"))?;
                Ok(if query == Query::State {
                    self.on_poll_state(channel, error_bits, state_code)
                } else {
                    self.on_home_state(channel, state_code)
                })
            }
            Query::JogLimit => {
                let limit: f64 = value.parse().map_err(|_| ReplyError::new(request, frame, "not a limit"))?;
                if !limit.is_finite() {
                    return Err(ReplyError::new(request, frame, "not a limit"));
                }
                Ok(self.on_jog_limit(channel, limit))
            }
            Query::Error => {
                let mut letters = value.chars();
                let (Some(code), None) = (letters.next(), letters.next()) else {
                    return Err(ReplyError::new(request, frame, "not one error letter"));
                };
                if code == '@' {
                    return Ok(Vec::new());
                }
                let meaning = error_meaning(code).unwrap_or("an error code the manual does not list");
                Ok(vec![ReplyEvent::ControllerError(VendorError {
                    channel: Some(channel),
                    code: code.to_string(),
                    meaning: meaning.into(),
                })])
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    fn answered(requests: &[Request<Step>]) -> Vec<bool> {
        requests.iter().map(|r| r.answered).collect()
    }

    fn go(position: f64, relative: bool) -> DriverCommand {
        DriverCommand::Move { position, relative, min_velocity: 0.0, max_velocity: 10_000.0, acceleration: 50_000.0 }
    }

    fn jog(velocity: f64) -> DriverCommand {
        DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: velocity, acceleration: 50_000.0 }
    }

    fn home() -> DriverCommand {
        DriverCommand::Home { forward: false, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 1000.0 }
    }

    fn follow_up(events: &[ReplyEvent<Step>]) -> Vec<String> {
        match events {
            [ReplyEvent::FollowUp(requests), ..] => sent(requests),
            _ => panic!("no follow-up first: {events:?}"),
        }
    }

    /// The status among `events`.
    fn status_of(events: &[ReplyEvent<Step>]) -> DeviceStatus {
        events
            .iter()
            .find_map(|e| match e {
                ReplyEvent::Status { status, .. } => Some(*status),
                _ => None,
            })
            .unwrap_or_else(|| panic!("no status: {events:?}"))
    }

    /// Run one poll of `channel` with these replies (`TS` is asked first): the events of both.
    fn polled(p: &mut Smc100, channel: usize, tp: &[u8], ts: &[u8]) -> Vec<ReplyEvent<Step>> {
        let poll = p.poll(&[channel]);
        let mut events = p.reply(&poll[0], ts).unwrap();
        events.extend(p.reply(&poll[1], tp).unwrap());
        events
    }

    #[test]
    fn moves_set_speed_and_acceleration_then_go_then_read_the_error() {
        let mut p = Smc100::default();
        let requests = p.command(1, &go(125_000.0, false)).unwrap();
        assert_eq!(sent(&requests), ["1VA1.000000\r\n", "1AC5.000000\r\n", "1PA12.500000\r\n", "1TE\r\n"]);
        assert_eq!(answered(&requests), [false, false, false, true]);
        assert_eq!(sent(&p.command(12, &go(-5000.4, true)).unwrap())[2], "12PR-0.500040\r\n");
        let scaled = &mut Smc100::new(Some(0.00005));
        assert_eq!(
            sent(&scaled.command(1, &go(250_000.0, false)).unwrap())[..3],
            ["1VA0.500000\r\n", "1AC2.500000\r\n", "1PA12.500000\r\n"]
        );
    }

    #[test]
    fn millimetres_per_step_default_to_a_tenth_of_a_micrometre_and_nonsense_is_not_taken() {
        assert_eq!(Smc100::new(None).units_per_step, 0.0001);
        assert_eq!(Smc100::new(Some(0.00005)).units_per_step, 0.00005);
        for nonsense in [0.0, -0.0001, f64::NAN, f64::INFINITY] {
            assert_eq!(Smc100::new(Some(nonsense)).units_per_step, DEFAULT_UNITS_PER_STEP, "{nonsense}");
        }
    }

    #[test]
    fn values_the_controller_cannot_take_are_refused_not_clamped() {
        let mut p = Smc100::default();
        let refused = |r: Result<Vec<Request<Step>>, CommandError>| matches!(r, Err(CommandError::OutOfRange { .. }));
        assert!(refused(p.command(1, &go(1e16, false))), "beyond 1e12 mm");
        assert!(refused(p.command(1, &go(f64::NAN, true))));
        let crawl = DriverCommand::Move {
            position: 1.0,
            relative: true,
            min_velocity: 0.0,
            max_velocity: 0.001,
            acceleration: 1.0,
        };
        assert!(refused(p.command(1, &crawl)), "a speed that is 0.000000 mm/s");
        assert!(refused(p.command(0, &go(1.0, false))), "address 0");
        assert!(refused(p.command(32, &go(1.0, false))), "address 32");
        assert!(refused(p.command(1, &DriverCommand::SetGain { gain: Gain::Proportional, value: -0.5 })));
        assert!(matches!(
            p.command(1, &DriverCommand::SetPosition { position: 0.0 }),
            Err(CommandError::Unsupported { .. })
        ));
    }

    #[test]
    fn every_other_command_is_one_setter_and_its_error_check() {
        let mut p = Smc100::default();
        let mut bytes = |c: DriverCommand| sent(&p.command(3, &c).unwrap());
        assert_eq!(bytes(DriverCommand::Stop { acceleration: 1.0 }), ["3ST\r\n", "3TE\r\n"]);
        assert_eq!(bytes(DriverCommand::Enable { on: true }), ["3MM1\r\n", "3TE\r\n"]);
        assert_eq!(bytes(DriverCommand::Enable { on: false }), ["3MM0\r\n", "3TE\r\n"]);
        assert!(bytes(DriverCommand::SetHighLimit { position: 0.0 }).is_empty(), "the controller keeps its own");
        assert!(bytes(DriverCommand::SetLowLimit { position: -50_000.0 }).is_empty());
        assert_eq!(
            bytes(DriverCommand::SetGain { gain: Gain::Proportional, value: 0.25 }),
            ["3KP250000.000000\r\n", "3TE\r\n"]
        );
        assert_eq!(bytes(DriverCommand::SetGain { gain: Gain::Integral, value: 0.5 })[0], "3KI500000.000000\r\n");
        assert_eq!(bytes(DriverCommand::SetGain { gain: Gain::Derivative, value: 0.001 })[0], "3KD1000.000000\r\n");
        assert_eq!(bytes(DriverCommand::SetEncoderRatio { ratio: 2.0 }), Vec::<String>::new());
        assert_eq!(bytes(DriverCommand::Poll), Vec::<String>::new());
    }

    #[test]
    fn raw_text_is_sent_as_written_and_awaits_a_reply_only_when_a_query() {
        let mut p = Smc100::default();
        for (text, query) in [("1VE", true), ("1SR?", true), ("1 tp", true), ("1PW1", false), ("2OH 2.5", false)] {
            let requests = p.command(1, &DriverCommand::Raw { text: text.into() }).unwrap();
            assert_eq!(sent(&requests), [format!("{text}\r\n")]);
            assert_eq!(answered(&requests), [query], "{text}");
            assert_eq!(p.reply(&requests[0], b"anything at all\r\n").unwrap(), []);
        }
    }

    #[test]
    fn a_jog_reads_the_limit_in_its_direction_then_moves_there() {
        let mut p = Smc100::default();
        let up = p.command(1, &jog(20_000.0)).unwrap();
        assert_eq!(sent(&up), ["1VA2.000000\r\n", "1AC5.000000\r\n", "1SR?\r\n"]);
        assert_eq!(answered(&up), [false, false, true]);
        assert_eq!(follow_up(&p.reply(&up[2], b"1SR12.5\r\n").unwrap()), ["1PA12.500000\r\n", "1TE\r\n"]);
        // Down: a positive speed (the EPICS driver's negative VA is refused by the controller),
        // and a limit with more decimals than sent is cut towards zero, never beyond.
        let down = p.command(1, &jog(-20_000.0)).unwrap();
        assert_eq!(sent(&down), ["1VA2.000000\r\n", "1AC5.000000\r\n", "1SL?\r\n"]);
        assert_eq!(follow_up(&p.reply(&down[2], b"1SL-5.0000009\r\n").unwrap())[0], "1PA-5.000000\r\n");
    }

    #[test]
    fn a_stop_calls_off_a_jog_still_waiting_for_its_limit() {
        let mut p = Smc100::default();
        let up = p.command(1, &jog(20_000.0)).unwrap();
        p.command(1, &DriverCommand::Stop { acceleration: 1.0 }).unwrap();
        assert_eq!(p.reply(&up[2], b"1SR12.5\r\n").unwrap(), [], "no move after the stop");
    }

    #[test]
    fn a_home_when_not_referenced_is_or_at_once() {
        let mut p = Smc100::default();
        let ask = p.command(1, &home()).unwrap();
        assert_eq!(sent(&ask), ["1TS\r\n"]);
        assert_eq!(follow_up(&p.reply(&ask[0], b"1TS00000A\r\n").unwrap()), ["1OR\r\n", "1TE\r\n"]);
        // Nothing is left waiting: the next poll sends nothing more.
        assert_eq!(polled(&mut p, 1, b"1TP0\r\n", b"1TS00000A\r\n").len(), 1);
    }

    #[test]
    fn a_home_when_referenced_resets_first_and_homes_once_the_controller_is_back() {
        let mut p = Smc100::default();
        let ask = p.command(2, &home()).unwrap();
        assert_eq!(follow_up(&p.reply(&ask[0], b"2TS000033\r\n").unwrap()), ["2RS\r\n"]);
        let events = polled(&mut p, 2, b"2TP3.2\r\n", b"2TS00000A\r\n");
        assert_eq!(follow_up(&events), ["2OR\r\n", "2TE\r\n"]);
        let status = status_of(&events);
        assert_eq!(status.msta & (msta::DONE | msta::MOVING), msta::MOVING, "the home is under way");
        // Once only.
        let events = polled(&mut p, 2, b"2TP3.2\r\n", b"2TS00001E\r\n");
        assert!(!matches!(events[0], ReplyEvent::FollowUp(_)), "{events:?}");
    }

    #[test]
    fn a_reset_that_did_not_happen_is_reported_and_nothing_homes() {
        let mut p = Smc100::default();
        let ask = p.command(1, &home()).unwrap();
        p.reply(&ask[0], b"1TS000032\r\n").unwrap();
        let events = polled(&mut p, 1, b"1TP0\r\n", b"1TS000032\r\n");
        assert!(events.iter().all(|e| !matches!(e, ReplyEvent::FollowUp(_))), "{events:?}");
        assert!(events
            .iter()
            .any(|e| matches!(e, ReplyEvent::ControllerError(VendorError { code, .. }) if code == "RS")));
    }

    #[test]
    fn a_new_connection_forgets_a_home_waiting_for_its_reset() {
        let mut p = Smc100::default();
        let ask = p.command(1, &home()).unwrap();
        p.reply(&ask[0], b"1TS000033\r\n").unwrap();
        let init = p.init(&[1, 4, 0]);
        assert_eq!(sent(&init), ["1TE\r\n", "4TE\r\n"], "an error left from before is read; address 0 is none");
        assert_eq!(p.reply(&init[0], b"1TEK\r\n").unwrap(), [], "and dropped");
        let events = polled(&mut p, 1, b"1TP0\r\n", b"1TS00000A\r\n");
        assert!(events.iter().all(|e| !matches!(e, ReplyEvent::FollowUp(_))), "no home after a reconnection");
    }

    #[test]
    fn a_poll_reads_state_then_position() {
        let mut p = Smc100::default();
        let poll = p.poll(&[1, 0, 2, 40]);
        assert_eq!(sent(&poll), ["1TS\r\n", "1TP\r\n", "2TS\r\n", "2TP\r\n"], "only addresses 1 to 31");
        let status = status_of(&polled(&mut p, 1, b"1TP-1.2345\r\n", b"1TS000032\r\n"));
        assert_eq!(status.position, -12_345.0);
        assert_eq!(status.encoder_position, -12_345.0);
        let ready_after_home = msta::DONE | msta::HOMED | msta::POSITION | msta::HOME | msta::GAIN_SUPPORT;
        assert_eq!(status.msta, ready_after_home);
        let status = status_of(&polled(&mut p, 1, b"1TP 3.2\r\n", b"1TS000028\r\n"));
        let moving_up = msta::MOVING | msta::HOMED | msta::POSITION | msta::GAIN_SUPPORT | msta::DIRECTION;
        assert_eq!((status.position, status.msta), (32_000.0, moving_up));
    }

    #[test]
    fn states_map_to_msta() {
        let base = msta::GAIN_SUPPORT;
        let cases = [
            (0x0000, 0x0A, msta::DONE | msta::POSITION),
            (0x0000, 0x1E, msta::MOVING | msta::POSITION),
            (0x0000, 0x28, msta::MOVING | msta::POSITION | msta::HOMED),
            (0x0000, 0x33, msta::DONE | msta::POSITION | msta::HOMED),
            (0x0000, 0x3C, msta::DONE | msta::HOMED),
            (0x0000, 0x14, msta::DONE),
            (0x0000, 0x46, msta::MOVING | msta::POSITION | msta::HOMED),
            (0x0000, 0x10, msta::DONE | msta::POSITION | msta::PROBLEM),
            (0x0000, 0x99, msta::DONE | msta::PROBLEM),
            (0x0002, 0x0F, msta::DONE | msta::POSITION | msta::PLUS_LS),
            (0x0001, 0x33, msta::DONE | msta::POSITION | msta::HOMED | msta::MINUS_LS),
            // End of run with a current limit: EPICS sees no limit here; both show.
            (0x000A, 0x0F, msta::DONE | msta::POSITION | msta::PLUS_LS | msta::PROBLEM),
            (0x0020, 0x3D, msta::DONE | msta::HOMED | msta::SLIP_STALL | msta::PROBLEM),
            (0x0040, 0x0B, msta::DONE | msta::POSITION | msta::PROBLEM),
        ];
        for (error_bits, code, expected) in cases {
            assert_eq!(msta_of(error_bits, code), expected | base, "{error_bits:04X}{code:02X}");
        }
    }

    #[test]
    fn a_fault_is_reported_once_when_it_appears() {
        let mut p = Smc100::default();
        let events = polled(&mut p, 1, b"1TP0\r\n", b"1TS00203D\r\n");
        let [ReplyEvent::ControllerError(VendorError { channel: Some(1), code, meaning }), ReplyEvent::Status { .. }] =
            &events[..]
        else {
            panic!("{events:?}")
        };
        assert_eq!((code.as_str(), meaning.as_str()), ("0020", "following error"));
        assert_eq!(polled(&mut p, 1, b"1TP0\r\n", b"1TS00203D\r\n").len(), 1, "not again while it lasts");
        assert_eq!(polled(&mut p, 1, b"1TP0\r\n", b"1TS000034\r\n").len(), 1);
        assert_eq!(polled(&mut p, 1, b"1TP0\r\n", b"1TS00603D\r\n").len(), 2, "a new one is");
    }

    #[test]
    fn the_error_letter_becomes_a_controller_error_with_its_meaning() {
        let mut p = Smc100::default();
        let requests = p.command(5, &go(1.0, false)).unwrap();
        let te = &requests[3];
        assert_eq!(p.reply(te, b"5TE@\r\n").unwrap(), []);
        let events = p.reply(te, b"5TEH\r\n").unwrap();
        assert_eq!(
            events,
            [ReplyEvent::ControllerError(VendorError {
                channel: Some(5),
                code: "H".into(),
                meaning: "Command not allowed in NOT REFERENCED state".into()
            })]
        );
        assert!(p.reply(te, b"5TE\r\n").is_err());
        assert!(p.reply(te, b"5TEHK\r\n").is_err());
    }

    #[test]
    fn a_reply_that_is_not_the_echo_of_its_request_is_refused() {
        let mut p = Smc100::default();
        let poll = p.poll(&[1]);
        assert!(p.reply(&poll[1], b"2TP1.5\r\n").is_err(), "another controller's reply");
        assert!(p.reply(&poll[1], b"11TP1.5\r\n").is_err(), "controller 11 is not 1");
        assert!(p.reply(&poll[1], b"1TS000033\r\n").is_err(), "another query's reply");
        assert!(p.reply(&poll[1], b"1TPlots\r\n").is_err());
        assert!(p.reply(&poll[1], b"1TPinf\r\n").is_err());
        assert!(p.reply(&poll[0], b"1TS00033\r\n").is_err(), "five digits");
        assert!(p.reply(&poll[0], b"1TS+00033\r\n").is_err());
        assert!(p.reply(&poll[0], b"1TS0000ZZ\r\n").is_err());
        let eleven = p.poll(&[11]);
        assert!(p.reply(&eleven[1], b"1TP1.5\r\n").is_err());
        assert_eq!(p.reply(&eleven[1], b"11TP1.5\r\n").unwrap(), []);
    }

    #[test]
    fn replies_are_framed_at_crlf_whatever_the_pieces_and_noise_before_is_junk() {
        let p = Smc100::default();
        let reply = b"12TS000033\r\n";
        for cut in 0..reply.len() {
            assert_eq!(p.frame(&reply[..cut]), Frame::Incomplete, "{cut} bytes");
        }
        assert_eq!(p.frame(reply), Frame::Complete(reply.len()));
        let mut two = reply.to_vec();
        two.extend_from_slice(b"12TP1\r\n");
        assert_eq!(p.frame(&two), Frame::Complete(reply.len()));
        assert_eq!(p.frame(b"\0\x001TP1\r\n"), Frame::Junk(2), "NULs after a power cut");
        assert_eq!(p.frame(b"\r\n"), Frame::Junk(2), "a stray terminator");
        assert_eq!(p.frame(b"~~~~~"), Frame::Junk(5), "a garbled line");
        assert_eq!(p.frame(b"1TP1\r"), Frame::Incomplete, "CR alone does not end a line");
    }
}
