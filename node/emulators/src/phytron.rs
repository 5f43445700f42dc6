//! A Phytron phyMOTION: a main module (MCM01) and axis modules, every axis addressed `M.A`
//! (module, axis), channel = module × 10 + axis. Two axes a module here (channels 11, 12, 21,
//! 22, …), which is what zmotor's launch files and tests name.
//!
//! # Sources
//! Phytron's phyMOTION communication / phyLOGIC command reference is the authority; its text
//! was not in the reference stores searched for this emulator, so what follows is taken from
//! what that manual is known to define (telegram layout, checksum, ACK/NAK, the `M.A` axis
//! commands, the parameters P01…P58, the `SE` status bits), checked byte for byte against the
//! second witness, the EPICS driver epics-motor/motorPhytron (`phytronAxisMotor.cpp`:
//! `sendPhytronCommand` for the framing and checksum, the poll for `SE`, `P20R`, `P22R`,
//! `==H`, the status masks 0xE800 / 0x1208, `IM0`, `ST`, `STC`, `CR`, `SEC`, `C`, the reference
//! runs of `home`). Other real clients add what they send: the MBI-Div-B pytango PhyMotion
//! server (`PhyMotionAxis.py`: `1.1SE 1.1P20R` with no `M` and a leading space, `P14S4000`
//! writes, `R+` / `R-`, `SN`, `SA`, `SEC`, `P01R`…`P58R` in one telegram), TUM's
//! phytron-phyMotion (`M1.1P14=4000`), and PhytronShell (commands as typed). Where these are
//! silent the reading taken is said below.
//!
//! # Telegrams
//! A request is `STX <address> <commands> ':' <checksum> ETX`. The address is one hex digit
//! (`0`…`F`, the EPICS driver's `%X`); this controller is `0`. The checksum is the XOR of every
//! byte from the address up to and including the `:`, written as two uppercase hex digits; `XX`
//! in its place means "do not check" and is taken. Several commands go in one telegram,
//! separated by spaces; the reply is one telegram `STX <answers> ':' <checksum> ETX`
//! without address: for each command an ACK (0x06) or NAK (0x15), followed by its data, the
//! checksum being the XOR of the bytes from the first ACK/NAK up to and including the `:`.
//!
//! # Commands
//! An axis command is `M<m.a><order>` or, the `M` left out, `<m.a><order>` (the MBI server's
//! `1.1P20R`); both are taken everywhere below.
//! - `M<m.a>A<n>`, `M<m.a>+<n>`, `M<m.a>-<n>`: absolute and relative moves at the run frequency
//!   P14 from the start/stop frequency P04 with the ramp P15;
//! - `M<m.a>L+` / `L-`: runs until stopped or a limit switch (free run);
//! - `M<m.a>R+C` / `R-C`: the reference run to the center switch at P08 with the ramp P09 (P10 is
//!   the frequency off the switch); the counters are 0 there and the axis initialised;
//! - `M<m.a>R+` / `R-` (motorPhytron's limit homing, the MBI server's `homing_plus` /
//!   `homing_minus`): the reference run to the limit switch + / − at P08 with the ramp P09 (P10
//!   as above). It ends on the switch: the counters are 0 there, the axis initialised (bit 3) and,
//!   as for any run that ends on a limit switch, the limit-switch error (bit 12) set, the power
//!   stage still ready (bit 9): the 0x1208 that motorPhytron's poll, masking with 0xFA29 (+) or
//!   0xFA19 (−), waits for before it sends `SEC`, which clears bit 12 (bit 3 stays). Stopped
//!   before the switch, it initialises nothing. The offsets P11 / P12 are kept, not travelled.
//! - the other reference runs motorPhytron sends, `R+I` / `R-I` (to the encoder's index), `R+^I` /
//!   `R-^I` (limit switch, then the index), `R+C^I` / `R-C^I` (center switch, then the index),
//!   `RC+` / `RC-` and `RC+^I` / `RC-^I` (the center of a rotary axis, then the index): each is
//!   taken as `R+C` / `R-C`, the simulation having one reference mark (its home switch), which
//!   stands for the index as well;
//! - `M<m.a>S`: stops with the ramp P15; `M<m.a>C`: axis reset (stops with the emergency ramp
//!   P07, errors cleared); `M<m.a>SN` (the MBI server's `abort`): stops with P07, errors kept;
//! - `M<m.a>SA` (the MBI server's `write_to_eeprom`) and a bare `SA`: acknowledged, no effect:
//!   this controller has no EEPROM, its parameters last until `CR`;
//! - `M<m.a>MA` / `MD`: power stage on / off (off while running: stop with P07);
//! - `M<m.a>P<n>R`, `M<m.a>P<n>=<value>`, `M<m.a>P<n>S<value>`: parameters 1–58 (`P1` ≡ `P01`),
//!   written with `=` (motorPhytron, TUM) or `S` (the MBI server's `P14S4000`, `P20S12.5`);
//!   P55…P58 are kept as plain values;
//! - `M<m.a>==H`: `E` at standstill, `N` running;
//! - `SE<m.a>` or `M<m.a>SE`: the extended axis status (decimal); `SEC<m.a>` or `M<m.a>SEC` (the
//!   MBI server's `1.1SEC`): clears its error bits;
//! - `IVR`: the firmware version; `IM0`: the main module's type, `MCM01`;
//! - `ST`: the controller status (decimal), `STC` clears it, `CR` resets the controller, a bare
//!   `S` is acknowledged (read as the stop of every axis: see `answer`).
//!
//! | SE bit | meaning |
//! |---|---|
//! | 0 | axis busy |
//! | 3 | axis initialised (reference run done) |
//! | 4 / 5 / 6 | limit switch + / − / center |
//! | 9 | power stage ready |
//! | 11 | axis internal error |
//! | 12 | limit-switch error |
//! | 13 | power-stage error |
//! | 14 | SFI error (encoder and motor disagree) |
//! | 16 | axis running |
//! | 19 | axis in position |
//!
//! # Readings taken
//! - Spaces only separate: several in a row, or before the first command or after the last (the
//!   MBI server's ` 1.1SE 1.1P20R`, a command typed in PhytronShell), leave empty fields that are
//!   no commands, ignored, neither answered nor malformed, so that each command gets exactly one
//!   answer. A telegram of spaces only carries no command: it is broken (one NAK).
//! - Unknown commands are answered NAK in their place of the reply, the other commands of the
//!   telegram still carried out; they count as malformed (the driver's fault). So do a telegram
//!   whose checksum is wrong or missing (answered by one NAK) and noise outside STX … ETX (no
//!   answer). A telegram for another address is not answered (on a bus another controller
//!   would) and is counted.
//! - A command for an axis the controller does not have is refused (NAK), not malformed: the
//!   syntax is right, the hardware is absent.
//! - A motion while the power stage is off or in error is refused (NAK), which is what the
//!   EPICS driver's `CHECK_AXIS` reports as "Start move" failing; a run that ends on a limit
//!   switch sets the limit-switch error (bit 12), which stays until `SEC` or `C`.
//! - P21 (absolute counter), P22 (encoder counter), P49 and P54 (temperatures) are measured:
//!   writing them is refused. P20 written sets the counter (the position). P22 reads the
//!   encoder counts × the encoder conversion factor P39. Counters count whole steps (P02/P03
//!   left at steps). Frequencies and ramps must be positive; the manual's upper bounds were
//!   not at hand and none is enforced.
//! - `IVR` answers `MCM01 emulated` (the manual gives no fixed text); `IM<m>` for an axis module
//!   is refused, as these two-axis modules are no Phytron product whose name could be given.
//! - `ST` answers 0 (no controller error); `CR` puts every axis back to its power-up state
//!   (factory parameters, power stage on, at rest where it stands).
//! - `raise_error` is a power-stage error (SE bit 13): the axis stops with P07 and motions are
//!   refused until `SEC` or `C`.

