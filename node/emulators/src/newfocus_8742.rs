//! The New Focus (Newport) Model 8742 Picomotor Controller/Driver: four open-loop picomotor
//! channels behind one controller, reached over Ethernet (Telnet, TCP port 23) or USB, ASCII
//! commands `[cc>][xx]MN[nn|?]` (`cc` the controller's RS-485 address, `xx` the axis 1–4, `MN`
//! the mnemonic in either case, `nn` the parameter or `?`), replies ending CR LF.
//!
//! # Witnesses
//!
//! 1. Newport's "Picomotor Controller/Driver User's Manual, Model 8742" (declaration of
//!    conformity dated 3 March 2017), as the pages stored from easymanua.ls, manualslib.com and
//!    manualshive.com could be read (not all: the pages of `AB`, `AC`, `DH`, `MV`, `PA`, `ST`,
//!    `VA`, `SM`, `ZZ` and the error appendix were not among them):
//!    - §6.1 "Command Syntax": `xx`, two letters, `nn`; a command ends with a carriage return;
//!      upper or lower case; a field not needed may be left blank (a space): `1DH`, `VE?`.
//!      Several commands on one line are separated by `;` (`3VA1500; 3PA1000`), and the
//!      answers of the queries of one line come back as one, separated by `;` (`3VA?; 3AC?`
//!      answers `2000; 30000`).
//!    - §6.2.1 (69): the axis number of an axis command is 1 to 4; `*IDN?` answers `New_Focus
//!      8742 v1.9 10/23/12 SN10001` (company, model, firmware version and date, serial).
//!    - `MC` (74): scans the motors and sets their types; refused with "MOTION IN PROGRESS"
//!      while an axis moves. `xxMD?` (74): 0 while a motion is in progress, 1 when not.
//!    - `PR` (77): relative move, −2147483648 to +2147483647 steps, default 0; while the axis
//!      moves it is ignored with a "MOTION IN PROGRESS" error; `ST` or `AB` end it. `xxPR?`
//!      answers the target position.
//!    - `QM` (78, 79): motor type 0 none, 1 unknown, 2 'Tiny', 3 'Standard'; a 'Tiny' runs at
//!      1750 steps/s at most; `xxQM?` answers the setting. `RS` (79): a soft reset, the
//!      parameters reloaded from memory and home (`DH`) set to 0.
//!    - `TE?` (86), `TB?` (8743-CL manual p. 113, the same family): error codes of up to three
//!      digits, 0–99 for the controller, 100–199 for axis 1, 200–299 axis 2 …; a FIFO ten
//!      deep, each error read once; `TB?` answers `108, MOTOR NOT CONNECTED` and `0, NO ERROR
//!      DETECTED`. `xxTP?` (87): the steps counted since power-up, reset or `DH`.
//! 2. The EPICS module epics-motor/motorNewFocus (commit 0f86a5b, April 2026;
//!    `874xMotorDriver.cpp` and `newfocus8742.cmd`, read only for the bytes a client sends and
//!    reads): output terminator CR, input CR LF; `VE?` answered by the model first (`8742 …`);
//!    `1 AC 100000.000000`, `1 VA …`, `1 PA …`, `1 PR …` (fields separated by spaces, numbers
//!    with six decimals), `1 MV +`, `1 ST`, `1 DH 0.000000`, `1 TP?`, `1 MD?`, its home being
//!    `1 MT +` or `1 MZ +` (8743-CL commands); a controller prefix `1>3` addresses axis 3 of
//!    controller 1, and the answer comes back prefixed `1>`.
//! 3. pylablib's `devices/Newport/picomotor.py` (`Picomotor8742`, stored copy 380686e): over
//!    the network writes end with LF; it flushes what the controller sent at connection;
//!    `MV+`/`MV-`, `AB` stops all axes at once, `SC?` a bit mask of the addresses (bit
//!    `addr`), `SD?` 1 when the scan is done, `SA?`, `QM?`, `VA?`, `AC?`, `DH<n>`, `*RST`,
//!    `SM`, `*RCL0|1`, `HOSTNAME?`, `IPMODE?`, `IPADDR?`, `GATEWAY?`, `NETMASK?`.
//! 4. cnanders/matlab-newfocus-model-8742 (`Model8742.m`, commit 271e035): every TCP
//!    connection first receives six bytes, `255 253 3 255 251 1` (Telnet IAC DO
//!    SUPPRESS-GO-AHEAD, IAC WILL ECHO); `ST` stops with the `AC` acceleration; `VA` 1–2000
//!    steps/s, `AC` 1–200000 steps/s², `DH?`, `PA?`, `XX` purges the memory. Another Ethernet
//!    client (a lab's `Picomotor8742` TCP class) skips a first reply beginning with byte 255.
//! 5. InstrumentKit's `PicoMotorController8742` (a stored copy, its docstrings' examples):
//!    `VE?` answers `8742 Version 2.2 08/01/13`, `*IDN?` `New_Focus 8742 v2.2 08/01/13
//!    13991`, `TB?` `0, NO ERROR DETECTED`, `MACADDR?` `5827809, 8087`; `ZZ` takes the
//!    configuration bits as binary digits (`ZZ11`).
//! 6. A public comparison of the PAMC-204 and the 8742 (mechano-transformer/pypamc-204 docs,
//!    2025), quoting the 8742 manual's appendix: the error codes 0 no error, 3 over-temperature
//!    shutdown, 6 command does not exist, 7 parameter out of range, 9 axis number out of range,
//!    x08 motor not connected, x14 motion in progress.
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Units.** One picomotor step is one simulator step; every position, velocity (steps/s)
//!   and acceleration (steps/s²) is the simulator's number.
//! - **Channels.** The controller always has axes 1 to 4; `channels` of them (1 to 4, from 1)
//!   have a motor (a simulated axis). An axis without one answers its queries (`TP?` 0, `MD?`
//!   1, `QM?` 0) and refuses motions with x08 MOTOR NOT CONNECTED. The controller's address
//!   is 1; a line addressed `n>` to another address is answered by nobody (malformed).
//! - **Lines.** CR or LF ends a line (CR LF is one end); spaces between fields are ignored.
//!   The answers of a line's queries are joined by `; ` and end with CR LF; a line without a
//!   query gets nothing. Commands are answered by nothing; a refused one queues an error. A
//!   controller command ignores an axis prefix (`1AB` is `AB`). A two-letter mnemonic ends
//!   after two letters (`1PAabc` is `PA` with a bad parameter); the network ones are words.
//!   Numbers may carry a sign and a fraction (the EPICS driver's `%f`); they are rounded to
//!   whole steps. 256 bytes without a line end overflow the input buffer.
//! - **Errors** (queued for `TE?`/`TB?`, the oldest dropped when ten wait): an unknown
//!   mnemonic, a query of a command that has none or a command form of a query, or a line
//!   that is not ASCII: 6 COMMAND DOES NOT EXIST; a parameter missing, malformed or beyond
//!   its range: 7 PARAMETER OUT OF RANGE; an axis command without an axis or outside 1–4: 9
//!   AXIS NUMBER OUT OF RANGE. These are malformed requests. `PA`, `PR`, `MV`, `DH` of a
//!   moving axis, and `MC` while one moves: x14 MOTION IN PROGRESS; a motion of an axis
//!   without motor: x08. The other codes of the appendix could not be read.
//! - **Motion.** `PA`/`PR` (missing parameter: 0) ramp at `AC` up to `VA`; `MV+`/`MV-` run
//!   at `VA` until `ST` (decelerating at `AC`; without an axis every axis) or `AB` (every axis
//!   at once). `VA`/`AC` set during a motion serve the next one. An open-loop picomotor has
//!   no limit or home switch input: a carriage at a mechanical end stops there and the motion
//!   is done, with no error. There is no home search: `OR`, `MT`, `MZ` do not exist on the
//!   8742 (error 6); home is defined by `xxDHnn` (default 0), the position becoming `nn`;
//!   `xxDH?` answers the last `nn`. `xxPA?`/`xxPR?` answer the last target (`PA`, `PR`, `DH`).
//! - **Power-up**: positions 0, `VA` 2000, `AC` 100000, motor types 3 ('Standard') where a
//!   motor is (as the power-up scan finds them) and 0 elsewhere, `ZZ` 0, the error FIFO empty.
//!   `SM` saves `VA`, `AC`, `QM`; `*RST`/`RS` stop every axis, reload them, set positions and
//!   home to 0 and empty the FIFO; `*RCL1` reloads them, `*RCL0` takes the factory values,
//!   `XX` resets the memory to them. `MC` sets the types found (3 or 0) without stepping.
//!   `SC0..2` is taken (no other controller is on the RS-485 line), `SC?` answers 2 (bit 1),
//!   `SD?` 1. The network settings are kept and read back: `HOSTNAME?` `8742-10001`,
//!   `IPMODE?` 1, `IPADDR?` `192.168.0.254`, `GATEWAY?` `192.168.0.1`, `NETMASK?`
//!   `255.255.255.0`, `MACADDR?` `5827809, 8087`. `VE?` answers `8742 Version 2.2 08/01/13`,
//!   `*IDN?` `New_Focus 8742 v2.2 08/01/13 SN10001`.
//! - **Telnet.** `new` (the Ethernet controller) queues the six negotiation bytes before
//!   anything else, and again for the next connection after one closes; it never echoes
//!   despite WILL ECHO (no client reads an echo). Telnet commands from the client (IAC …) are
//!   dropped. `usb` is the same controller without Telnet: no greeting, every byte is data.
//! - `raise_error` is a motor disconnected: the axis stops at once and x08 is queued.

