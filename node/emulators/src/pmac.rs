//! A Delta Tau Turbo PMAC2 as a Geo Brick carries it, reached over Ethernet (TCP port 1025):
//! packets of Delta Tau's Ethernet protocol around the Turbo PMAC's ASCII command language,
//! motors 1 to n on the physical simulator, one simulator step a PMAC count.
//!
//! # Witnesses
//!
//! 1. Delta Tau's "Turbo PMAC/PMAC2 Software Reference Manual" (Turbo SRM), read page by page as
//!    published (the Turbo PMAC2 PCI and Geo Brick LV editions, one text): the motor status
//!    words of `?` (p. 281: word 1 bit 19 amplifier enabled, 18 open loop, 17 move timer active,
//!    16 integration mode (Ixx34), 15 dwell, 14 data block error, 13 desired velocity zero;
//!    p. 284: word 2 bit 0 in position, and the example `#1?` → `81200001C401`: word 1 bit 23
//!    motor activated, word 2 bits 23–20 C.S. − 1, 19–16 axis definition, 15 assigned to a C.S.);
//!    `??` answers eighteen hex digits (p. 284); `V` reports counts per servo cycle, a cycle
//!    lasting I10/8,388,608 ms (p. 402); `VERSION`/`VER` answers e.g. `1.934` (p. 402);
//!    `<CTRL-P>` reports positions in counts rounded to 1/32 count, space-separated (p. 260);
//!    Ixx19 maximum jog/home acceleration, counts/ms², default 0.15625 (p. 100, whose text
//!    says 0.015625); Ixx21 S-curve time 50 ms, Ixx22 jog speed 32 counts/ms, Ixx23 home speed
//!    and direction 32 counts/ms (p. 101: the acceleration lasts Ixx20, or 2·Ixx21 when that is
//!    longer, and is lengthened so as not to exceed Ixx19); Ixx26 home offset in 1/16 count
//!    from the trigger to the home zero (p. 108).
//! 2. Delta Tau's (non-Turbo) "PMAC 2 Software Reference": I6 and its error list (I6=1:
//!    `<BELL>ERRnnn<CR>`; ERR003 "data error or unrecognized command", ERR004 "illegal
//!    character: bad value (>127 ASCII)…"); status bits of the same meaning as the Turbo ones:
//!    word 1 bit 12 abort deceleration, 10 home search in progress, word 2 bit 11 stopped on
//!    position limit (software or hardware, latched until the next move), 10 home complete;
//!    Ix13/Ix14 software limits (0: none).
//! 3. The "Ethernet Protocol" chapter of Delta Tau's UMAC Turbo CPU/Communications Board manual
//!    (the Acc-54E protocol, pp. 36–37): the 8-byte packet header `RequestType Request wValue
//!    wIndex wLength` (16-bit fields in network order), `VR_PMAC_READREADY` answering two bytes
//!    (the first non-zero when data waits), `VR_CTRL_RESPONSE` answering a control character
//!    (meaningful for ^B ^C ^F ^G ^P ^V only).
//! 4. dls-pmaclib (Diamond Light Source), `PmacEthernetInterface`: a command is sent as
//!    `0x40 0xBF 0 0 0 0 0 len` and the text, without terminator, and answered in one `recv`:
//!    values each followed by CR, then ACK; an error answer ends with CR and is passed up as it
//!    is. It checks `i6=1 i3=2 ver` against `^\d+\.\d+\s*\r\x06$`, takes `cid` 603382 for a
//!    Geo Brick, counts 8 axes plus 8 per MACRO IC whose base address (I20..I23) is not `$0`,
//!    reads Ixx24 as `$hex` and sets its bit $20000 to disable limits, polls with
//!    `0xC0 0xC5 0 0 0 0 0x08 0x00` (a 2048-byte `VR_PMAC_GETBUFFER`, no data after it) while a
//!    long answer has not ended with ACK, and jogs with `#nJ=`, `#nJ^`, `#nJ+`/`J-`, `#nJ/`,
//!    `#nHM`. Its table names ERR001 to ERR019 as the PMAC 2 manual does.
//!
//! Not read, taken from the Turbo layout as it is known: word 1 bits 22 and 21 (negative,
//! positive end limit set) and word 2 bit 2 (fatal following error). The Turbo SRM's example
//! puts "amplifier enabled" at word 2 bit 14, the PMAC 2 place; its bit table says word 1 bit
//! 19, which this emulator follows (word 2 bit 14 stays clear). `P` is taken to round as
//! `<CTRL-P>` does.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Framing.** A `VR_DOWNLOAD` (0x40) packet carries `wLength` bytes of data (1492 at most,
//!   else the input is dropped and counted as malformed); a `VR_UPLOAD` (0xC0) packet carries
//!   none, its `wLength` being what the host will read. Any other request type, or a request
//!   this emulator does not serve (`VR_PMAC_SENDLINE`, `GETLINE`, `WRITEBUFFER`, `PORT`…), is
//!   counted as malformed and not answered.
//! - **Answers.** Whatever I3 and I6 say, a command line is answered as with I3=2 and I6=1 (their
//!   power-on values here, and what every Ethernet client sets). An answer longer than 1400
//!   bytes is sent in 1400-byte pieces, the rest for `VR_PMAC_GETBUFFER` (an empty buffer
//!   answers a lone ACK, which ends any reader's loop); `VR_PMAC_READREADY` tells whether some
//!   waits; `VR_PMAC_FLUSH` drops it and answers one byte, `@` (0x40), as a client of real units
//!   reports. A new command line drops what an earlier one left.
//! - **Errors.** A byte above 127 refuses the whole line with ERR004. Anything else not
//!   understood (unknown command, bad number, variable beyond 8191) refuses with ERR003 at that
//!   command: what the line reported before stays in front, what follows is not carried out.
//!   These count as malformed; ERR003 for what a PMAC has but this emulator does not carry out
//!   (`#n` beyond the motors installed, `O` open-loop output, jog-until-trigger) does not.
//! - **Control characters** (`VR_CTRL_RESPONSE`): ^B, ^F, ^P, ^V report motors 1–8, separated
//!   by spaces, then CR ACK; ^K kills every motor; every other answers a lone ACK.
//! - **Jogs** (`J+ J- J= J={c} J^{c} J:{c} J/`) run at Ixx22 with one constant acceleration:
//!   Ixx22 over the acceleration time (Ixx20, or 2·Ixx21 when longer), capped at Ixx19 (0: no
//!   cap); `HM` likewise at Ixx23, its sign the direction. Any jog or `HM` closes the loop of a
//!   killed motor first (the Turbo SRM, as remembered, says so of `J/`; taken for all of them,
//!   so that `#1K … #1J/` re-enables a motor). The pre-jog position `J=` returns to is where the
//!   motor was commanded to be when the last other jog began.
//! - **Software limits.** With Ixx13 (Ixx14) not 0, a jog's end is cut at it and an indefinite
//!   jog ends there; word 2 bit 11 "stopped on position limit" is then set until the next move,
//!   as it is after a stop at a limit switch. With Ixx24 bit 17 set, the limit switches no longer
//!   show in word 1 (bits 21, 22); they still stop the simulated carriage, which has no travel
//!   beyond them.
//! - **Home.** `HM` ends on the simulator's home switch (found from either side); the home zero
//!   lies Ixx26/16 counts beyond it, where the motor then goes and reads 0. Home complete is set
//!   when the switch is found, cleared when a search starts.
//! - **No following error.** The simulator follows its trajectory exactly: `F` is 0, in position
//!   holds whenever the loop is closed, no move is in progress and Ixx28 > 0, and the commanded
//!   and actual position registers are one. The suggested M-variables Mxx61 (commanded) and
//!   Mxx62 (actual position), in 1/(Ixx08·32) count, both read it and a write to either redefines
//!   it; Mxx40 reads the in-position bit, writes to it are taken and change nothing; other
//!   M-variables hold values. M-variable definitions (`Mn->…`) are taken and change nothing.
//! - **Formats.** Decimal values as the shortest decimal to 10 places; `P` rounded to 1/32 count,
//!   `V` to a tenth; I20–I23, Ixx24, Ixx25 as `$` and upper-case hex (I9=2). `???` answers twelve
//!   zeros, `&n??` eighteen (no coordinate system is set up, nothing is wrong).
//! - **Identity and defaults** not read: `cpu` DSP56321, `type` TURBO2, `date` 10/27/2011, `ver`
//!   1.947; Ixx24 $800001 (PMAC2-style flags, high-true amplifier fault), Ixx25 the flag
//!   registers of the Geo Brick's two servo ICs; Ixx08 96, Ixx28 160, Ixx30–Ixx34
//!   2000/1280/1280/0/1 as the Turbo SRM is remembered to give them; I10 3713707. `SAVE` and
//!   `$$$` are acknowledged and change nothing.