use crate::emulator::{axes, Emulator};
use std::collections::{BTreeMap, VecDeque};
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

const STX: u8 = 0x02;
const ETX: u8 = 0x03;
const ACK: u8 = 0x06;
const NAK: u8 = 0x15;
const SEPARATOR: u8 = b':';
/// This controller's address.
const OWN_ADDRESS: u8 = b'0';
/// The longest telegram the controller takes, framing included.
const INPUT_LIMIT: usize = 1000;
/// Axes on each emulated module.
const AXES_PER_MODULE: usize = 2;
/// The highest parameter number.
const LAST_PARAMETER: u32 = 58;
/// Parameters that are measured, never written.
const MEASURED: [u32; 4] = [21, 22, 49, 54];
/// The answer to `IVR`.
const VERSION: &str = "MCM01 emulated";
/// The reference runs taken as the run to the center switch (`R+C` / `R-C`): the direction is
/// the sign's.
const REFERENCES: [&str; 12] =
    ["R+C", "R-C", "R+I", "R-I", "R+^I", "R-^I", "R+C^I", "R-C^I", "RC+", "RC-", "RC+^I", "RC-^I"];

/// The `SE` bits this emulator sets.
mod bit {
    pub(super) const BUSY: u32 = 1 << 0;
    pub(super) const INITIALISED: u32 = 1 << 3;
    pub(super) const PLUS_LIMIT: u32 = 1 << 4;
    pub(super) const MINUS_LIMIT: u32 = 1 << 5;
    pub(super) const CENTER: u32 = 1 << 6;
    pub(super) const POWER_READY: u32 = 1 << 9;
    pub(super) const INTERNAL_ERROR: u32 = 1 << 11;
    pub(super) const LIMIT_ERROR: u32 = 1 << 12;
    pub(super) const POWER_ERROR: u32 = 1 << 13;
    pub(super) const SFI_ERROR: u32 = 1 << 14;
    pub(super) const RUNNING: u32 = 1 << 16;
    pub(super) const IN_POSITION: u32 = 1 << 19;
}

/// The XOR of `bytes` as two uppercase hex digits.
fn xor_digits(bytes: &[u8]) -> [u8; 2] {
    let sum = bytes.iter().fold(0u8, |acc, b| acc ^ b);
    let hex = |nibble: u8| if nibble < 10 { b'0' + nibble } else { b'A' + nibble - 10 };
    [hex(sum >> 4), hex(sum & 0x0F)]
}

/// A reply telegram carrying `answers` (each an ACK or NAK and its data).
fn reply(answers: &[u8]) -> Vec<u8> {
    let mut checked = answers.to_vec();
    checked.push(SEPARATOR);
    let digits = xor_digits(&checked);
    let mut out = Vec::with_capacity(checked.len() + 4);
    out.push(STX);
    out.extend_from_slice(&checked);
    out.extend_from_slice(&digits);
    out.push(ETX);
    out
}