use crate::emulator::{axes, Connection};
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Axes of one controller.
const AXES: usize = 4;
/// The command terminator (LF is taken as CR).
const CR: &[u8] = b"\r";
/// The reply terminator.
const CRLF: &str = "\r\n";
/// Bytes without a terminator the controller holds before its buffer overflows.
const INPUT_BUFFER: usize = 256;
/// What a TCP connection receives first: IAC DO SUPPRESS-GO-AHEAD, IAC WILL ECHO.
const TELNET_GREETING: [u8; 6] = [255, 253, 3, 255, 251, 1];
const IAC: u8 = 255;
const SB: u8 = 250;
const SE: u8 = 240;

const IDENTIFICATION: &str = "New_Focus 8742 v2.2 08/01/13 SN10001";
const VERSION: &str = "8742 Version 2.2 08/01/13";

const DEFAULT_VELOCITY: u32 = 2_000;
const MAX_VELOCITY: u32 = 2_000;
const TINY_MAX_VELOCITY: u32 = 1_750;
const DEFAULT_ACCELERATION: u32 = 100_000;
const MAX_ACCELERATION: u32 = 200_000;
const STANDARD: u8 = 3;
const TINY: u8 = 2;
const ERROR_FIFO: usize = 10;

/// Every mnemonic the controller knows.
const MNEMONICS: [&str; 31] = [
    "*IDN", "*RCL", "*RST", "AB", "AC", "DH", "GATEWAY", "HOSTNAME", "IPADDR", "IPMODE", "MACADDR", "MC", "MD", "MV",
    "NETMASK", "PA", "PR", "QM", "RS", "SA", "SC", "SD", "SM", "ST", "TB", "TE", "TP", "VA", "VE", "XX", "ZZ",
];