use crate::emulator::axes;
use crate::Emulator;
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::Gain;

/// Request types and requests of the Ethernet protocol.
const VR_DOWNLOAD: u8 = 0x40;
const VR_UPLOAD: u8 = 0xC0;
const VR_PMAC_FLUSH: u8 = 0xB3;
const VR_PMAC_GETRESPONSE: u8 = 0xBF;
const VR_PMAC_READREADY: u8 = 0xC2;
const VR_CTRL_RESPONSE: u8 = 0xC4;
const VR_PMAC_GETBUFFER: u8 = 0xC5;

/// The packet header's length, the most data a packet carries, the most an answer carries.
const HEADER: usize = 8;
const DATA_LIMIT: usize = 1492;
const REPLY_LIMIT: usize = 1400;

const ACK: u8 = 0x06;
const CR: u8 = b'\r';

/// I, P, Q and M variables are numbered 0 to 8191; a Turbo PMAC has 32 motors at most.
const VARIABLES: usize = 8192;
const MOST_MOTORS: usize = 32;

/// The Geo Brick's card ID (`cid`), firmware and CPU.
const IDENTITY: [(&[u8], &str); 6] = [
    (b"VERSION", "1.947"),
    (b"VER", "1.947"),
    (b"CID", "603382"),
    (b"CPU", "DSP56321"),
    (b"TYPE", "TURBO2"),
    (b"DATE", "10/27/2011"),
];

/// Motor xx's I-variables, Ixx00 to Ixx99: the ones this emulator acts on.
mod ixx {
    pub(super) const ACTIVATED: usize = 0;
    pub(super) const SCALE: usize = 8;
    pub(super) const POSITIVE_LIMIT: usize = 13;
    pub(super) const NEGATIVE_LIMIT: usize = 14;
    pub(super) const MAX_ACCELERATION: usize = 19;
    pub(super) const ACCELERATION_TIME: usize = 20;
    pub(super) const S_CURVE_TIME: usize = 21;
    pub(super) const JOG_SPEED: usize = 22;
    pub(super) const HOME_SPEED: usize = 23;
    pub(super) const FLAGS: usize = 24;
    pub(super) const FLAG_ADDRESS: usize = 25;
    pub(super) const HOME_OFFSET: usize = 26;
    pub(super) const IN_POSITION_BAND: usize = 28;
    pub(super) const PROPORTIONAL: usize = 30;
    pub(super) const DERIVATIVE: usize = 31;
    pub(super) const VELOCITY_FEED_FORWARD: usize = 32;
    pub(super) const INTEGRAL: usize = 33;
    pub(super) const INTEGRATION_MODE: usize = 34;
    /// Suggested M-variables: in-position bit, commanded and actual position registers.
    pub(super) const M_IN_POSITION: usize = 40;
    pub(super) const M_COMMANDED: usize = 61;
    pub(super) const M_ACTUAL: usize = 62;
}

/// Ixx24 bit 17: the overtravel limit inputs are not used.
const LIMITS_DISABLED: u32 = 0x2_0000;

/// The power-on value of Ixx`nn` of motor `motor` (1-based), of a controller with `installed`.
fn motor_default(motor: usize, nn: usize, installed: usize) -> f64 {
    // The flag registers of servo IC 0 ($078000…) and 1 ($078100…), four channels each.
    let flag_address = 0x07_8000 + 0x100 * ((motor - 1) / 4 % 2) + 8 * ((motor - 1) % 4);
    match nn {
        ixx::ACTIVATED => f64::from(u8::from(motor <= installed)),
        ixx::SCALE => 96.0,
        ixx::MAX_ACCELERATION => 0.156_25,
        ixx::S_CURVE_TIME => 50.0,
        ixx::JOG_SPEED | ixx::HOME_SPEED => 32.0,
        ixx::FLAGS => f64::from(0x80_0001),
        ixx::FLAG_ADDRESS => flag_address as f64,
        ixx::IN_POSITION_BAND => 160.0,
        ixx::PROPORTIONAL => 2000.0,
        ixx::DERIVATIVE | ixx::VELOCITY_FEED_FORWARD => 1280.0,
        ixx::INTEGRATION_MODE => 1.0,
        _ => 0.0,
    }
}

/// Whether I`n` is reported in hexadecimal: the MACRO IC base addresses, a motor's flag words.
fn hexadecimal(n: usize) -> bool {
    (20..=23).contains(&n) || ((100..100 * (MOST_MOTORS + 1)).contains(&n) && matches!(n % 100, 24 | 25))
}