/// What a telegram's content (between STX and ETX) is.
#[derive(Debug, PartialEq)]
enum Telegram<'a> {
    /// For this controller, checksum right (or `XX`): its commands.
    Commands(&'a str),
    /// For another controller.
    Elsewhere,
    /// Not a telegram of the protocol.
    Broken,
}

fn telegram(content: &[u8]) -> Telegram<'_> {
    // address, at least one command byte, ':', two digits
    if content.len() < 5 || content[content.len() - 3] != SEPARATOR {
        return Telegram::Broken;
    }
    let (checked, digits) = content.split_at(content.len() - 2);
    let unchecked = digits.eq_ignore_ascii_case(b"XX");
    if !unchecked && xor_digits(checked) != [digits[0].to_ascii_uppercase(), digits[1].to_ascii_uppercase()] {
        return Telegram::Broken;
    }
    let address = checked[0];
    let body = &checked[1..checked.len() - 1];
    let no_command = body.iter().all(|b| *b == b' ');
    if !address.is_ascii_hexdigit() || no_command || !body.iter().all(|b| (0x20..0x7F).contains(b)) {
        return Telegram::Broken;
    }
    if address.to_ascii_uppercase() != OWN_ADDRESS {
        return Telegram::Elsewhere;
    }
    match std::str::from_utf8(body) {
        Ok(text) => Telegram::Commands(text),
        Err(_) => Telegram::Broken,
    }
}

/// One command's answer.
enum Answer {
    /// ACK and data.
    Ack(String),
    /// NAK: known, but not carried out here and now.
    Refused,
    /// NAK: not a command of the protocol.
    Unknown,
}

fn done() -> Answer {
    Answer::Ack(String::new())
}

/// `m.a` at the start of `text`: the channel and what follows.
fn axis_address(text: &str) -> Option<(usize, &str)> {
    let dot = text.find('.')?;
    let module = &text[..dot];
    if module.is_empty() || module.len() > 2 || !module.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let module: usize = module.parse().ok()?;
    let axis = *text.as_bytes().get(dot + 1)?;
    if module == 0 || !(b'1'..=b'9').contains(&axis) {
        return None;
    }
    Some((module * 10 + usize::from(axis - b'0'), &text[dot + 2..]))
}

/// A decimal as commands write it: an optional sign (if `signed`), digits, at most one point.
fn decimal(text: &str, signed: bool) -> Option<f64> {
    let digits = if signed { text.strip_prefix('-').unwrap_or(text) } else { text };
    let points = digits.bytes().filter(|b| *b == b'.').count();
    let ok = points <= 1
        && digits.bytes().any(|b| b.is_ascii_digit())
        && digits.bytes().all(|b| b.is_ascii_digit() || b == b'.');
    if ok {
        text.parse().ok()
    } else {
        None
    }
}

/// A value as the controller prints it: no decimals when it has none.
fn printed(value: f64) -> String {
    if value.fract() == 0.0 {
        format!("{}", value as i64)
    } else {
        format!("{value}")
    }
}

/// Factory parameters that matter here.
fn factory(encoder: bool) -> BTreeMap<u32, f64> {
    let mut parameters: BTreeMap<u32, f64> = (1..=LAST_PARAMETER).map(|n| (n, 0.0)).collect();
    for (number, value) in [
        (1, 1.0),
        (2, 1.0),
        (3, 1.0),
        (4, 400.0),
        (7, 100_000.0),
        (8, 2_000.0),
        (9, 4_000.0),
        (10, 400.0),
        (13, 20.0),
        (14, 4_000.0),
        (15, 4_000.0),
        (16, 20.0),
        (34, if encoder { 1.0 } else { 0.0 }),
        (39, 1.0),
        (49, 30.0),
        (54, 30.0),
    ] {
        parameters.insert(number, value);
    }
    parameters
}

/// One axis of the controller.
struct Axis {
    channel: usize,
    sim: SimAxis,
    parameters: BTreeMap<u32, f64>,
    power: bool,
    power_error: bool,
    limit_error: bool,
    was_running: bool,
    /// A reference run to a limit switch (`R+`: true, `R-`: false) under way.
    limit_reference: Option<bool>,
    /// A reference run to a limit switch has ended on it (the simulation's own HOMED stands for
    /// the other reference runs).
    initialised: bool,
}

impl Axis {
    fn new(channel: usize, sim: SimAxis) -> Self {
        let encoder = sim.config().encoder_counts_per_step.is_some();
        Self {
            channel,
            sim,
            parameters: factory(encoder),
            power: true,
            power_error: false,
            limit_error: false,
            was_running: false,
            limit_reference: None,
            initialised: false,
        }
    }

    fn p(&self, number: u32) -> f64 {
        self.parameters.get(&number).copied().unwrap_or(0.0)
    }

    /// A run that ended on a limit switch leaves the limit-switch error; a reference run to a
    /// limit switch that ended on it initialises the axis, the counters 0 there.
    fn watch(&mut self) {
        let running = self.sim.is_moving();
        let limits = self.sim.status().msta;
        if self.was_running && !running {
            if limits & (msta::PLUS_LS | msta::MINUS_LS) != 0 {
                self.limit_error = true;
            }
            if let Some(plus) = self.limit_reference.take() {
                let switch = if plus { msta::PLUS_LS } else { msta::MINUS_LS };
                if limits & switch != 0 {
                    self.initialised = true;
                    self.sim.set_position(0.0);
                }
            }
        }
        self.was_running = running;
    }