const COMMAND_DOES_NOT_EXIST: u16 = 6;
const PARAMETER_OUT_OF_RANGE: u16 = 7;
const AXIS_OUT_OF_RANGE: u16 = 9;
/// Axis errors: add 100 × the axis.
const MOTOR_NOT_CONNECTED: u16 = 8;
const MOTION_IN_PROGRESS: u16 = 14;

/// The text `TB?` gives a code.
fn error_text(code: u16) -> &'static str {
    match (code / 100, code % 100) {
        (0, 0) => "NO ERROR DETECTED",
        (0, 3) => "OVER TEMPERATURE SHUTDOWN",
        (0, 6) => "COMMAND DOES NOT EXIST",
        (0, 7) => "PARAMETER OUT OF RANGE",
        (0, 9) => "AXIS NUMBER OUT OF RANGE",
        (1..=4, 8) => "MOTOR NOT CONNECTED",
        (1..=4, 14) => "MOTION IN PROGRESS",
        _ => "UNKNOWN ERROR",
    }
}

/// Why a command was not carried out.
#[derive(Debug, PartialEq)]
enum Refusal {
    /// Not for this controller: nobody answers (a malformed request).
    NotAddressed,
    /// An error queued; `malformed` when the request was not well-formed.
    Error { code: u16, malformed: bool },
}

fn malformed(code: u16) -> Refusal {
    Refusal::Error { code, malformed: true }
}

fn refused(code: u16) -> Refusal {
    Refusal::Error { code, malformed: false }
}

/// The working parameters `SM` saves.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Parameters {
    velocity: u32,
    acceleration: u32,
    motor_type: u8,
}

/// One of the four channels; `sim` is None where no motor is connected.
#[derive(Debug)]
struct Channel {
    sim: Option<SimAxis>,
    parameters: Parameters,
    saved: Parameters,
    /// The last target (`PA`, `PR`, `DH`), steps.
    target: i64,
    /// The last `DH` value.
    home: i64,
}

impl Channel {
    fn new(sim: Option<SimAxis>) -> Self {
        let parameters = factory(sim.is_some());
        Self { sim, parameters, saved: parameters, target: 0, home: 0 }
    }

    fn position(&self) -> i64 {
        self.sim.as_ref().map_or(0, |sim| sim.status().position.round() as i64)
    }

    fn is_moving(&self) -> bool {
        self.sim.as_ref().is_some_and(SimAxis::is_moving)
    }

    /// The motor, if the axis (numbered from 1) may start a motion now.
    fn motor(&mut self, axis: usize) -> Result<&mut SimAxis, Refusal> {
        let code = |error: u16| axis as u16 * 100 + error;
        let moving = self.is_moving();
        match self.sim.as_mut() {
            None => Err(refused(code(MOTOR_NOT_CONNECTED))),
            Some(_) if moving => Err(refused(code(MOTION_IN_PROGRESS))),
            Some(sim) => Ok(sim),
        }
    }
}

/// The factory parameters of a channel, with or without its motor.
fn factory(motor: bool) -> Parameters {
    Parameters {
        velocity: DEFAULT_VELOCITY,
        acceleration: DEFAULT_ACCELERATION,
        motor_type: if motor { STANDARD } else { 0 },
    }
}

/// Where the Telnet filter stands between two pieces of input.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Telnet {
    Data,
    Command,
    Option,
    Sub,
    SubCommand,
}

/// The network settings, kept and read back.
#[derive(Debug)]
struct Network {
    hostname: String,
    ipmode: u8,
    ipaddr: String,
    gateway: String,
    netmask: String,
}

/// A New Focus 8742 Picomotor controller with axes 1 to 4, motors on the first `channels`.
#[derive(Debug)]
pub struct Picomotor8742Emulator {
    channels: Vec<Channel>,
    lines: Lines,
    /// None over USB: no Telnet.
    telnet: Option<Telnet>,
    output: VecDeque<Vec<u8>>,
    errors: VecDeque<u16>,
    malformed: usize,
    address: u8,
    configuration: u8,
    network: Network,
}