/// Why a command line stops.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Refusal {
    /// ERR003, the host's fault: unknown command, bad number or variable.
    Syntax,
    /// ERR003 for something a PMAC has and this one does not do.
    Unsupported,
    /// ERR004: a byte above 127.
    IllegalCharacter,
}

/// What a motor is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Motion {
    Idle,
    /// An indefinite jog, or a jog being stopped.
    Jog,
    /// A jog to a position: the move timer runs.
    JogTo,
    HomeSearch,
    /// From the home trigger to the home zero.
    HomeOffset,
}

/// One motor: its simulated axis and what the controller knows of it.
struct Motor {
    axis: SimAxis,
    closed_loop: bool,
    amplifier: bool,
    motion: Motion,
    /// Where the jog to a position in progress ends.
    target: Option<f64>,
    prejog: f64,
    home_complete: bool,
    fatal_following_error: bool,
    /// The move in progress was cut at a software limit.
    soft_limited: bool,
    stopped_on_limit: bool,
}

impl Motor {
    fn new(axis: SimAxis) -> Self {
        Self {
            axis,
            closed_loop: true,
            amplifier: true,
            motion: Motion::Idle,
            target: None,
            prejog: 0.0,
            home_complete: false,
            fatal_following_error: false,
            soft_limited: false,
            stopped_on_limit: false,
        }
    }

    fn position(&self) -> f64 {
        self.axis.status().position
    }

    /// Where the motor is commanded to be: the end of a jog to a position, else where it is.
    fn commanded(&self) -> f64 {
        self.target.unwrap_or_else(|| self.position())
    }

    fn close_loop(&mut self) {
        self.closed_loop = true;
        self.amplifier = true;
        self.fatal_following_error = false;
        self.axis.enable(true);
    }

    fn kill(&mut self) {
        self.axis.stop(0.0);
        self.axis.enable(false);
        self.closed_loop = false;
        self.amplifier = false;
        self.motion = Motion::Idle;
        self.target = None;
    }

    /// Starting a move: what the last one left is forgotten.
    fn start(&mut self, motion: Motion, target: Option<f64>) {
        self.motion = motion;
        self.target = target;
        self.soft_limited = false;
        self.stopped_on_limit = false;
    }
}