    fn status_word(&self) -> u32 {
        let status = self.sim.status();
        let running = self.sim.is_moving();
        [
            (running, bit::BUSY | bit::RUNNING),
            (!running, bit::IN_POSITION),
            (status.msta & msta::HOMED != 0 || self.initialised, bit::INITIALISED),
            (status.msta & msta::PLUS_LS != 0, bit::PLUS_LIMIT),
            (status.msta & msta::MINUS_LS != 0, bit::MINUS_LIMIT),
            (self.sim.on_home_switch(), bit::CENTER),
            (self.power && !self.power_error, bit::POWER_READY),
            (status.msta & msta::PROBLEM != 0, bit::INTERNAL_ERROR),
            (self.limit_error, bit::LIMIT_ERROR),
            (self.power_error, bit::POWER_ERROR),
            (status.msta & msta::SLIP_STALL != 0, bit::SFI_ERROR),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |word, (_, bits)| word | bits)
    }

    fn clear_errors(&mut self) {
        self.limit_error = false;
        self.power_error = false;
    }

    fn may_run(&self) -> bool {
        self.power && !self.power_error
    }

    /// One command after `M<m.a>`.
    fn command(&mut self, order: &str) -> Answer {
        let answer = self.carry_out(order);
        self.watch();
        answer
    }

    fn carry_out(&mut self, order: &str) -> Answer {
        let reference = REFERENCES.contains(&order);
        if matches!(order, "L+" | "L-" | "R+" | "R-") || reference {
            if !self.may_run() {
                return Answer::Refused;
            }
            self.limit_reference = None;
        }
        match order {
            "==H" => return Answer::Ack(if self.sim.is_moving() { "N" } else { "E" }.into()),
            "MA" => self.power = true,
            "MD" => {
                self.power = false;
                self.sim.stop(self.p(7));
            }
            "S" => self.sim.stop(self.p(15)),
            "SN" => self.sim.stop(self.p(7)),
            // No EEPROM: the parameters last until `CR` anyway.
            "SA" => {}
            "C" => {
                self.sim.stop(self.p(7));
                self.clear_errors();
            }
            "L+" => self.sim.move_velocity(self.p(4), self.p(14), self.p(15)),
            "L-" => self.sim.move_velocity(self.p(4), -self.p(14), self.p(15)),
            "R+" | "R-" => {
                let plus = order == "R+";
                let frequency = if plus { self.p(8) } else { -self.p(8) };
                self.sim.move_velocity(self.p(10), frequency, self.p(9));
                self.limit_reference = Some(plus);
            }
            _ if reference => self.sim.home(order.contains('+'), self.p(10), self.p(8), self.p(9)),
            _ => return self.other(order),
        }
        done()
    }

    /// Parameters and moves.
    fn other(&mut self, order: &str) -> Answer {
        if let Some(rest) = order.strip_prefix('P') {
            return self.parameter(rest);
        }
        let (relative, target) = match order.as_bytes().first() {
            Some(b'A') => (false, decimal(&order[1..], true)),
            Some(b'+') => (true, decimal(&order[1..], false)),
            Some(b'-') => (true, decimal(&order[1..], false).map(|d| -d)),
            _ => return Answer::Unknown,
        };
        let Some(target) = target else { return Answer::Unknown };
        if !self.may_run() {
            return Answer::Refused;
        }
        self.limit_reference = None;
        self.sim.move_to(target, relative, self.p(4), self.p(14), self.p(15));
        done()
    }

    /// `P<n>R`, `P<n>=<value>` or `P<n>S<value>`, after the `P`.
    fn parameter(&mut self, text: &str) -> Answer {
        let digits = text.bytes().take_while(u8::is_ascii_digit).count();
        let number = match text[..digits].parse::<u32>() {
            Ok(n) if (1..=LAST_PARAMETER).contains(&n) && digits <= 2 => n,
            _ => return Answer::Unknown,
        };
        match &text[digits..] {
            "R" => Answer::Ack(printed(self.read(number))),
            rest => match rest.strip_prefix(['=', 'S']).and_then(|v| decimal(v, true)) {
                Some(value) => self.write(number, value),
                None => Answer::Unknown,
            },
        }
    }

    fn read(&self, number: u32) -> f64 {
        let status = self.sim.status();
        match number {
            20 | 21 => status.position.round(),
            22 => status.encoder_position.round() * self.p(39),
            _ => self.p(number),
        }
    }

    fn write(&mut self, number: u32, value: f64) -> Answer {
        let positive = matches!(number, 4 | 7 | 8 | 9 | 10 | 14 | 15 | 39);
        if MEASURED.contains(&number) || (positive && value <= 0.0) {
            return Answer::Refused;
        }
        if number == 20 {
            self.sim.set_position(value);
        } else {
            self.parameters.insert(number, value);
        }
        done()
    }
}