impl Picomotor8742Emulator {
    /// An Ethernet (Telnet) controller with motors on axes 1 to `channels` (one at least, four
    /// at most); the Telnet negotiation bytes are the first thing it sends.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let mut emulator = Self::usb(channels, mechanics);
        emulator.telnet = Some(Telnet::Data);
        emulator.output.push_back(TELNET_GREETING.to_vec());
        emulator
    }

    /// The same controller over USB: no Telnet negotiation, every byte is data.
    pub fn usb(channels: usize, mechanics: &SimConfig) -> Self {
        let motors = channels.clamp(1, AXES);
        let mut sims = axes(motors, mechanics).into_iter();
        Self {
            channels: (0..AXES).map(|_| Channel::new(sims.next())).collect(),
            lines: Lines::new(CR, INPUT_BUFFER),
            telnet: None,
            output: VecDeque::new(),
            errors: VecDeque::new(),
            malformed: 0,
            address: 1,
            configuration: 0,
            network: Network {
                hostname: "8742-10001".into(),
                ipmode: 1,
                ipaddr: "192.168.0.254".into(),
                gateway: "192.168.0.1".into(),
                netmask: "255.255.255.0".into(),
            },
        }
    }

    fn push_error(&mut self, code: u16) {
        if self.errors.len() == ERROR_FIFO {
            self.errors.pop_front();
        }
        self.errors.push_back(code);
    }

    /// Telnet commands out, LF as CR: the data bytes of `bytes`.
    fn data(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut data = Vec::with_capacity(bytes.len());
        for &byte in bytes {
            let byte_in = if byte == b'\n' { b'\r' } else { byte };
            self.telnet = match (self.telnet, byte) {
                (None, _) => {
                    data.push(byte_in);
                    None
                }
                (Some(Telnet::Data), IAC) => Some(Telnet::Command),
                (Some(Telnet::Data), _) | (Some(Telnet::Command), IAC) => {
                    data.push(byte_in);
                    Some(Telnet::Data)
                }
                (Some(Telnet::Command), 251..=254) => Some(Telnet::Option),
                (Some(Telnet::Command), SB) => Some(Telnet::Sub),
                (Some(Telnet::Command | Telnet::Option), _) => Some(Telnet::Data),
                (Some(Telnet::Sub | Telnet::SubCommand), IAC) => Some(Telnet::SubCommand),
                (Some(Telnet::SubCommand), SE) => Some(Telnet::Data),
                (Some(Telnet::Sub | Telnet::SubCommand), _) => Some(Telnet::Sub),
            };
        }
        data
    }

    /// Carry out one line; queue the answers of its queries.
    fn handle_line(&mut self, line: &[u8]) {
        let Some(text) = std::str::from_utf8(line).ok().filter(|t| t.is_ascii()) else {
            self.malformed += 1;
            self.push_error(COMMAND_DOES_NOT_EXIST);
            return;
        };
        let mut answers = Vec::new();
        for command in text.split(';').map(str::trim).filter(|c| !c.is_empty()) {
            match self.command(command) {
                Ok(Some(answer)) => answers.push(answer),
                Ok(None) => {}
                Err(Refusal::NotAddressed) => self.malformed += 1,
                Err(Refusal::Error { code, malformed }) => {
                    self.malformed += usize::from(malformed);
                    self.push_error(code);
                }
            }
        }
        if !answers.is_empty() {
            self.output.push_back(format!("{}{CRLF}", answers.join("; ")).into_bytes());
        }
    }

    /// One command `[cc>][xx]MN[nn|?]`: its answer, if a query.
    fn command(&mut self, text: &str) -> Result<Option<String>, Refusal> {
        let (prefix, rest) = match text.split_once('>') {
            Some((address, rest)) => {
                let address: u8 = address.trim().parse().map_err(|_| malformed(COMMAND_DOES_NOT_EXIST))?;
                if address != self.address {
                    return Err(Refusal::NotAddressed);
                }
                (Some(address), rest.trim_start())
            }
            None => (None, text),
        };
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        let axis = (digits > 0).then(|| rest[..digits].parse::<usize>().unwrap_or(usize::MAX));
        let rest = rest[digits..].trim_start();
        let star = usize::from(rest.starts_with('*'));
        let letters = rest[star..].bytes().take_while(u8::is_ascii_alphabetic).count();
        // The longer names are whole words; a two-letter mnemonic may run into letters that
        // are its (bad) argument.
        let word = rest[..star + letters].to_ascii_uppercase();
        let length = if MNEMONICS.contains(&word.as_str()) { word.len() } else { (star + letters).min(2) };
        let mnemonic = &word[..length];
        let argument = rest[length..].trim();
        let answer = self.execute(axis, mnemonic, argument)?;
        Ok(answer.map(|a| match prefix {
            Some(p) => format!("{p}>{a}"),
            None => a,
        }))
    }

    /// Carry out `mnemonic` with `argument` (`?` for a query) for `axis`, if given.
    fn execute(&mut self, axis: Option<usize>, mnemonic: &str, argument: &str) -> Result<Option<String>, Refusal> {
        let query = argument == "?";
        let answer = |text: &str| Ok(Some(text.to_string()));
        match mnemonic {
            "AC" | "DH" | "MD" | "MV" | "PA" | "PR" | "QM" | "TP" | "VA" => {
                let index = axis.filter(|a| (1..=AXES).contains(a)).ok_or(malformed(AXIS_OUT_OF_RANGE))?;
                self.axis_command(index, mnemonic, argument)
            }
            "ST" if !query => match axis {
                None => {
                    for channel in &mut self.channels {
                        let acceleration = f64::from(channel.parameters.acceleration);
                        channel.sim.iter_mut().for_each(|sim| sim.stop(acceleration));
                    }
                    Ok(None)
                }
                Some(a) if (1..=AXES).contains(&a) => self.axis_command(a, mnemonic, argument),
                Some(_) => Err(malformed(AXIS_OUT_OF_RANGE)),
            },
            "*IDN" if query => answer(IDENTIFICATION),
            "VE" if query => answer(VERSION),
            "TE" if query => Ok(Some(self.errors.pop_front().unwrap_or(0).to_string())),
            "TB" if query => {
                let code = self.errors.pop_front().unwrap_or(0);
                Ok(Some(format!("{code}, {}", error_text(code))))
            }
            "AB" if argument.is_empty() => {
                self.channels.iter_mut().filter_map(|c| c.sim.as_mut()).for_each(|sim| sim.stop(0.0));
                Ok(None)
            }
            "*RST" | "RS" if argument.is_empty() => {
                self.errors.clear();
                for channel in &mut self.channels {
                    channel.parameters = channel.saved;
                    channel.target = 0;
                    channel.home = 0;
                    if let Some(sim) = channel.sim.as_mut() {
                        sim.stop(0.0);
                        sim.set_position(0.0);
                    }
                }
                Ok(None)
            }
            "*RCL" => {
                let saved = match number(argument) {
                    Some(0) => false,
                    Some(1) => true,
                    _ => return Err(malformed(PARAMETER_OUT_OF_RANGE)),
                };
                for channel in &mut self.channels {
                    channel.parameters = if saved { channel.saved } else { factory(channel.sim.is_some()) };
                }
                Ok(None)
            }
            "SM" if argument.is_empty() => {
                self.channels.iter_mut().for_each(|c| c.saved = c.parameters);
                Ok(None)
            }
            "XX" if argument.is_empty() => {
                self.channels.iter_mut().for_each(|c| c.saved = factory(c.sim.is_some()));
                Ok(None)
            }
            "MC" if argument.is_empty() => {
                if let Some(moving) = self.channels.iter().position(Channel::is_moving) {
                    return Err(refused((moving as u16 + 1) * 100 + MOTION_IN_PROGRESS));
                }
                for channel in &mut self.channels {
                    channel.parameters.motor_type = factory(channel.sim.is_some()).motor_type;
                }
                Ok(None)
            }
            "SA" if query => Ok(Some(self.address.to_string())),
            "SA" => {
                self.address = ranged(argument, 1, 31)? as u8;
                Ok(None)
            }
            "SC" if query => Ok(Some((1u32 << self.address).to_string())),
            "SC" => ranged(argument, 0, 2).map(|_| None),
            "SD" if query => answer("1"),
            "ZZ" if query => Ok(Some(format!("{:b}", self.configuration))),
            "ZZ" => {
                let bits =
                    (!argument.is_empty() && argument.len() <= 8 && argument.bytes().all(|b| b == b'0' || b == b'1'))
                        .then(|| u8::from_str_radix(argument, 2).ok())
                        .flatten()
                        .ok_or(malformed(PARAMETER_OUT_OF_RANGE))?;
                self.configuration = bits;
                Ok(None)
            }
            "IPMODE" if query => Ok(Some(self.network.ipmode.to_string())),
            "IPMODE" => {
                self.network.ipmode = ranged(argument, 0, 1)? as u8;
                Ok(None)
            }
            "MACADDR" if query => answer("5827809, 8087"),
            "HOSTNAME" | "IPADDR" | "GATEWAY" | "NETMASK" => {
                let network = &mut self.network;
                let field = match mnemonic {
                    "HOSTNAME" => &mut network.hostname,
                    "IPADDR" => &mut network.ipaddr,
                    "GATEWAY" => &mut network.gateway,
                    _ => &mut network.netmask,
                };
                if query {
                    return Ok(Some(field.clone()));
                }
                if argument.is_empty() || argument.contains(char::is_whitespace) {
                    return Err(malformed(PARAMETER_OUT_OF_RANGE));
                }
                *field = argument.to_string();
                Ok(None)
            }
            _ => Err(malformed(COMMAND_DOES_NOT_EXIST)),
        }
    }

    /// An axis command for `axis` (1 to 4).
    fn axis_command(&mut self, axis: usize, mnemonic: &str, argument: &str) -> Result<Option<String>, Refusal> {
        let query = argument == "?";
        let channel = &mut self.channels[axis - 1];
        let answer = |value: i64| Ok(Some(value.to_string()));
        let p = channel.parameters;
        let (velocity, acceleration) = (f64::from(p.velocity), f64::from(p.acceleration));
        match (mnemonic, query) {
            ("TP", true) => answer(channel.position()),
            ("MD", true) => answer(i64::from(!channel.is_moving())),
            ("PA" | "PR", true) => answer(channel.target),
            ("DH", true) => answer(channel.home),
            ("VA", true) => answer(i64::from(p.velocity)),
            ("AC", true) => answer(i64::from(p.acceleration)),
            ("QM", true) => answer(i64::from(p.motor_type)),
            ("VA", false) => {
                let max = if p.motor_type == TINY { TINY_MAX_VELOCITY } else { MAX_VELOCITY };
                channel.parameters.velocity = ranged(argument, 1, i64::from(max))? as u32;
                Ok(None)
            }
            ("AC", false) => {
                channel.parameters.acceleration = ranged(argument, 1, i64::from(MAX_ACCELERATION))? as u32;
                Ok(None)
            }
            ("QM", false) => {
                channel.parameters.motor_type = ranged(argument, 0, 3)? as u8;
                Ok(None)
            }
            ("PA" | "PR" | "DH", false) => {
                let value = if argument.is_empty() { 0 } else { ranged(argument, i32::MIN.into(), i32::MAX.into())? };
                let position = channel.position();
                let sim = channel.motor(axis)?;
                match mnemonic {
                    "DH" => {
                        sim.set_position(value as f64);
                        channel.home = value;
                        channel.target = value;
                    }
                    _ => {
                        let relative = mnemonic == "PR";
                        sim.move_to(value as f64, relative, 0.0, velocity, acceleration);
                        channel.target = if relative { position + value } else { value };
                    }
                }
                Ok(None)
            }
            ("MV", false) => {
                let direction = match argument {
                    "+" => 1.0,
                    "-" => -1.0,
                    _ => return Err(malformed(PARAMETER_OUT_OF_RANGE)),
                };
                channel.motor(axis)?.move_velocity(0.0, direction * velocity, acceleration);
                Ok(None)
            }
            ("ST", false) if argument.is_empty() => {
                channel.sim.iter_mut().for_each(|sim| sim.stop(acceleration));
                Ok(None)
            }
            _ => Err(malformed(COMMAND_DOES_NOT_EXIST)),
        }
    }
}