/// A Geo Brick (Turbo PMAC2) with motors 1 to n behind its Ethernet port.
pub struct PmacEmulator {
    motors: Vec<Motor>,
    ivars: Vec<f64>,
    pvars: Vec<f64>,
    qvars: Vec<f64>,
    mvars: Vec<f64>,
    /// The motor on-line motor commands go to (`#n`).
    addressed: usize,
    input: Vec<u8>,
    /// What an answer had beyond its first 1400 bytes, for `VR_PMAC_GETBUFFER`.
    held: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl PmacEmulator {
    /// A controller with motors 1 to `motors` (1 to 32) on `mechanics`, each a servo loop,
    /// closed, its amplifier enabled.
    pub fn new(motors: usize, mechanics: &SimConfig) -> Self {
        let installed = motors.clamp(1, MOST_MOTORS);
        let mechanics = SimConfig { servo: true, ..mechanics.clone() };
        let mut ivars = vec![0.0; VARIABLES];
        ivars[3] = 2.0;
        ivars[6] = 1.0;
        ivars[9] = 2.0;
        ivars[10] = 3_713_707.0;
        for motor in 1..=MOST_MOTORS {
            for nn in 0..100 {
                ivars[100 * motor + nn] = motor_default(motor, nn, installed);
            }
        }
        Self {
            motors: axes(installed, &mechanics).into_iter().map(Motor::new).collect(),
            ivars,
            pvars: vec![0.0; VARIABLES],
            qvars: vec![0.0; VARIABLES],
            mvars: vec![0.0; VARIABLES],
            addressed: 1,
            input: Vec::new(),
            held: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// Ixx`nn` of motor `motor`.
    fn ivar(&self, motor: usize, nn: usize) -> f64 {
        self.ivars[100 * motor + nn]
    }

    fn motor(&mut self, motor: usize) -> &mut Motor {
        &mut self.motors[motor - 1]
    }

    /// One packet's answer, if it has one.
    fn packet(&mut self, request_type: u8, request: u8, value: u16, data: &[u8]) -> Option<Vec<u8>> {
        match (request_type, request) {
            (VR_DOWNLOAD, VR_PMAC_GETRESPONSE) => {
                let mut reply = self.line(data);
                self.held = if reply.len() > REPLY_LIMIT { reply.split_off(REPLY_LIMIT) } else { Vec::new() };
                Some(reply)
            }
            (VR_DOWNLOAD, VR_PMAC_FLUSH) => {
                self.held.clear();
                Some(vec![VR_DOWNLOAD])
            }
            (VR_UPLOAD, VR_PMAC_READREADY) => Some(vec![u8::from(!self.held.is_empty()), 0]),
            (VR_UPLOAD, VR_PMAC_GETBUFFER) if self.held.is_empty() => Some(vec![ACK]),
            (VR_UPLOAD, VR_PMAC_GETBUFFER) => {
                let rest = self.held.split_off(self.held.len().min(REPLY_LIMIT));
                Some(std::mem::replace(&mut self.held, rest))
            }
            (VR_UPLOAD, VR_CTRL_RESPONSE) => Some(self.control(value)),
            _ => {
                self.malformed += 1;
                None
            }
        }
    }

    /// The answer to a control character.
    fn control(&mut self, character: u16) -> Vec<u8> {
        let group = 1..=self.motors.len().min(8);
        let fields: Vec<String> = match character {
            0x02 => group.map(|m| self.status_text(m)).collect(),
            0x06 => group.map(|_| "0".to_string()).collect(),
            0x10 => group.map(|m| self.position_text(m)).collect(),
            0x16 => group.map(|m| self.velocity_text(m)).collect(),
            0x0B => {
                self.motors.iter_mut().for_each(Motor::kill);
                Vec::new()
            }
            _ => Vec::new(),
        };
        if fields.is_empty() {
            vec![ACK]
        } else {
            format!("{}\r\x06", fields.join(" ")).into_bytes()
        }
    }

    /// The answer to a command line: each value reported followed by CR, then ACK; or, at the
    /// first refusal, BEL ERRnnn CR after what was reported before it.
    fn line(&mut self, data: &[u8]) -> Vec<u8> {
        let end = data.iter().rposition(|b| !matches!(b, b'\r' | b'\n' | 0)).map_or(0, |i| i + 1);
        let text = data[..end].to_ascii_uppercase();
        let mut reported = Vec::new();
        let mut outcome = if text.iter().any(|b| *b > 127) { Err(Refusal::IllegalCharacter) } else { Ok(()) };
        let mut parser = Parser { text: &text, at: 0 };
        while outcome.is_ok() {
            parser.skip_spaces();
            if parser.at == text.len() {
                break;
            }
            outcome = self.command(&mut parser, &mut reported);
            self.settle();
        }
        let mut reply: Vec<u8> = reported.iter().flat_map(|value| value.bytes().chain([CR])).collect();
        match outcome {
            Ok(()) => reply.push(ACK),
            Err(refusal) => {
                if refusal != Refusal::Unsupported {
                    self.malformed += 1;
                }
                let code = if refusal == Refusal::IllegalCharacter { 4 } else { 3 };
                reply.extend(format!("\x07ERR{code:03}\r").bytes());
            }
        }
        reply
    }

    /// Carry out the command at the parser, pushing what it reports.
    fn command(&mut self, p: &mut Parser<'_>, reported: &mut Vec<String>) -> Result<(), Refusal> {
        let m = self.addressed;
        if p.eat(b"#") {
            let motor = p.integer().ok_or(Refusal::Syntax)?;
            if !(1..=self.motors.len()).contains(&motor) {
                return Err(Refusal::Unsupported);
            }
            self.addressed = motor;
        } else if p.eat(b"&") {
            p.integer().filter(|cs| (1..=16).contains(cs)).ok_or(Refusal::Syntax)?;
        } else if p.eat(b"???") {
            reported.push("0".repeat(12));
        } else if p.eat(b"??") {
            reported.push("0".repeat(18));
        } else if p.eat(b"?") {
            reported.push(self.status_text(m));
        } else if p.eat(b"$$$") || p.eat(b"SAVE") {
            // Acknowledged; nothing to reset or keep.
        } else if let Some((_, answer)) = IDENTITY.iter().find(|(word, _)| p.eat(word)) {
            reported.push((*answer).to_string());
        } else if p.eat(b"HOME") || p.eat(b"HM") {
            self.home(m);
        } else if p.eat(b"J") {
            self.jog(m, p)?;
        } else if p.eat(b"K") {
            self.motor(m).kill();
        } else if p.eat(b"O") {
            return Err(Refusal::Unsupported);
        } else if let Some(kind) = p.variable_letter() {
            self.variable(kind, p, reported)?;
        } else if p.eat(b"P") {
            reported.push(self.position_text(m));
        } else if p.eat(b"V") {
            reported.push(self.velocity_text(m));
        } else if p.eat(b"F") {
            // The simulator follows its trajectory exactly.
            reported.push("0".into());
        } else {
            return Err(Refusal::Syntax);
        }
        Ok(())
    }

    /// `J` and what follows it.
    fn jog(&mut self, m: usize, p: &mut Parser<'_>) -> Result<(), Refusal> {
        let kind = p.text.get(p.at).copied().ok_or(Refusal::Syntax)?;
        p.at += 1;
        let number = p.signed_number();
        if p.text.get(p.at) == Some(&b'^') {
            // Jog-until-trigger.
            return Err(Refusal::Unsupported);
        }
        let motor = &self.motors[m - 1];
        let (prejog, actual, commanded) = (motor.prejog, motor.position(), motor.commanded());
        match (kind, number) {
            (b'+', None) => self.jog_on(m, 1.0),
            (b'-', None) => self.jog_on(m, -1.0),
            (b'/', None) => self.jog_stop(m),
            (b'=', None) => self.jog_to(m, prejog, false),
            (b'=', Some(target)) => self.jog_to(m, target, true),
            (b'^', Some(distance)) => self.jog_to(m, actual + distance, true),
            (b':', Some(distance)) => self.jog_to(m, commanded + distance, true),
            _ => return Err(Refusal::Syntax),
        }
        Ok(())
    }

    /// Speed (steps/s) and acceleration (steps/s², 0: none) of a jog or home move at `speed`
    /// counts/ms: see the module's readings.
    fn profile(&self, m: usize, speed: f64) -> (f64, f64) {
        let speed = speed.abs();
        let time = self.ivar(m, ixx::ACCELERATION_TIME).max(2.0 * self.ivar(m, ixx::S_CURVE_TIME));
        let mut acceleration = if time > 0.0 { speed / time } else { f64::INFINITY };
        let cap = self.ivar(m, ixx::MAX_ACCELERATION);
        if cap > 0.0 {
            acceleration = acceleration.min(cap);
        }
        (speed * 1e3, if acceleration.is_finite() { acceleration * 1e6 } else { 0.0 })
    }

    /// The software limits, negative and positive, where set.
    fn soft_limits(&self, m: usize) -> (Option<f64>, Option<f64>) {
        let set = |x: f64| Some(x).filter(|x| *x != 0.0);
        (set(self.ivar(m, ixx::NEGATIVE_LIMIT)), set(self.ivar(m, ixx::POSITIVE_LIMIT)))
    }

    fn jog_to(&mut self, m: usize, target: f64, remember: bool) {
        let (low, high) = self.soft_limits(m);
        let end = high.map_or(target, |h| target.min(h));
        let end = low.map_or(end, |l| end.max(l));
        let (speed, acceleration) = self.profile(m, self.ivar(m, ixx::JOG_SPEED));
        let motor = self.motor(m);
        motor.close_loop();
        if remember {
            motor.prejog = motor.commanded();
        }
        motor.start(Motion::JogTo, Some(end));
        motor.soft_limited = end != target;
        motor.axis.move_to(end, false, 0.0, speed, acceleration);
    }

    /// `J+` (`direction` 1) or `J-` (−1): on until a limit, or `J/`.
    fn jog_on(&mut self, m: usize, direction: f64) {
        let (low, high) = self.soft_limits(m);
        if let Some(limit) = if direction > 0.0 { high } else { low } {
            self.jog_to(m, limit, true);
            self.motor(m).soft_limited = true;
            return;
        }
        let (speed, acceleration) = self.profile(m, self.ivar(m, ixx::JOG_SPEED));
        let motor = self.motor(m);
        motor.close_loop();
        motor.prejog = motor.commanded();
        motor.start(Motion::Jog, None);
        motor.axis.move_velocity(0.0, direction * speed, acceleration);
    }

    fn jog_stop(&mut self, m: usize) {
        let (_, deceleration) = self.profile(m, self.ivar(m, ixx::JOG_SPEED));
        let motor = self.motor(m);
        motor.close_loop();
        motor.target = None;
        if motor.axis.is_moving() {
            motor.motion = Motion::Jog;
            motor.axis.stop(deceleration);
        } else {
            motor.motion = Motion::Idle;
        }
    }

    fn home(&mut self, m: usize) {
        let direction = self.ivar(m, ixx::HOME_SPEED);
        let (speed, acceleration) = self.profile(m, direction);
        let motor = self.motor(m);
        motor.close_loop();
        motor.home_complete = false;
        motor.start(Motion::HomeSearch, None);
        motor.axis.home(direction >= 0.0, 0.0, speed, acceleration);
    }

    /// Moves that have ended: a home search goes on to its home zero, the others are over.
    fn settle(&mut self) {
        for m in 1..=self.motors.len() {
            let motor = &self.motors[m - 1];
            if motor.motion == Motion::Idle || motor.axis.is_moving() {
                continue;
            }
            if motor.motion == Motion::HomeSearch {
                // A search that found the switch ends there, its counter zeroed.
                let found = motor.axis.on_home_switch() && motor.position() == 0.0;
                let offset = self.ivar(m, ixx::HOME_OFFSET) / 16.0;
                let (speed, acceleration) = self.profile(m, self.ivar(m, ixx::HOME_SPEED));
                let motor = self.motor(m);
                motor.home_complete = found;
                motor.motion = Motion::Idle;
                if found && offset != 0.0 {
                    motor.axis.set_position(-offset);
                    motor.start(Motion::HomeOffset, Some(0.0));
                    motor.axis.move_to(0.0, false, 0.0, speed, acceleration);
                }
            } else {
                let motor = self.motor(m);
                let state = motor.axis.state();
                motor.stopped_on_limit = motor.soft_limited || state.high_limit || state.low_limit;
                motor.motion = Motion::Idle;
                motor.target = None;
            }
        }
    }

    /// The two 24-bit status words of motor `m`.
    fn status(&self, m: usize) -> (u32, u32) {
        let motor = &self.motors[m - 1];
        let state = motor.axis.state();
        let position = motor.position();
        let (low, high) = self.soft_limits(m);
        let switches = self.ivar(m, ixx::FLAGS) as u32 & LIMITS_DISABLED == 0;
        let negative = (switches && state.low_limit) || low.is_some_and(|l| position < l);
        let positive = (switches && state.high_limit) || high.is_some_and(|h| position > h);
        let velocity_zero = motor.closed_loop && motor.motion == Motion::Idle;
        let in_position = velocity_zero && self.ivar(m, ixx::IN_POSITION_BAND) > 0.0;
        let bits = |flags: &[(bool, u32)]| flags.iter().filter(|(on, _)| *on).fold(0, |word, (_, bit)| word | 1 << bit);
        let first = bits(&[
            (self.ivar(m, ixx::ACTIVATED) != 0.0, 23),
            (negative, 22),
            (positive, 21),
            (motor.amplifier, 19),
            (!motor.closed_loop, 18),
            (matches!(motor.motion, Motion::JogTo | Motion::HomeOffset), 17),
            (self.ivar(m, ixx::INTEGRATION_MODE) == 1.0, 16),
            (velocity_zero, 13),
            (motor.motion == Motion::HomeSearch, 10),
        ]);
        let second = bits(&[
            (motor.stopped_on_limit, 11),
            (motor.home_complete, 10),
            (motor.fatal_following_error, 2),
            (in_position, 0),
        ]);
        (first, second)
    }

    fn status_text(&self, m: usize) -> String {
        let (first, second) = self.status(m);
        format!("{first:06X}{second:06X}")
    }

    fn position_text(&self, m: usize) -> String {
        decimal((self.motors[m - 1].position() * 32.0).round() / 32.0)
    }

    /// Counts per servo cycle, a cycle being I10/8,388,608 ms.
    fn velocity_text(&self, m: usize) -> String {
        let per_cycle = self.motors[m - 1].axis.status().velocity / 1e3 * self.ivars[10] / 8_388_608.0;
        decimal((per_cycle * 10.0).round() / 10.0)
    }

    /// A variable command: report, range report, setting, or M-variable definition.
    fn variable(&mut self, kind: u8, p: &mut Parser<'_>, reported: &mut Vec<String>) -> Result<(), Refusal> {
        let first = p.integer().filter(|n| *n < VARIABLES).ok_or(Refusal::Syntax)?;
        if p.eat(b"..") {
            let last = p.integer().filter(|n| (first..VARIABLES).contains(n)).ok_or(Refusal::Syntax)?;
            reported.extend((first..=last).map(|n| self.show(kind, n)));
        } else if kind == b'M' && p.eat(b"->") {
            let start = p.at;
            while p.text.get(p.at).is_some_and(|b| *b != b' ') {
                p.at += 1;
            }
            if p.at == start {
                return Err(Refusal::Syntax);
            }
        } else if p.eat(b"=") {
            let value = self.expression(p)?;
            self.write(kind, first, value)?;
        } else {
            reported.push(self.show(kind, first));
        }
        Ok(())
    }

    /// The motor and the `nn` of variable number `n`, if it is one of an installed motor's.
    fn motor_variable(&self, n: usize) -> Option<(usize, usize)> {
        Some((n / 100, n % 100)).filter(|(m, _)| (1..=self.motors.len()).contains(m))
    }

    /// 1/(Ixx08·32) count, the unit of the position registers.
    fn register_unit(&self, m: usize) -> f64 {
        self.ivar(m, ixx::SCALE) * 32.0
    }

    fn read(&self, kind: u8, n: usize) -> f64 {
        match (kind, self.motor_variable(n)) {
            (b'I', _) => self.ivars[n],
            (b'P', _) => self.pvars[n],
            (b'Q', _) => self.qvars[n],
            (_, Some((m, ixx::M_IN_POSITION))) => f64::from(self.status(m).1 & 1),
            (_, Some((m, ixx::M_COMMANDED | ixx::M_ACTUAL))) => self.motors[m - 1].position() * self.register_unit(m),
            _ => self.mvars[n],
        }
    }

    fn show(&self, kind: u8, n: usize) -> String {
        let value = self.read(kind, n);
        if kind == b'I' && hexadecimal(n) {
            format!("${:X}", value as i64 & 0xFF_FFFF)
        } else {
            decimal(value)
        }
    }

    fn write(&mut self, kind: u8, n: usize, value: f64) -> Result<(), Refusal> {
        match (kind, self.motor_variable(n)) {
            (b'I', motor) => {
                self.ivars[n] = value;
                let gain = match motor.map(|(_, nn)| nn) {
                    Some(ixx::PROPORTIONAL) => Some(Gain::Proportional),
                    Some(ixx::DERIVATIVE) => Some(Gain::Derivative),
                    Some(ixx::INTEGRAL) => Some(Gain::Integral),
                    _ => None,
                };
                if let (Some(gain), Some((m, _))) = (gain, motor) {
                    self.motor(m).axis.set_gain(gain, value);
                }
            }
            (b'P', _) => self.pvars[n] = value,
            (b'Q', _) => self.qvars[n] = value,
            (_, Some((_, ixx::M_IN_POSITION))) => {}
            (_, Some((m, ixx::M_COMMANDED | ixx::M_ACTUAL))) => {
                let unit = self.register_unit(m);
                if unit == 0.0 {
                    return Err(Refusal::Syntax);
                }
                self.motor(m).axis.set_position(value / unit);
            }
            _ => self.mvars[n] = value,
        }
        Ok(())
    }

    /// `term {(+|-) term}`.
    fn expression(&self, p: &mut Parser<'_>) -> Result<f64, Refusal> {
        let mut value = self.term(p)?;
        while let Some(operator) = p.operator(b"+-") {
            let right = self.term(p)?;
            value = if operator == b'+' { value + right } else { value - right };
        }
        Ok(value)
    }

    /// `factor {(*|/) factor}`.
    fn term(&self, p: &mut Parser<'_>) -> Result<f64, Refusal> {
        let mut value = self.factor(p)?;
        while let Some(operator) = p.operator(b"*/") {
            let right = self.factor(p)?;
            if operator == b'/' && right == 0.0 {
                return Err(Refusal::Syntax);
            }
            value = if operator == b'*' { value * right } else { value / right };
        }
        Ok(value)
    }

    /// A number, a variable, a signed factor or a parenthesized expression.
    fn factor(&self, p: &mut Parser<'_>) -> Result<f64, Refusal> {
        p.skip_spaces();
        if p.eat(b"-") {
            return Ok(-self.factor(p)?);
        }
        if p.eat(b"+") {
            return self.factor(p);
        }
        if p.eat(b"(") {
            let value = self.expression(p)?;
            p.skip_spaces();
            return if p.eat(b")") { Ok(value) } else { Err(Refusal::Syntax) };
        }
        if let Some(kind) = p.variable_letter() {
            let n = p.integer().filter(|n| *n < VARIABLES).ok_or(Refusal::Syntax)?;
            return Ok(self.read(kind, n));
        }
        p.number().ok_or(Refusal::Syntax)
    }
}

/// Values as the shortest decimal to 10 places, `-0` as `0`.
fn decimal(value: f64) -> String {
    let text = format!("{value:.10}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".to_string()
    } else {
        text.to_string()
    }
}

/// A command line (upper case) and where its reading has got to.
struct Parser<'a> {
    text: &'a [u8],
    at: usize,
}

impl Parser<'_> {
    fn eat(&mut self, word: &[u8]) -> bool {
        let found = self.text[self.at..].starts_with(word);
        if found {
            self.at += word.len();
        }
        found
    }

    fn skip_spaces(&mut self) {
        while self.text.get(self.at) == Some(&b' ') {
            self.at += 1;
        }
    }

    fn digits(&mut self, radix: u32) -> &[u8] {
        let start = self.at;
        while self.text.get(self.at).is_some_and(|b| char::from(*b).is_digit(radix)) {
            self.at += 1;
        }
        &self.text[start..self.at]
    }

    /// Decimal digits, as a number.
    fn integer(&mut self) -> Option<usize> {
        std::str::from_utf8(self.digits(10)).ok()?.parse().ok()
    }

    /// `$` and hex digits, or decimal digits with an optional fraction.
    fn number(&mut self) -> Option<f64> {
        if self.eat(b"$") {
            let hex = std::str::from_utf8(self.digits(16)).ok()?;
            return u64::from_str_radix(hex, 16).ok().map(|n| n as f64);
        }
        let start = self.at;
        let whole = self.digits(10).len();
        let fraction = if self.eat(b".") { self.digits(10).len() } else { 0 };
        if whole + fraction == 0 {
            self.at = start;
            return None;
        }
        std::str::from_utf8(&self.text[start..self.at]).ok()?.parse().ok()
    }

    /// A constant with an optional sign.
    fn signed_number(&mut self) -> Option<f64> {
        let start = self.at;
        let sign = if self.eat(b"-") {
            -1.0
        } else {
            self.eat(b"+");
            1.0
        };
        let number = self.number().map(|n| sign * n);
        if number.is_none() {
            self.at = start;
        }
        number
    }

    /// One of `operators` after optional spaces, taken; else nothing is.
    fn operator(&mut self, operators: &[u8]) -> Option<u8> {
        let start = self.at;
        self.skip_spaces();
        match self.text.get(self.at) {
            Some(b) if operators.contains(b) => {
                self.at += 1;
                Some(*b)
            }
            _ => {
                self.at = start;
                None
            }
        }
    }

    /// I, P, Q or M followed by a digit: taken, its letter returned.
    fn variable_letter(&mut self) -> Option<u8> {
        let letter = *self.text.get(self.at)?;
        let digit = self.text.get(self.at + 1).is_some_and(u8::is_ascii_digit);
        (matches!(letter, b'I' | b'P' | b'Q' | b'M') && digit).then(|| {
            self.at += 1;
            letter
        })
    }
}

impl Emulator for PmacEmulator {
    fn name(&self) -> &'static str {
        "pmac"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for motor in &mut self.motors {
            motor.axis.advance(now);
        }
        self.settle();
        self.input.extend_from_slice(bytes);
        while self.input.len() >= HEADER {
            let request_type = self.input[0];
            let length = usize::from(u16::from_be_bytes([self.input[6], self.input[7]]));
            let data = if request_type == VR_DOWNLOAD { length } else { 0 };
            if !matches!(request_type, VR_DOWNLOAD | VR_UPLOAD) || data > DATA_LIMIT {
                // No telling where the next packet starts: what came is dropped.
                self.input.clear();
                self.malformed += 1;
                break;
            }
            if self.input.len() < HEADER + data {
                break;
            }
            let packet: Vec<u8> = self.input.drain(..HEADER + data).collect();
            let value = u16::from_be_bytes([packet[2], packet[3]]);
            if let Some(reply) = self.packet(request_type, packet[1], value, &packet[HEADER..]) {
                self.output.push_back(reply);
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        channel.checked_sub(1).and_then(|i| self.motors.get_mut(i)).map(|motor| &mut motor.axis)
    }

    /// The motor is killed on a fatal following error, as the controller does.
    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(motor) = channel.checked_sub(1).and_then(|i| self.motors.get_mut(i)) else { return false };
        motor.kill();
        motor.fatal_following_error = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn at(ms: u64) -> Instant {
        Instant::ZERO + Duration::from_millis(ms)
    }

    fn brick() -> PmacEmulator {
        PmacEmulator::new(8, &stage())
    }

    /// A command line as dls-pmaclib wraps it: `0x40 0xBF 0 0 0 0` and the length, big-endian.
    fn getresponse(line: &str) -> Vec<u8> {
        let mut packet = vec![VR_DOWNLOAD, VR_PMAC_GETRESPONSE, 0, 0, 0, 0];
        packet.extend(u16::try_from(line.len()).unwrap().to_be_bytes());
        packet.extend(line.bytes());
        packet
    }

    fn reply(e: &mut PmacEmulator) -> String {
        let reply = e.poll_transmit().expect("answered");
        assert!(e.poll_transmit().is_none(), "in one piece");
        String::from_utf8(reply).expect("ASCII")
    }

    fn say(e: &mut PmacEmulator, ms: u64, line: &str) -> String {
        e.handle_input(at(ms), &getresponse(line));
        reply(e)
    }

    #[test]
    fn packets_come_whole_whatever_the_pieces() {
        let mut e = brick();
        let packet = getresponse("#1P");
        e.handle_input(at(0), &packet[..3]);
        e.handle_input(at(0), &packet[3..9]);
        assert!(e.poll_transmit().is_none(), "header and one byte of data");
        e.handle_input(at(0), &packet[9..]);
        assert_eq!(reply(&mut e), "0\r\x06");
        let two = [getresponse("cid"), getresponse("i6")].concat();
        e.handle_input(at(0), &two);
        assert_eq!(e.poll_transmit().unwrap(), b"603382\r\x06");
        assert_eq!(e.poll_transmit().unwrap(), b"1\r\x06");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn dls_pmaclib_bytes_are_understood() {
        let mut e = brick();
        // struct.pack("8B", 0x40, 0xBF, 0, 0, 0, 0, 0, len(cmd)) + cmd
        e.handle_input(at(0), b"\x40\xbf\x00\x00\x00\x00\x00\x0di6=1 i3=2 ver");
        let version = reply(&mut e);
        let (digits, rest) = version.split_once('.').unwrap();
        assert!(digits.bytes().all(|b| b.is_ascii_digit()) && !digits.is_empty(), "{version:?}");
        assert!(rest.ends_with("\r\x06") && rest.trim_end_matches("\r\x06").bytes().all(|b| b.is_ascii_digit()));
        assert_eq!(say(&mut e, 0, "cid"), "603382\r\x06");
        assert_eq!(say(&mut e, 0, "i20 i21 i22 i23 "), "$0\r$0\r$0\r$0\r\x06", "no MACRO IC: 8 axes");
        // Its VR_PMAC_GETBUFFER: a 2048-byte read, no data after the header.
        e.handle_input(at(0), b"\xc0\xc5\x00\x00\x00\x00\x08\x00");
        assert_eq!(reply(&mut e), "\x06", "nothing held");
        assert_eq!(say(&mut e, 0, "i124"), "$800001\r\x06");
        assert_eq!(say(&mut e, 0, "i124=$820001"), "\x06", "disableLimits");
        assert_eq!(say(&mut e, 0, "i124"), "$820001\r\x06");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_line_reports_its_values_in_order_and_takes_its_settings() {
        let mut e = brick();
        assert_eq!(say(&mut e, 0, "#2 I222=16 i222 #1P i122"), "16\r0\r32\r\x06");
        assert_eq!(say(&mut e, 0, "I120..123"), "0\r50\r32\r32\r\x06");
        assert_eq!(say(&mut e, 0, "i119 P7=2.5 p7 Q7=-1 q7"), "0.15625\r2.5\r-1\r\x06");
        assert_eq!(say(&mut e, 0, ""), "\x06");
        assert_eq!(say(&mut e, 0, "SAVE $$$ ??? &1??"), "000000000000\r000000000000000000\r\x06");
    }

    #[test]
    fn expressions_follow_precedence_and_read_variables() {
        let mut e = brick();
        assert_eq!(
            say(&mut e, 0, "P1=2+3*4 P2=(2+3)*4 P3=-P1/2 P4=$1F P5=32*I108 P6=1 - -2 P1..6"),
            "14\r20\r-7\r31\r3072\r3\r\x06"
        );
        assert_eq!(say(&mut e, 0, "P1=1/0"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "P1=(1"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "P1"), "14\r\x06", "refused settings change nothing");
    }

    #[test]
    fn refusals_end_the_line_with_bel_errnnn_cr() {
        let mut e = brick();
        assert_eq!(say(&mut e, 0, "nonsense"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "P1=5 P1 XYZ P1=6"), "5\r\x07ERR003\r", "what came before stays");
        assert_eq!(say(&mut e, 0, "P1"), "5\r\x06", "what came after is not carried out");
        assert_eq!(say(&mut e, 0, "I8192"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "I5..3"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "#1J^"), "\x07ERR003\r");
        let mut accented = getresponse("P1e");
        *accented.last_mut().unwrap() = 0xE9;
        e.handle_input(at(0), &accented);
        assert_eq!(reply(&mut e), "\x07ERR004\r");
        assert_eq!(e.malformed(), 6);
        // A PMAC's, not carried out here: refused, not the host's fault.
        assert_eq!(say(&mut e, 0, "#9P"), "\x07ERR003\r", "eight motors");
        assert_eq!(say(&mut e, 0, "#1O10"), "\x07ERR003\r");
        assert_eq!(say(&mut e, 0, "#1J=10^5"), "\x07ERR003\r");
        assert_eq!(e.malformed(), 6);
    }

    #[test]
    fn a_jog_to_a_position_ends_in_position() {
        let mut e = brick();
        // 32 counts/ms, accelerating at Ixx19 = 0.15625 counts/ms² (100 ms of S-curve asks more).
        assert_eq!(say(&mut e, 0, "#1J=1000"), "\x06");
        assert_eq!(say(&mut e, 50, "#1?"), "8B0000000000\r\x06", "move timer, no in-position");
        assert_eq!(say(&mut e, 1000, "#1? P V F"), "892000000001\r1000\r0\r0\r\x06");
        assert_eq!(say(&mut e, 1000, "#1J^-250.5"), "\x06");
        assert_eq!(say(&mut e, 2000, "#1P"), "749.5\r\x06");
        assert_eq!(say(&mut e, 2000, "#1J:250.5 #2J=-20"), "\x06");
        assert_eq!(say(&mut e, 3000, "#1P #2P #1J= #1?"), "1000\r-20\r8B0000000000\r\x06", "back to the pre-jog");
        assert_eq!(say(&mut e, 4000, "#1P M140 M161 M162"), "749.5\r1\r2302464\r2302464\r\x06");
    }

    #[test]
    fn jogs_run_until_stopped_and_stop_decelerating() {
        let mut e = brick();
        assert_eq!(say(&mut e, 0, "#1J+ #2J-"), "\x06");
        let velocity: f64 = say(&mut e, 1000, "#1V").trim_end_matches("\r\x06").parse().unwrap();
        assert!((velocity - 14.2).abs() < 0.01, "32 counts/ms × 0.4427 ms a servo cycle: {velocity}");
        assert_eq!(say(&mut e, 1000, "#1J/ #1?"), "890000000000\r\x06", "decelerating");
        assert_eq!(say(&mut e, 2000, "#1? #2?"), "892000000001\r890000000000\r\x06", "#2 jogs on");
    }

    #[test]
    fn a_home_search_ends_at_the_home_zero_with_home_complete() {
        let mut e = brick();
        say(&mut e, 0, "#1J=5000 #2J=-3000 I226=-8000");
        assert_eq!(say(&mut e, 1000, "#1HM #2HOME #1?"), "890400000000\r\x06", "home search in progress");
        assert_eq!(say(&mut e, 2000, "#1P #1? #2?"), "0\r892000000401\r8B0000000400\r\x06");
        assert_eq!(say(&mut e, 3000, "#2P #2?"), "0\r892000000401\r\x06");
        assert_eq!(e.axis(2).unwrap().physical_position(), -500.0, "Ixx26 -8000/16 from the switch");
    }

    #[test]
    fn k_kills_and_a_jog_closes_the_loop_again() {
        let mut e = brick();
        say(&mut e, 0, "#1J+");
        let killed = say(&mut e, 500, "#1K #1? P");
        let (status, position) = killed.split_once('\r').unwrap();
        assert_eq!(status, "850000000000", "open loop, amplifier disabled");
        assert_eq!(say(&mut e, 1500, "#1P"), position, "a killed motor does not move");
        assert_eq!(say(&mut e, 1500, "#1J/ #1?"), "892000000001\r\x06");
    }

    #[test]
    fn the_suggested_m_variables_redefine_the_position() {
        let mut e = brick();
        assert_eq!(say(&mut e, 0, "#1K M161=1000*32*I108 M162=1000*32*I108 #1J/ #1P"), "1000\r\x06");
        assert_eq!(e.axis(1).unwrap().physical_position(), 0.0, "the carriage stayed");
        assert_eq!(say(&mut e, 0, "M140=0 M140 M7=3 M7"), "1\r3\r\x06");
    }

    #[test]
    fn limits_stop_jogs_and_are_reported() {
        let mut e = brick();
        say(&mut e, 0, "#1I122=1000 I119=100 J+");
        assert_eq!(say(&mut e, 1000, "#1P #1?"), "200000\rA92000000801\r\x06", "+limit, stopped on it");
        assert_eq!(say(&mut e, 1000, "I124=$820001 #1?"), "892000000801\r\x06", "limits disabled: not shown");
        say(&mut e, 1000, "#1J=0 I113=500");
        assert_eq!(say(&mut e, 3000, "#1J+"), "\x06");
        assert_eq!(say(&mut e, 4000, "#1P #1?"), "500\r892000000801\r\x06", "at the software limit");
        say(&mut e, 4000, "#1J=10000");
        assert_eq!(say(&mut e, 5000, "#1P"), "500\r\x06");
    }

    #[test]
    fn a_raised_error_kills_with_a_fatal_following_error() {
        let mut e = brick();
        assert!(e.raise_error(3));
        assert!(!e.raise_error(0) && !e.raise_error(9));
        assert_eq!(say(&mut e, 0, "#3?"), "850000000004\r\x06");
        assert_eq!(say(&mut e, 0, "#3J/ #3?"), "892000000001\r\x06", "cleared when re-enabled");
        assert_eq!(e.name(), "pmac");
    }

    #[test]
    fn long_answers_wait_in_the_buffer_and_control_characters_answer() {
        let mut e = brick();
        e.handle_input(at(0), &getresponse("I0..999"));
        let mut answer = e.poll_transmit().unwrap();
        assert_eq!(answer.len(), REPLY_LIMIT);
        e.handle_input(at(0), &[VR_UPLOAD, VR_PMAC_READREADY, 0, 0, 0, 0, 0, 2]);
        assert_eq!(e.poll_transmit().unwrap(), [1, 0]);
        while answer.last() != Some(&ACK) {
            e.handle_input(at(0), b"\xc0\xc5\x00\x00\x00\x00\x08\x00");
            answer.extend(e.poll_transmit().unwrap());
        }
        assert_eq!(answer.iter().filter(|b| **b == CR).count(), 1000, "one line a variable");
        e.handle_input(at(0), &[VR_DOWNLOAD, VR_PMAC_FLUSH, 0, 0, 0, 0, 0, 0]);
        assert_eq!(e.poll_transmit().unwrap(), b"@");
        say(&mut e, 0, "#2J=64");
        e.handle_input(at(1000), &[VR_UPLOAD, VR_CTRL_RESPONSE, 0, 0x10, 0, 0, 0, 0]);
        assert_eq!(reply(&mut e), "0 64 0 0 0 0 0 0\r\x06");
        e.handle_input(at(1000), &[VR_UPLOAD, VR_CTRL_RESPONSE, 0, 0x0B, 0, 0, 0, 0]);
        assert_eq!(reply(&mut e), "\x06");
        assert_eq!(say(&mut e, 1000, "#8?"), "850000000000\r\x06", "killed, all of them");
    }

    #[test]
    fn what_the_protocol_does_not_have_is_counted_as_malformed() {
        let mut e = brick();
        e.handle_input(at(0), &[VR_DOWNLOAD, 0xB0, 0, 0, 0, 0, 0, 1, b'P']);
        e.handle_input(at(0), &[0x12, 0, 0, 0, 0, 0, 0, 0]);
        e.handle_input(at(0), &[VR_DOWNLOAD, VR_PMAC_GETRESPONSE, 0, 0, 0, 0, 0x05, 0xD5]);
        assert!(e.poll_transmit().is_none());
        assert_eq!(e.malformed(), 3);
        assert_eq!(say(&mut e, 0, "#1P"), "0\r\x06", "and the next packet is read");
        assert!(e.axis(0).is_none() && e.axis(8).is_some() && e.axis(9).is_none());
    }
}