/// An emulated phyMOTION: a main module and modules of two axes.
pub struct PhymotionEmulator {
    axes: Vec<Axis>,
    mechanics: SimConfig,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl PhymotionEmulator {
    /// `modules` axis modules of two axes each, every axis on `mechanics`, power stages on.
    pub fn new(modules: usize, mechanics: &SimConfig) -> Self {
        let axes = (1..=modules)
            .flat_map(|module| (1..=AXES_PER_MODULE).map(move |axis| module * 10 + axis))
            .zip(axes(modules * AXES_PER_MODULE, mechanics))
            .map(|(channel, sim)| Axis::new(channel, sim))
            .collect();
        Self { axes, mechanics: mechanics.clone(), input: Vec::new(), output: VecDeque::new(), malformed: 0 }
    }

    /// Every channel below `channels` that modules of two axes give, two modules at least.
    pub fn with_channels_below(channels: usize, mechanics: &SimConfig) -> Self {
        Self::new((channels.saturating_sub(1) / 10).max(2), mechanics)
    }

    fn find(&mut self, channel: usize) -> Option<&mut Axis> {
        self.axes.iter_mut().find(|axis| axis.channel == channel)
    }

    /// A controller reset: every axis at its power-up settings, where it stands.
    fn reset(&mut self) {
        let encoder = self.mechanics.encoder_counts_per_step.is_some();
        for axis in &mut self.axes {
            axis.sim.stop(axis.p(7));
            axis.parameters = factory(encoder);
            axis.power = true;
            axis.clear_errors();
            // A reset forgets the reference: the axis is no longer initialised.
            axis.initialised = false;
            axis.limit_reference = None;
        }
    }

    fn answer(&mut self, command: &str) -> Answer {
        match command {
            "IVR" => return Answer::Ack(VERSION.into()),
            "IM0" => return Answer::Ack("MCM01".into()),
            "ST" => return Answer::Ack("0".into()),
            "STC" => return done(),
            // The parameters to EEPROM: there is none here (see `Axis::carry_out`).
            "SA" => return done(),
            // A bare `S`: the EPICS driver sends it after `CR` until it is acknowledged, so the
            // controller acknowledges it once it is back. Read as the controller-level stop (an
            // axis's own is `M<m.a>S`): every axis stops; after a reset none moves anyway.
            "S" => {
                for axis in &mut self.axes {
                    axis.sim.stop(axis.p(7));
                }
                return done();
            }
            "CR" => {
                self.reset();
                return done();
            }
            _ => {}
        }
        if let Some(module) = command.strip_prefix("IM") {
            let numbered = !module.is_empty() && module.bytes().all(|b| b.is_ascii_digit());
            return if numbered { Answer::Refused } else { Answer::Unknown };
        }
        let (channel, order) = if let Some(rest) = command.strip_prefix("SEC") {
            match axis_address(rest) {
                Some((channel, "")) => (channel, "SEC"),
                _ => return Answer::Unknown,
            }
        } else if let Some(rest) = command.strip_prefix("SE") {
            match axis_address(rest) {
                Some((channel, "")) => (channel, "SE"),
                _ => return Answer::Unknown,
            }
        } else {
            match axis_address(command.strip_prefix('M').unwrap_or(command)) {
                Some(found) => found,
                None => return Answer::Unknown,
            }
        };
        let Some(axis) = self.find(channel) else { return Answer::Refused };
        match order {
            "SE" => Answer::Ack(axis.status_word().to_string()),
            "SEC" => {
                axis.clear_errors();
                done()
            }
            order => axis.command(order),
        }
    }

    fn telegram(&mut self, content: &[u8]) {
        let commands = match telegram(content) {
            Telegram::Commands(text) => text.to_string(),
            Telegram::Elsewhere => {
                self.malformed += 1;
                return;
            }
            Telegram::Broken => {
                self.malformed += 1;
                self.output.push_back(reply(&[NAK]));
                return;
            }
        };
        let mut answers = Vec::new();
        for command in commands.split(' ').filter(|c| !c.is_empty()) {
            match self.answer(command) {
                Answer::Ack(data) => {
                    answers.push(ACK);
                    answers.extend_from_slice(data.as_bytes());
                }
                Answer::Refused => answers.push(NAK),
                Answer::Unknown => {
                    self.malformed += 1;
                    answers.push(NAK);
                }
            }
        }
        self.output.push_back(reply(&answers));
    }
}

impl Emulator for PhymotionEmulator {
    fn name(&self) -> &'static str {
        "phytron"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.sim.advance(now);
            axis.watch();
        }
        self.input.extend_from_slice(bytes);
        loop {
            match self.input.iter().position(|b| *b == STX) {
                None => {
                    if !self.input.is_empty() {
                        self.input.clear();
                        self.malformed += 1;
                    }
                    return;
                }
                Some(0) => {}
                Some(noise) => {
                    self.input.drain(..noise);
                    self.malformed += 1;
                }
            }
            let Some(end) = self.input.iter().position(|b| *b == ETX) else {
                if self.input.len() > INPUT_LIMIT {
                    self.input.clear();
                    self.malformed += 1;
                }
                return;
            };
            let frame: Vec<u8> = self.input.drain(..=end).collect();
            self.telegram(&frame[1..end]);
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.find(channel).map(|axis| &mut axis.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(axis) = self.find(channel) else { return false };
        axis.power_error = true;
        axis.sim.stop(axis.p(7));
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn emulator() -> PhymotionEmulator {
        PhymotionEmulator::new(2, &SimConfig { encoder_counts_per_step: Some(1.0), ..crate::stage() })
    }

    /// A request telegram for address 0 carrying `commands`, checksum computed here.
    fn request(commands: &str) -> Vec<u8> {
        let mut checked = vec![b'0'];
        checked.extend_from_slice(commands.as_bytes());
        checked.push(b':');
        let sum = checked.iter().fold(0u8, |a, b| a ^ b);
        let mut out = vec![STX];
        out.extend_from_slice(&checked);
        out.extend_from_slice(format!("{sum:02X}").as_bytes());
        out.push(ETX);
        out
    }

    /// The answers of a reply telegram, its checksum checked: data, or "NAK".
    fn answers(frame: &[u8]) -> Vec<String> {
        assert_eq!((frame[0], frame[frame.len() - 1]), (STX, ETX), "{frame:?}");
        let content = &frame[1..frame.len() - 1];
        let (checked, digits) = content.split_at(content.len() - 2);
        assert_eq!(checked.last(), Some(&b':'));
        let sum = checked.iter().fold(0u8, |a, b| a ^ b);
        assert_eq!(digits, format!("{sum:02X}").as_bytes(), "reply checksum");
        let body = &checked[..checked.len() - 1];
        let mut out: Vec<String> = Vec::new();
        for byte in body {
            match *byte {
                ACK => out.push(String::new()),
                NAK => out.push("NAK".into()),
                other => out.last_mut().expect("ACK or NAK first").push(char::from(other)),
            }
        }
        out
    }

    fn ask(e: &mut PhymotionEmulator, seconds: f64, commands: &str) -> Vec<String> {
        e.handle_input(Instant::from_secs_f64(seconds), &request(commands));
        answers(&e.poll_transmit().expect("a reply"))
    }

    fn word(e: &mut PhymotionEmulator, seconds: f64, axis: &str) -> u32 {
        ask(e, seconds, &format!("SE{axis}"))[0].parse().expect("a decimal status")
    }

    #[test]
    fn the_checksum_is_the_xor_from_the_address_to_the_colon_in_two_uppercase_digits() {
        // '0' 'S' 'E' '1' '.' '1' ':' : 30 53 45 31 2E 31 3A, XORed by hand: 0x32.
        assert_eq!(xor_digits(b"0SE1.1:"), *b"32");
        assert_eq!(request("SE1.1"), b"\x020SE1.1:32\x03");
        // An ACK alone: 06 3A → 0x3C.
        assert_eq!(reply(&[ACK]), b"\x02\x06:3C\x03");
        // An ACK and "E": 06 45 3A → 0x79.
        assert_eq!(reply(b"\x06E"), b"\x02\x06E:79\x03");
        assert_eq!(xor_digits(&[0xA0, 0x0B]), *b"AB", "letters are uppercase");
    }

    #[test]
    fn every_command_of_a_telegram_is_answered_in_one_reply() {
        let mut e = emulator();
        let replies = ask(&mut e, 0.0, "SE1.1 M1.1P20R M1.1P22R M1.2P34R M2.2==H SE3.1 IM0");
        assert_eq!(replies, ["524864", "0", "0", "1", "E", "NAK", "MCM01"], "ready, in position, center switch");
        assert_eq!(e.malformed(), 0, "an axis it lacks is refused, not malformed");
        e.handle_input(Instant::ZERO, b"\x020SE1.1:XX\x03");
        assert_eq!(answers(&e.poll_transmit().unwrap()), ["524864"], "XX: not checked");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn broken_telegrams_are_refused_and_counted() {
        let mut e = emulator();
        e.handle_input(Instant::ZERO, b"\x020SE1.1:33\x03");
        assert_eq!(answers(&e.poll_transmit().unwrap()), ["NAK"], "wrong checksum");
        e.handle_input(Instant::ZERO, b"\x020SE1.1\x03");
        assert_eq!(answers(&e.poll_transmit().unwrap()), ["NAK"], "no checksum");
        assert_eq!(e.malformed(), 2);
        e.handle_input(Instant::ZERO, b"\x021SE1.1:33\x03");
        assert_eq!(e.poll_transmit(), None, "another controller's telegram");
        assert_eq!(e.malformed(), 3);
        e.handle_input(Instant::ZERO, b"~~");
        assert_eq!(e.malformed(), 4);
    }

    #[test]
    fn an_unknown_command_is_answered_nak_in_its_place() {
        let mut e = emulator();
        assert_eq!(ask(&mut e, 0.0, "M1.1X M1.1P99R M1.1P14=abc XYZ M1.1P20R"), ["NAK", "NAK", "NAK", "NAK", "0"]);
        assert_eq!(e.malformed(), 4);
    }

    #[test]
    fn identification_and_controller_status() {
        let mut e = emulator();
        assert_eq!(ask(&mut e, 0.0, "IVR IM0 ST STC"), [VERSION, "MCM01", "0", ""]);
        assert_eq!(ask(&mut e, 0.0, "IM1"), ["NAK"]);
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn moves_run_at_the_parameters_and_end_in_position() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M1.1P14=1000.000000 M1.1P04=1000.000000 M1.1P15=4000.000000 M1.1MA M1.1A500");
        assert_eq!(ask(&mut e, 0.25, "M1.1==H M1.1P20R"), ["N", "250"]);
        let w = word(&mut e, 0.25, "1.1");
        assert_eq!(w & (bit::BUSY | bit::RUNNING | bit::IN_POSITION), bit::BUSY | bit::RUNNING);
        assert_eq!(ask(&mut e, 1.0, "SE1.1 M1.1P20R"), ["524800", "500"], "ready and in position");
        ask(&mut e, 1.0, "M1.1-100");
        assert_eq!(ask(&mut e, 2.0, "M1.1P20R M1.1P21R M1.1P22R"), ["400", "400", "400"]);
        assert_eq!(ask(&mut e, 2.0, "M1.1P39=0.5 M1.1P20=0.000000 M1.1P21=5 M1.1P49=1"), ["", "", "NAK", "NAK"]);
        assert_eq!(ask(&mut e, 2.0, "M1.1P20R M1.1P22R"), ["0", "0"]);
        assert_eq!(ask(&mut e, 2.0, "M1.1P14=0 M1.1P14R"), ["NAK", "1000"]);
    }

    #[test]
    fn a_free_run_into_a_limit_switch_leaves_an_error_until_cleared() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M2.1P14=500000 M2.1P15=500000 M2.1L-");
        let w = word(&mut e, 5.0, "2.1");
        assert_eq!(w & (bit::MINUS_LIMIT | bit::LIMIT_ERROR | bit::BUSY), bit::MINUS_LIMIT | bit::LIMIT_ERROR);
        ask(&mut e, 5.0, "SEC2.1");
        assert_eq!(word(&mut e, 5.0, "2.1") & bit::LIMIT_ERROR, 0);
    }

    #[test]
    fn no_motion_without_the_power_stage_and_a_power_stage_error_until_cleared() {
        let mut e = emulator();
        assert_eq!(ask(&mut e, 0.0, "M1.2MD M1.2A100 M1.2L+ M1.2R+C"), ["", "NAK", "NAK", "NAK"]);
        assert_eq!(word(&mut e, 0.0, "1.2") & bit::POWER_READY, 0);
        assert!(e.raise_error(12) && !e.raise_error(13));
        assert_eq!(ask(&mut e, 0.0, "M1.2MA M1.2A100"), ["", "NAK"]);
        assert_eq!(word(&mut e, 0.0, "1.2") & (bit::POWER_ERROR | bit::POWER_READY), bit::POWER_ERROR);
        assert_eq!(ask(&mut e, 0.0, "SEC1.2 M1.2A100"), ["", ""]);
        assert!(e.raise_error(12));
        assert_eq!(ask(&mut e, 1.0, "M1.2C M1.2A100"), ["", ""], "an axis reset clears it too");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_reference_run_ends_initialised_on_the_center_switch() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M2.2P14=10000 M2.2P15=100000 M2.2A5000");
        ask(&mut e, 2.0, "M2.2P20=7000 M2.2P08=10000 M2.2P09=100000 M2.2R-C");
        assert_eq!(word(&mut e, 2.0, "2.2") & (bit::BUSY | bit::INITIALISED), bit::BUSY);
        let replies = ask(&mut e, 5.0, "SE2.2 M2.2P20R");
        let w: u32 = replies[0].parse().unwrap();
        assert_eq!(w & (bit::BUSY | bit::INITIALISED | bit::CENTER), bit::INITIALISED | bit::CENTER);
        assert_eq!(replies[1], "0");
    }

    #[test]
    fn a_controller_reset_restores_the_factory_parameters() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M1.1P14=123 M1.1MD");
        assert_eq!(ask(&mut e, 0.0, "CR M1.1P14R"), ["", "4000"]);
        assert_ne!(word(&mut e, 0.0, "1.1") & bit::POWER_READY, 0);
    }

    #[test]
    fn the_module_prefix_may_be_left_out_and_se_may_follow_the_axis() {
        let mut e = emulator();
        let replies = ask(&mut e, 0.0, "1.1P20R 1.1SE M1.1SE 1.2SEC M1.2SEC 3.1SE 1.1A100");
        assert_eq!(replies, ["0", "524864", "524864", "", "", "NAK", ""], "3.1: an axis it lacks");
        assert_eq!(ask(&mut e, 1.0, "1.1==H 1.1P20R"), ["E", "100"]);
        assert_eq!(ask(&mut e, 1.0, "1.1 .1P20R M.1P20R"), ["NAK", "NAK", "NAK"]);
        assert_eq!(e.malformed(), 3);
    }

    #[test]
    fn parameters_are_written_with_s_as_with_equals() {
        let mut e = emulator();
        let replies = ask(&mut e, 0.0, "M1.1P14S1234 M1.1P14R 1.1P20S12 M1.1P20R M1.1P03S0.5 M1.1P03R");
        assert_eq!(replies, ["", "1234", "", "12", "", "0.5"]);
        assert_eq!(ask(&mut e, 0.0, "M1.1P15S-5 M1.1P21S3 M1.1P14R"), ["NAK", "NAK", "1234"], "refused alike");
        assert_eq!(ask(&mut e, 0.0, "M1.1P14S M1.1P14Sx M1.1P14S=5"), ["NAK", "NAK", "NAK"]);
        assert_eq!(e.malformed(), 3);
    }

    #[test]
    fn parameters_run_to_p58_the_last_four_plain_values() {
        let mut e = emulator();
        assert_eq!(ask(&mut e, 0.0, "M1.1P55R M1.1P58R M1.1P59R"), ["0", "0", "NAK"]);
        assert_eq!(e.malformed(), 1);
        let replies = ask(&mut e, 0.0, "M1.1P55=7.25 M1.1P58S-3 M1.1P55R M1.1P58R M1.2P55R");
        assert_eq!(replies, ["", "", "7.25", "-3", "0"]);
        let all: Vec<String> = (1..=58).map(|n| format!("1.1P{n:02}R")).collect();
        let replies = ask(&mut e, 0.0, &format!(" {}", all.join(" ")));
        assert_eq!(replies.len(), 58, "the MBI server's read of every parameter");
        assert!(replies.iter().all(|r| r != "NAK"));
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn a_reference_run_to_a_limit_switch_ends_there_initialised_with_the_error_motorphytron_clears() {
        let mut e = emulator();
        ask(&mut e, 0.0, "SEC1.1 M1.1P08=500000 M1.1P09=500000 M1.1P20=7 M1.1R+");
        assert_eq!(word(&mut e, 0.5, "1.1") & (bit::BUSY | bit::INITIALISED), bit::BUSY);
        let replies = ask(&mut e, 5.0, "SE1.1 M1.1P20R M1.1P22R");
        let w: u32 = replies[0].parse().unwrap();
        assert_eq!(w & 0xFA29, 0x1208, "motorPhytron's mask after a limit homing +");
        assert_ne!(w & bit::PLUS_LIMIT, 0, "on the switch");
        assert_eq!(replies[1..], ["0", "0"], "the counters are 0 there");
        ask(&mut e, 5.0, "SEC1.1");
        assert_eq!(word(&mut e, 5.0, "1.1") & 0xFA29, 0x0208, "SEC clears the error, the axis stays initialised");
        ask(&mut e, 5.0, "1.1R-");
        let w = word(&mut e, 10.0, "1.1");
        assert_eq!(w & 0xFA19, 0x1208, "motorPhytron's mask after a limit homing −");
        assert_eq!(ask(&mut e, 10.0, "M1.1P20R"), ["0"]);
        // Stopped before the switch: nothing initialised.
        ask(&mut e, 10.0, "M1.2R+");
        ask(&mut e, 10.1, "M1.2S");
        let w = word(&mut e, 12.0, "1.2");
        assert_eq!(w & (bit::BUSY | bit::INITIALISED | bit::PLUS_LIMIT | bit::LIMIT_ERROR), 0);
        assert_ne!(ask(&mut e, 12.0, "M1.2P20R"), ["0"]);
        assert_eq!(ask(&mut e, 12.0, "M1.2MD M1.2R+ M1.2R-"), ["", "NAK", "NAK"], "no power stage, no run");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn every_reference_run_motorphytron_sends_is_taken_as_the_run_to_the_center_switch() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M2.1P14=100000 M2.1P15=1000000 M2.1P08=100000 M2.1P09=1000000");
        for (i, order) in REFERENCES.iter().enumerate() {
            let t = 2.0 * i as f64;
            ask(&mut e, t, "M2.1A5000");
            assert_eq!(ask(&mut e, t + 1.0, &format!("M2.1P20=7 M2.1{order}")), ["", ""], "{order}");
            let replies = ask(&mut e, t + 2.0, "SE2.1 M2.1P20R");
            let w: u32 = replies[0].parse().unwrap();
            assert_eq!(w & (bit::BUSY | bit::INITIALISED | bit::CENTER), bit::INITIALISED | bit::CENTER, "{order}");
            assert_eq!(replies[1], "0", "{order}");
        }
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn sn_stops_with_the_emergency_ramp_and_sa_does_nothing() {
        let mut e = emulator();
        ask(&mut e, 0.0, "M1.1P14=1000 M1.1P07=1000 M1.1L+");
        assert_eq!(ask(&mut e, 1.0, "1.1SN M1.1==H"), ["", "N"]);
        assert_eq!(ask(&mut e, 1.5, "M1.1==H"), ["N"], "P07: a second to stop from 1000 Hz, P15 a quarter");
        assert_eq!(ask(&mut e, 2.5, "M1.1==H"), ["E"]);
        assert_eq!(ask(&mut e, 2.5, "SA M1.1SA 1.2SA M1.1P14R"), ["", "", "", "1000"], "no EEPROM: nothing happens");
        assert_eq!(ask(&mut e, 2.5, "M3.1SN M3.1SA"), ["NAK", "NAK"], "an axis it lacks");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn empty_fields_between_spaces_are_no_commands() {
        let mut e = emulator();
        assert_eq!(ask(&mut e, 0.0, " 1.1SE  M1.1P20R   SE1.2 "), ["524864", "0", "524864"]);
        assert_eq!(ask(&mut e, 0.0, "M1.1P20R "), ["0"]);
        assert_eq!(e.malformed(), 0);
        assert_eq!(ask(&mut e, 0.0, "   "), ["NAK"], "no command at all: broken");
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn telegrams_come_whole_whatever_the_pieces() {
        let mut e = emulator();
        let mut bytes = request("M1.1P20R");
        bytes.extend(request("SE1.1"));
        for byte in bytes {
            e.handle_input(Instant::ZERO, &[byte]);
        }
        assert_eq!(answers(&e.poll_transmit().unwrap()), ["0"]);
        assert_eq!(answers(&e.poll_transmit().unwrap()), ["524864"]);
        assert_eq!(e.malformed(), 0);
    }
}