/// A decimal number, sign and fraction optional, rounded to a whole number; None when it is not
/// one (or is beyond any range the controller takes).
fn number(text: &str) -> Option<i64> {
    let digits = text.strip_prefix(['+', '-']).unwrap_or(text);
    let (whole, fraction) = digits.split_once('.').unwrap_or((digits, ""));
    let all_digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    if whole.len() + fraction.len() == 0 || !all_digits(whole) || !all_digits(fraction) || whole.len() > 12 {
        return None;
    }
    text.parse::<f64>().ok().filter(|x| x.is_finite()).map(|x| x.round() as i64)
}

/// A number within `min..=max`, else error 7.
fn ranged(text: &str, min: i64, max: i64) -> Result<i64, Refusal> {
    number(text).filter(|n| (min..=max).contains(n)).ok_or(malformed(PARAMETER_OUT_OF_RANGE))
}

impl Emulator for Picomotor8742Emulator {
    fn name(&self) -> &'static str {
        "newfocus_8742"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for sim in self.channels.iter_mut().filter_map(|c| c.sim.as_mut()) {
            sim.advance(now);
        }
        let data = self.data(bytes);
        for line in self.lines.push(&data) {
            if !line.iter().all(u8::is_ascii_whitespace) {
                self.handle_line(&line);
            }
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.channels.get_mut(channel.checked_sub(1)?)?.sim.as_mut()
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(sim) = self.axis(channel) else { return false };
        sim.stop(0.0);
        self.push_error(channel as u16 * 100 + MOTOR_NOT_CONNECTED);
        true
    }

    fn handle_closed(&mut self, connection: Connection) {
        let _ = connection;
        // What was queued for the closed connection is lost, with the line it had begun; the
        // next connection is greeted anew.
        self.output.clear();
        self.malformed += self.lines.overflowed();
        self.lines = Lines::new(CR, INPUT_BUFFER);
        if self.telnet.is_some() {
            self.telnet = Some(Telnet::Data);
            self.output.push_back(TELNET_GREETING.to_vec());
        }
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

    /// A USB controller (no Telnet greeting) with `channels` motors.
    fn usb(channels: usize) -> Picomotor8742Emulator {
        Picomotor8742Emulator::usb(channels, &stage())
    }

    /// Every byte sent in answer to `line` (CR-terminated), as text.
    fn send(e: &mut Picomotor8742Emulator, now: Instant, line: &str) -> String {
        e.handle_input(now, format!("{line}\r").as_bytes());
        let bytes: Vec<u8> = std::iter::from_fn(|| e.poll_transmit()).flatten().collect();
        String::from_utf8(bytes).expect("ASCII")
    }

    fn error(e: &mut Picomotor8742Emulator) -> String {
        send(e, at(0), "TB?")
    }

    #[test]
    fn the_telnet_greeting_comes_first_and_again_after_a_reconnection() {
        let mut e = Picomotor8742Emulator::new(4, &stage());
        assert_eq!(e.poll_transmit(), Some(vec![255, 253, 3, 255, 251, 1]));
        assert_eq!(e.poll_transmit(), None);
        // The client's own negotiation is no command.
        e.handle_input(at(0), &[255, 254, 3, 255, 252, 1, 255, 250, 24, 0, 255, 240]);
        assert_eq!(e.poll_transmit(), None);
        assert_eq!(send(&mut e, at(0), "*IDN?"), "New_Focus 8742 v2.2 08/01/13 SN10001\r\n");
        e.handle_input(at(0), b"1TP");
        e.handle_closed(0);
        assert_eq!(e.poll_transmit(), Some(TELNET_GREETING.to_vec()));
        assert_eq!(send(&mut e, at(0), "?"), "", "the half line died with its connection");
        assert_eq!(error(&mut e), "6, COMMAND DOES NOT EXIST\r\n");
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn identification_and_power_on_state() {
        let mut e = usb(2);
        assert_eq!(e.poll_transmit(), None, "no Telnet over USB");
        assert_eq!(send(&mut e, at(0), "*IDN?"), "New_Focus 8742 v2.2 08/01/13 SN10001\r\n");
        assert_eq!(send(&mut e, at(0), "VE?"), "8742 Version 2.2 08/01/13\r\n");
        assert_eq!(send(&mut e, at(0), "TB?"), "0, NO ERROR DETECTED\r\n");
        assert_eq!(send(&mut e, at(0), "TE?"), "0\r\n");
        for (line, reply) in [
            ("1TP?", "0"),
            ("1MD?", "1"),
            ("1VA?", "2000"),
            ("1AC?", "100000"),
            ("2QM?", "3"),
            ("3QM?", "0"),
            ("1DH?", "0"),
            ("1PA?", "0"),
            ("SA?", "1"),
            ("SC?", "2"),
            ("SD?", "1"),
            ("ZZ?", "0"),
            ("IPMODE?", "1"),
            ("HOSTNAME?", "8742-10001"),
            ("IPADDR?", "192.168.0.254"),
            ("GATEWAY?", "192.168.0.1"),
            ("NETMASK?", "255.255.255.0"),
            ("MACADDR?", "5827809, 8087"),
        ] {
            assert_eq!(send(&mut e, at(0), line), format!("{reply}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "newfocus_8742");
    }

    #[test]
    fn commands_are_silent_and_settings_read_back() {
        let mut e = usb(4);
        for line in ["1VA1500", "1ac 5000", "2QM2", "ZZ11", "SC0", "SM", "HOSTNAME lab-pico", "IPMODE0"] {
            assert_eq!(send(&mut e, at(0), line), "", "{line}");
        }
        assert_eq!(send(&mut e, at(0), "1VA?; 1AC?"), "1500; 5000\r\n");
        assert_eq!(send(&mut e, at(0), "2QM?;ZZ?;HOSTNAME?;IPMODE?"), "2; 11; lab-pico; 0\r\n");
        assert_eq!(send(&mut e, at(0), "2VA1800"), "", "a 'Tiny' runs 1750 steps/s at most");
        assert_eq!(error(&mut e), "7, PARAMETER OUT OF RANGE\r\n");
        // Saved, changed, recalled; factory; a reset reloads the saved ones.
        send(&mut e, at(0), "1VA100");
        send(&mut e, at(0), "*RCL1");
        assert_eq!(send(&mut e, at(0), "1VA?"), "1500\r\n");
        send(&mut e, at(0), "*RCL 0");
        assert_eq!(send(&mut e, at(0), "1VA?;2QM?"), "2000; 3\r\n");
        send(&mut e, at(0), "*RST");
        assert_eq!(send(&mut e, at(0), "1VA?;1AC?"), "1500; 5000\r\n");
        send(&mut e, at(0), "XX");
        send(&mut e, at(0), "RS");
        assert_eq!(send(&mut e, at(0), "1VA?;1AC?"), "2000; 100000\r\n");
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn a_move_is_busy_then_done_at_its_target() {
        let mut e = usb(1);
        send(&mut e, at(0), "1VA1000");
        send(&mut e, at(0), "1AC200000");
        assert_eq!(send(&mut e, at(0), "1PA2000"), "");
        assert_eq!(send(&mut e, at(1000), "1MD?"), "0\r\n");
        let p: i64 = send(&mut e, at(1000), "1TP?").trim().parse().unwrap();
        assert!((995..=1001).contains(&p), "{p}");
        assert_eq!(send(&mut e, at(1000), "1PR5"), "", "refused while moving");
        assert_eq!(send(&mut e, at(1000), "1DH"), "");
        assert_eq!(send(&mut e, at(1000), "TE?"), "114\r\n");
        assert_eq!(error(&mut e), "114, MOTION IN PROGRESS\r\n");
        assert_eq!(send(&mut e, at(1000), "1PA?"), "2000\r\n");
        assert_eq!(send(&mut e, at(2100), "1MD?;1TP?"), "1; 2000\r\n");
        assert_eq!(send(&mut e, at(2100), "1PR-500"), "");
        assert_eq!(send(&mut e, at(2100), "1PR?"), "1500\r\n", "the target");
        assert_eq!(send(&mut e, at(3000), "1TP?"), "1500\r\n");
        // The EPICS driver's spacing and decimals.
        assert_eq!(send(&mut e, at(3000), "1 VA 2000.000000"), "");
        assert_eq!(send(&mut e, at(3000), "1 PA -499.600000"), "");
        assert_eq!(send(&mut e, at(5000), "1 TP?"), "-500\r\n");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_jog_runs_until_stopped_or_aborted() {
        let mut e = usb(2);
        send(&mut e, at(0), "2VA1000");
        send(&mut e, at(0), "2AC1000");
        assert_eq!(send(&mut e, at(0), "2MV-"), "");
        assert_eq!(send(&mut e, at(0), "2MV+"), "", "no turning on the fly");
        assert_eq!(error(&mut e), "214, MOTION IN PROGRESS\r\n");
        assert_eq!(send(&mut e, at(5000), "2MD?"), "0\r\n");
        let p: i64 = send(&mut e, at(5000), "2TP?").trim().parse().unwrap();
        assert!(p < -4000, "{p}");
        assert_eq!(send(&mut e, at(5000), "2ST"), "");
        assert_eq!(send(&mut e, at(5500), "2MD?"), "0\r\n", "decelerating at AC");
        assert_eq!(send(&mut e, at(6100), "2MD?"), "1\r\n");
        let stopped: i64 = send(&mut e, at(6100), "2TP?").trim().parse().unwrap();
        assert!((p - 600..=p - 400).contains(&stopped), "{p} {stopped}");
        send(&mut e, at(6100), "1MV+");
        send(&mut e, at(6100), "2MV+");
        assert_eq!(send(&mut e, at(6200), "AB"), "");
        assert_eq!(send(&mut e, at(6200), "1MD?;2MD?"), "1; 1\r\n", "every axis, at once");
        send(&mut e, at(6200), "1MV+");
        send(&mut e, at(6300), "ST");
        assert_eq!(send(&mut e, at(9000), "1MD?"), "1\r\n", "ST without an axis stops them all");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn a_carriage_at_its_mechanical_end_stops_without_error() {
        let mut e = usb(1);
        send(&mut e, at(0), "1AC200000");
        send(&mut e, at(0), "1MV+");
        assert_eq!(send(&mut e, at(101_000), "1MD?;1TP?"), "1; 200000\r\n");
        assert_eq!(error(&mut e), "0, NO ERROR DETECTED\r\n");
        assert_eq!(send(&mut e, at(101_000), "1PR-1000"), "", "away from it");
        assert_eq!(send(&mut e, at(103_000), "1TP?"), "199000\r\n");
    }

    #[test]
    fn home_is_defined_not_searched() {
        let mut e = usb(3);
        send(&mut e, at(0), "3PA700");
        assert_eq!(send(&mut e, at(2000), "3TP?"), "700\r\n");
        assert_eq!(send(&mut e, at(2000), "3DH"), "");
        assert_eq!(send(&mut e, at(2000), "3TP?;3DH?;3PA?"), "0; 0; 0\r\n");
        assert_eq!(send(&mut e, at(2000), "3DH-250"), "");
        assert_eq!(send(&mut e, at(2000), "3TP?;3DH?"), "-250\r\n".replace("\r\n", "; -250\r\n"));
        assert_eq!(send(&mut e, at(2000), "3PA0"), "");
        assert_eq!(send(&mut e, at(3000), "3TP?"), "0\r\n");
        assert!((e.axis(3).unwrap().physical_position() - 950.0).abs() < 1e-9);
        // No home search on an open-loop picomotor: the EPICS driver's MT/MZ and ESP's OR.
        for line in ["3 MT +", "3 MZ +", "3OR"] {
            assert_eq!(send(&mut e, at(3000), line), "", "{line}");
            assert_eq!(error(&mut e), "6, COMMAND DOES NOT EXIST\r\n");
        }
        send(&mut e, at(3000), "RS");
        assert_eq!(send(&mut e, at(3000), "3TP?;3DH?"), "0; 0\r\n", "a reset sets home to 0");
        assert_eq!(e.malformed(), 3);
    }

    #[test]
    fn errors_queue_in_order_and_raise_error_disconnects_a_motor() {
        let mut e = usb(2);
        send(&mut e, at(0), "2MV+");
        assert!(e.raise_error(2));
        assert_eq!(send(&mut e, at(100), "2MD?"), "1\r\n", "stopped at once");
        assert_eq!(send(&mut e, at(100), "4PA10"), "", "no motor on axis 4");
        send(&mut e, at(100), "MC");
        assert_eq!(send(&mut e, at(100), "TE?;TB?"), "208; 408, MOTOR NOT CONNECTED\r\n");
        assert_eq!(error(&mut e), "0, NO ERROR DETECTED\r\n", "each error is read once");
        for _ in 0..12 {
            send(&mut e, at(100), "9TP?");
        }
        send(&mut e, at(100), "1VA0");
        let codes: Vec<String> = (0..11).map(|_| send(&mut e, at(100), "TE?")).collect();
        assert_eq!(codes[..9], vec!["9\r\n".to_string(); 9]);
        assert_eq!(codes[9..], ["7\r\n".to_string(), "0\r\n".to_string()], "ten deep, the oldest dropped");
        assert!(!e.raise_error(0) && !e.raise_error(3) && !e.raise_error(5));
        assert!(e.axis(2).is_some() && e.axis(3).is_none());
        assert_eq!(e.malformed(), 13);
    }

    #[test]
    fn motion_check_refused_while_moving() {
        let mut e = usb(4);
        send(&mut e, at(0), "1QM0");
        send(&mut e, at(0), "3MV+");
        send(&mut e, at(0), "MC");
        assert_eq!(error(&mut e), "314, MOTION IN PROGRESS\r\n");
        send(&mut e, at(0), "AB");
        send(&mut e, at(0), "MC");
        assert_eq!(send(&mut e, at(0), "1QM?"), "3\r\n");
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn unknown_and_malformed_commands_queue_their_errors() {
        let mut e = usb(1);
        for (line, code) in [
            ("1XY?", 6),
            ("FOO", 6),
            ("1TP5", 6),
            ("AB?", 6),
            ("1MV?", 6),
            ("1PAabc", 7),
            ("1PA3000000000", 7),
            ("1MV", 7),
            ("1MVx", 7),
            ("1AC0", 7),
            ("1AC200001", 7),
            ("1QM4", 7),
            ("SA32", 7),
            ("ZZ2", 7),
            ("*RCL", 7),
            ("TP?", 9),
            ("0MD?", 9),
            ("5PA1", 9),
            ("99999999999999999999TP?", 9),
            ("x>1TP?", 6),
        ] {
            assert_eq!(send(&mut e, at(0), line), "", "{line}");
            assert_eq!(send(&mut e, at(0), "TE?"), format!("{code}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), 20);
    }

    #[test]
    fn the_controller_prefix_addresses_this_controller_only() {
        let mut e = usb(4);
        assert_eq!(send(&mut e, at(0), "1>3 TP?"), "1>0\r\n");
        assert_eq!(send(&mut e, at(0), "1>1MD?;1>VE?"), "1>1; 1>8742 Version 2.2 08/01/13\r\n");
        assert_eq!(send(&mut e, at(0), "2>1TP?"), "", "no controller 2 on the line");
        send(&mut e, at(0), "SA2");
        assert_eq!(send(&mut e, at(0), "2>SA?;SC?"), "2>2; 4\r\n");
        assert_eq!(e.malformed(), 1);
    }

    #[test]
    fn lines_come_whole_from_any_pieces_and_any_line_end() {
        let mut e = usb(1);
        e.handle_input(at(0), b"1T");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at(0), b"P?\r\n1md");
        e.handle_input(at(0), b"?\n");
        e.handle_input(at(0), b"VE?\n\r  \r\n");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"0\r\n".to_vec(), b"1\r\n".to_vec(), b"8742 Version 2.2 08/01/13\r\n".to_vec()]);
        assert_eq!(e.malformed(), 0);
        e.handle_input(at(0), b"1T\xffP?\r\x00\x01\r");
        assert_eq!(e.poll_transmit(), None);
        assert_eq!(e.malformed(), 2, "garbage bytes are no command");
        assert_eq!(send(&mut e, at(0), "TE?;TE?"), "6; 6\r\n");
        e.handle_input(at(0), &[b'1'; 257]);
        assert_eq!(e.malformed(), 3, "an overflowing input buffer counts");
        assert_eq!(send(&mut e, at(0), "1TP?"), "0\r\n");
    }

    #[test]
    fn channels_are_one_to_four() {
        assert_eq!(usb(0).channels.iter().filter(|c| c.sim.is_some()).count(), 1);
        assert_eq!(usb(9).channels.iter().filter(|c| c.sim.is_some()).count(), 4);
        let mut e = usb(4);
        assert!(e.axis(0).is_none() && e.axis(4).is_some() && e.axis(5).is_none());
    }
}
