//! The piezosystem jena NV40/3 CLE: a three-channel piezo amplifier with a closed-loop
//! (strain-gauge / capacitive sensor) option, on RS-232 at 19 200 baud, 8N1, software
//! handshake. One ASCII command a line, ended by CR: `<command>[,<channel>][,<value>…]`
//! (`set,0,50.000`); a query is answered with the command's name, the channel and the value
//! (`rk,0,50.000`), every answer framed by XOFF (0x13) before it and XON (0x11) after it.
//!
//! This is the NV40/3 CLE itself, not the d-Drive: the vendor's own client libraries for it
//! were found (below), so the d-Drive fallback was not needed.
//!
//! # Witnesses
//!
//! The NV40/3 CLE operating manual itself could not be found in any searchable copy. What
//! stands in for it, most authoritative first:
//!
//! 1. piezosystem jena's own Python library `psj-lib` (github.com/piezosystemjena/psj-lib,
//!    commit 4b74f12, 11 March 2026): its NV-family documentation (`doc/nv_series.rst`) and the
//!    bytes its NV40/3CLE classes send and expect. It gave: 19 200 baud; commands end with CR;
//!    answers are read up to XON, XON and XOFF stripped; identification is an empty line
//!    answered with text containing `NV403CLE>`; three channels 0…2; the command names `set`
//!    (setpoint: V in open loop, µm in closed loop; no read-back), `rk` (actual value), `cloop`
//!    (closed loop on/off, readable), `setk` (modulation source: 0 knob/analog, 1 serial; no
//!    read-back), `monwpa` (monitor output 0 voltage, 1 position, 2 mode dependent), `unitol`,
//!    `unitcl`, `dspvmin`/`dspvmax` (global), `dspclmin`/`dspclmax`, `light` (0…255),
//!    `encmode` `enctime` `enclim` `encexp` `encstol` `encstcl`, `setall` (all three setpoints
//!    at once, ignored unless all three channels have an actuator and serial control) and
//!    `measure` (all positions, answered `aw,p0,p1,p2`); a reply is split at commas, its first
//!    field the command, then the channel; the status is the global `ERROR`, answered with one
//!    hexadecimal fault word per channel: 0x0001 actuator not plugged, 0x0002 actuator short,
//!    0x0010 EEPROM error, 0x1000 underload, 0x2000 overload (setpoint unreachable even at full
//!    voltage), 0x4000 invalid actuator, 0x8000 over-temperature; command errors are answered
//!    `ErrorCode,<n>`: 11 unknown command, 15 and 16 unknown channel, 17 parameter missing,
//!    18 admissible range exceeded, 25 actuator not connected.
//! 2. piezosystem jena's Micro-Manager adapter `Piezosystem_NV40_3` (Chris Belter,
//!    piezosystem jena, 2013): 19 200 8N1 software handshake; CR ends commands and answers;
//!    the identification is read up to `>\r`; `ver` is answered with three lines (version,
//!    date, serial number, each `name,value`); `stat,<ch>` is answered `STATUS,<ch>,<decimal>`
//!    whose bits are 0x0001 actuator name, 0x0002 actuator serial number, 0x0004 coordinate,
//!    0x0008 closed loop, 0x0010 measuring system present, 0x0060 the monitor output source,
//!    0x0080 remote (serial) control, 0x8000 actuator ready; `cloop,<ch>` is answered
//!    `cloop,<ch>,<0|1>`; settings such as `set` are "normally" not answered; values are sent
//!    with three decimals; the open-loop range is −20…130 V and positions are converted
//!    linearly between it and the closed-loop range; `acdescr`, `accoor`, `fenable`, `fready`.
//! 3. The NV40/1 CLE manual (German, manualslib.de, §9.10): ASCII characters below 0x20 other
//!    than CR are ignored; an unknown command is answered with an error message; remote
//!    control must be switched on before a setpoint is taken.
//! 4. Only for the bytes clients send: klauer/nv40 (an EPICS driver for this NV40/3, 19 200
//!    8N1 xon/xoff, `set,%d,%.3f`, `rk,%d` read as `rk,n,xx.xxx`, `measure` read as
//!    `aw,0.000,0.000,0.000`, no stop, no jog, no home) and epics-motor/motorPiJena (for the
//!    d-Drive EDS2: answers framed `\x13…\r\n\x11`, a bare XOFF XON after a setting).
//!
//! # Readings taken where the witnesses are silent
//!
//! - **Framing.** Every line gets exactly one answer: XOFF, the answer's lines each ended by
//!   CR LF, XON. A setting that takes effect (and one ignored without serial control) is
//!   answered by XOFF XON alone. LF and other control bytes from the host are dropped (as the
//!   NV40/1 does), so `\r\n` endings work too. 80 bytes without a CR overflow the buffer.
//! - **Identification.** An empty line is answered `NV403CLE>`; `ver` with `ver,1.00`,
//!   `sdate,01.01.2013` and `serno,000000` (made-up values). Command names are taken in any
//!   case; answers use the names in lower case (`STATUS`, `ERROR`, `ErrorCode` as witnessed).
//!   There is no `s` help list, no `i0`/`i1` (the NV40/1's), no `cl` (the d-Drive's) and no
//!   `chloop`/`ERR?` (sent by klauer's driver, perhaps for an older firmware): all unknown.
//! - **Errors.** Unknown command: 11. Channel missing or not a number: 15; 3 or more: 16; a
//!   channel with no actuator (the `channels` given to `new` are the plugged ones): 25. A
//!   value missing, not a number, or one too many: 17. A value out of range: 18. Every
//!   `ErrorCode` answer is counted as malformed. The `ERROR` words are four hexadecimal
//!   digits; an unplugged channel shows 0x0001.
//! - **Write-only commands** (`set`, `setk`, `monwpa`) read without a value answer 17.
//!   `cloop`, `fenable` and the global settings read back as `name[,ch],value`.
//! - **Status.** A plugged channel has bits 0x8000, 0x0010 and 0x0007; then 0x0008 in closed
//!   loop, the monitor source × 0x0020, 0x0080 under serial control. No bit shows motion: a
//!   client compares successive `rk` values.
//! - **Units and steps.** One step of the simulated axis is 1 nm. Closed loop: `set`/`rk` in
//!   µm with three decimals, range `dspclmin` 0.000 … `dspclmax` 100.000 µm (unit `um`, ASCII).
//!   Open loop: `set`/`rk` in V, range `dspvmin` −20.000 … `dspvmax` 130.000 V (unit `V`),
//!   mapped linearly onto 0…100 µm as the vendor's adapter does (so at 0 nm `rk` reads
//!   −20.000 V). Switching the loop leaves the stage where it is.
//! - **Motion.** A piezo has no home, limit or reference switches, no jog and no stop
//!   command: a setpoint is reached at a fixed slew of 10 µm/ms (a full 100 µm stroke settles
//!   in 10 ms, a 1 µm step in 0.1 ms), without ramps. To stop, a client sets the setpoint to
//!   the position it reads. Any limit switches in the simulated mechanics are never reported.
//! - **Power-on**: open loop, knob control (`setk` 0), monitor source 0, soft start off,
//!   `light` 128, `encmode` 0, `enctime` 10, `enclim` 1000, `encexp` 3, `encstol` and
//!   `encstcl` 1.000, `fready` 0. Actuators are named `PSH100CAP`, their coordinate is the
//!   channel number (X, Y, Z).
//! - **`raise_error`** sets the overload flag (0x2000) of the channel's `ERROR` word and
//!   freezes the stage where it is; the next setpoint accepted on that channel clears it.

use crate::emulator::axes;
use crate::{Emulator, Lines};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};

/// Actuator sockets of an NV40/3.
const SOCKETS: usize = 3;
/// CR ends a command.
const CR: &[u8] = b"\r";
/// Bytes without a CR the input buffer holds.
const INPUT_BUFFER: usize = 80;
/// Start and end of every answer.
const XOFF: u8 = 0x13;
const XON: u8 = 0x11;
const PROMPT: &str = "NV403CLE>";
/// Slew, steps (nm) per second: 10 µm/ms.
const SLEW: f64 = 10_000_000.0;
/// Closed-loop range, µm, and open-loop range, V.
const STROKE_UM: f64 = 100.0;
const VOLT_MIN: f64 = -20.0;
const VOLT_MAX: f64 = 130.0;
/// Steps per µm.
const STEPS_PER_UM: f64 = 1000.0;

/// `ERROR` word flags.
const FAULT_NOT_PLUGGED: u16 = 0x0001;
const FAULT_OVERLOAD: u16 = 0x2000;
/// `stat` word bits.
const STAT_IDENTIFIED: u16 = 0x0007;
const STAT_CLOSED_LOOP: u16 = 0x0008;
const STAT_SENSOR: u16 = 0x0010;
const STAT_MONITOR_SHIFT: u16 = 5;
const STAT_REMOTE: u16 = 0x0080;
const STAT_READY: u16 = 0x8000;

/// `ErrorCode` numbers.
const E_UNKNOWN: u8 = 11;
const E_CHANNEL: u8 = 15;
const E_NO_SUCH_CHANNEL: u8 = 16;
const E_PARAMETER: u8 = 17;
const E_RANGE: u8 = 18;
const E_NO_ACTUATOR: u8 = 25;

/// The device-wide settings: name, power-on value, lowest, highest, whole number.
const GLOBALS: [(&str, f64, f64, f64, bool); 8] = [
    ("light", 128.0, 0.0, 255.0, true),
    ("encmode", 0.0, 0.0, 2.0, true),
    ("enctime", 10.0, 0.0, 255.0, true),
    ("enclim", 1000.0, 1.0, 65535.0, true),
    ("encexp", 3.0, 1.0, 10.0, true),
    ("encstol", 1.0, 0.001, 150.0, false),
    ("encstcl", 1.0, 0.001, 100.0, false),
    ("fready", 0.0, 0.0, 1.0, true),
];

/// One plugged actuator channel.
#[derive(Debug)]
struct Channel {
    sim: SimAxis,
    closed_loop: bool,
    /// `setk` 1: setpoints come from the serial line.
    remote: bool,
    /// `monwpa`, 0…2.
    monitor: u16,
    /// `fenable`.
    soft_start: bool,
    /// The `ERROR` word's flags.
    faults: u16,
}

impl Channel {
    fn new(sim: SimAxis) -> Self {
        Self { sim, closed_loop: false, remote: false, monitor: 0, soft_start: false, faults: 0 }
    }

    /// Where the stage is, µm.
    fn microns(&self) -> f64 {
        self.sim.status().position / STEPS_PER_UM
    }

    /// The actual value `rk` gives: µm in closed loop, the piezo voltage in open loop.
    fn actual(&self) -> f64 {
        if self.closed_loop {
            self.microns()
        } else {
            VOLT_MIN + (VOLT_MAX - VOLT_MIN) * self.microns() / STROKE_UM
        }
    }

    /// The setpoint's admissible range in the current mode.
    fn range(&self) -> (f64, f64) {
        if self.closed_loop {
            (0.0, STROKE_UM)
        } else {
            (VOLT_MIN, VOLT_MAX)
        }
    }

    /// Steps for setpoint `value` (checked against `range` already).
    fn target(&self, value: f64) -> f64 {
        let microns = if self.closed_loop { value } else { (value - VOLT_MIN) / (VOLT_MAX - VOLT_MIN) * STROKE_UM };
        (microns * STEPS_PER_UM).round()
    }

    fn go(&mut self, value: f64) {
        self.faults &= !FAULT_OVERLOAD;
        let target = self.target(value);
        self.sim.move_to(target, false, 0.0, SLEW, 0.0);
    }

    fn status(&self) -> u16 {
        let mut word = STAT_READY | STAT_SENSOR | STAT_IDENTIFIED | (self.monitor << STAT_MONITOR_SHIFT);
        if self.closed_loop {
            word |= STAT_CLOSED_LOOP;
        }
        if self.remote {
            word |= STAT_REMOTE;
        }
        word
    }
}

/// The answer to one line: its text lines, or an `ErrorCode`.
type Answer = Result<Vec<String>, u8>;

/// An NV40/3 CLE with actuators plugged into its first `channels` sockets (0, 1, 2).
#[derive(Debug)]
pub struct Nv40Emulator {
    channels: Vec<Channel>,
    globals: [f64; GLOBALS.len()],
    lines: Lines,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Nv40Emulator {
    /// An NV40/3 CLE with `channels` actuators (one at least, three at most) on channels
    /// 0 to `channels − 1`, numbered as the device numbers them; one step is 1 nm.
    pub fn new(channels: usize, mechanics: &SimConfig) -> Self {
        let channels = channels.clamp(1, SOCKETS);
        Self {
            channels: axes(channels, mechanics).into_iter().map(Channel::new).collect(),
            globals: GLOBALS.map(|(_, default, ..)| default),
            lines: Lines::new(CR, INPUT_BUFFER),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The answer to one line (ASCII, control bytes removed).
    fn answer(&mut self, line: &str) -> Answer {
        let mut fields = line.split(',').map(str::trim);
        let name = fields.next().unwrap_or_default().to_ascii_lowercase();
        let params: Vec<&str> = fields.collect();
        if let Some(index) = GLOBALS.iter().position(|g| g.0 == name) {
            return self.global(index, &params);
        }
        match name.as_str() {
            "" if params.is_empty() => Ok(vec![PROMPT.to_string()]),
            "ver" => none(&params)
                .map(|()| vec!["ver,1.00".to_string(), "sdate,01.01.2013".to_string(), "serno,000000".to_string()]),
            "measure" => none(&params).map(|()| {
                let values = (0..SOCKETS).map(|ch| number(self.channels.get(ch).map_or(0.0, Channel::actual)));
                vec![format!("aw,{}", values.collect::<Vec<_>>().join(","))]
            }),
            "error" => none(&params).map(|()| {
                let words = (0..SOCKETS)
                    .map(|ch| format!("{:04X}", self.channels.get(ch).map_or(FAULT_NOT_PLUGGED, |c| c.faults)));
                vec![format!("ERROR,{}", words.collect::<Vec<_>>().join(","))]
            }),
            "dspvmin" => none(&params).map(|()| vec![format!("dspvmin,{}", number(VOLT_MIN))]),
            "dspvmax" => none(&params).map(|()| vec![format!("dspvmax,{}", number(VOLT_MAX))]),
            "setall" => self.set_all(&params),
            "set" | "rk" | "cloop" | "setk" | "monwpa" | "stat" | "dspclmin" | "dspclmax" | "unitol" | "unitcl"
            | "fenable" | "acdescr" | "accoor" => {
                let (first, rest) = params.split_first().ok_or(E_CHANNEL)?;
                let channel: usize = first.parse().map_err(|_| E_CHANNEL)?;
                if channel >= SOCKETS {
                    return Err(E_NO_SUCH_CHANNEL);
                }
                let unit = self.channels.get_mut(channel).ok_or(E_NO_ACTUATOR)?;
                channel_command(unit, &name, channel, rest)
            }
            _ => Err(E_UNKNOWN),
        }
    }

    /// A device-wide setting read (`light`) or written (`light,200`).
    fn global(&mut self, index: usize, params: &[&str]) -> Answer {
        let (name, _, low, high, whole) = GLOBALS[index];
        match params {
            [] => {
                let value = self.globals[index];
                Ok(vec![if whole { format!("{name},{value:.0}") } else { format!("{name},{}", number(value)) }])
            }
            [text] => {
                let value = if whole { integer(text)? as f64 } else { real(text)? };
                if !(low..=high).contains(&value) {
                    return Err(E_RANGE);
                }
                self.globals[index] = value;
                Ok(Vec::new())
            }
            _ => Err(E_PARAMETER),
        }
    }

    /// `setall,v0,v1,v2`: ignored unless all three sockets hold actuators under serial control.
    fn set_all(&mut self, params: &[&str]) -> Answer {
        let [a, b, c] = params else { return Err(E_PARAMETER) };
        let values = [real(a)?, real(b)?, real(c)?];
        if self.channels.len() < SOCKETS || self.channels.iter().any(|c| !c.remote) {
            return Ok(Vec::new());
        }
        for (unit, value) in self.channels.iter().zip(values) {
            let (low, high) = unit.range();
            if !(low..=high).contains(&value) {
                return Err(E_RANGE);
            }
        }
        for (unit, value) in self.channels.iter_mut().zip(values) {
            unit.go(value);
        }
        Ok(Vec::new())
    }
}

/// Carry out channel command `name` on `unit` (channel `ch`) with the values after the channel.
fn channel_command(unit: &mut Channel, name: &str, ch: usize, rest: &[&str]) -> Answer {
    let reply = |value: String| Ok(vec![format!("{name},{ch},{value}")]);
    match (name, rest) {
        ("rk", []) => reply(number(unit.actual())),
        ("stat", []) => Ok(vec![format!("STATUS,{ch},{}", unit.status())]),
        ("cloop", []) => reply(u8::from(unit.closed_loop).to_string()),
        ("fenable", []) => reply(u8::from(unit.soft_start).to_string()),
        ("dspclmin", []) => reply(number(0.0)),
        ("dspclmax", []) => reply(number(STROKE_UM)),
        ("unitol", []) => reply("V".to_string()),
        ("unitcl", []) => reply("um".to_string()),
        ("acdescr", []) => reply("PSH100CAP".to_string()),
        ("accoor", []) => reply(ch.to_string()),
        ("set", [text]) => {
            let value = real(text)?;
            let (low, high) = unit.range();
            if !(low..=high).contains(&value) {
                return Err(E_RANGE);
            }
            // Without serial control the knob and analog input set the position; ignored.
            if unit.remote {
                unit.go(value);
            }
            Ok(Vec::new())
        }
        ("cloop" | "setk" | "fenable", [text]) => {
            let on = match integer(text)? {
                0 => false,
                1 => true,
                _ => return Err(E_RANGE),
            };
            match name {
                "cloop" => unit.closed_loop = on,
                "setk" => unit.remote = on,
                _ => unit.soft_start = on,
            }
            Ok(Vec::new())
        }
        ("monwpa", [text]) => {
            unit.monitor = u16::try_from(integer(text)?).ok().filter(|m| *m <= 2).ok_or(E_RANGE)?;
            Ok(Vec::new())
        }
        _ => Err(E_PARAMETER),
    }
}

/// No values may follow.
fn none(params: &[&str]) -> Result<(), u8> {
    if params.is_empty() {
        Ok(())
    } else {
        Err(E_PARAMETER)
    }
}

/// A decimal number, a sign and a point allowed (`50`, `-20.5`, `+.25`).
fn real(text: &str) -> Result<f64, u8> {
    let body = text.strip_prefix(['+', '-']).unwrap_or(text);
    let digits = body.bytes().filter(u8::is_ascii_digit).count();
    let points = body.bytes().filter(|b| *b == b'.').count();
    if digits == 0 || digits + points != body.len() || points > 1 || text.len() > 20 {
        return Err(E_PARAMETER);
    }
    text.strip_prefix('+').unwrap_or(text).parse().map_err(|_| E_PARAMETER)
}

/// A whole decimal number.
fn integer(text: &str) -> Result<i64, u8> {
    let body = text.strip_prefix(['+', '-']).unwrap_or(text);
    if body.is_empty() || !body.bytes().all(|b| b.is_ascii_digit()) || body.len() > 9 {
        return Err(E_PARAMETER);
    }
    text.strip_prefix('+').unwrap_or(text).parse().map_err(|_| E_PARAMETER)
}

/// Three decimals, never `-0.000`.
fn number(value: f64) -> String {
    let rounded = (value * 1000.0).round() / 1000.0 + 0.0;
    format!("{rounded:.3}")
}

/// XOFF, the lines each ended by CR LF, XON.
fn frame(lines: &[String]) -> Vec<u8> {
    let mut bytes = vec![XOFF];
    for line in lines {
        bytes.extend_from_slice(line.as_bytes());
        bytes.extend_from_slice(b"\r\n");
    }
    bytes.push(XON);
    bytes
}

impl Emulator for Nv40Emulator {
    fn name(&self) -> &'static str {
        "piezojena_nv40"
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for unit in &mut self.channels {
            unit.sim.advance(now);
        }
        // Control characters other than CR (LF, XON, XOFF, …) are ignored, as on the NV40/1.
        let kept: Vec<u8> = bytes.iter().copied().filter(|&b| b == b'\r' || b >= 0x20).collect();
        for line in self.lines.push(&kept) {
            let text = std::str::from_utf8(&line).ok().filter(|t| t.is_ascii());
            let answer = text.map_or(Err(E_UNKNOWN), |t| self.answer(t));
            let lines = answer.unwrap_or_else(|code| {
                self.malformed += 1;
                vec![format!("ErrorCode,{code}")]
            });
            self.output.push_back(frame(&lines));
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed + self.lines.overflowed()
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.channels.get_mut(channel).map(|unit| &mut unit.sim)
    }

    fn raise_error(&mut self, channel: usize) -> bool {
        let Some(unit) = self.channels.get_mut(channel) else { return false };
        unit.sim.stop(0.0);
        unit.faults |= FAULT_OVERLOAD;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage;
    use std::time::Duration;

    fn at_us(us: u64) -> Instant {
        Instant::ZERO + Duration::from_micros(us)
    }

    /// The answer to `line`, XOFF and XON checked and removed.
    fn exchange(e: &mut Nv40Emulator, now: Instant, line: &str) -> String {
        e.handle_input(now, format!("{line}\r").as_bytes());
        let reply = e.poll_transmit().expect("every line is answered");
        assert!(e.poll_transmit().is_none(), "one answer a line");
        assert_eq!((reply.first(), reply.last()), (Some(&XOFF), Some(&XON)), "{reply:?}");
        String::from_utf8(reply[1..reply.len() - 1].to_vec()).expect("ASCII")
    }

    fn serial_closed_loop(e: &mut Nv40Emulator, ch: usize) {
        assert_eq!(exchange(e, at_us(0), &format!("setk,{ch},1")), "");
        assert_eq!(exchange(e, at_us(0), &format!("cloop,{ch},1")), "");
    }

    #[test]
    fn identification_and_power_on_state() {
        let mut e = Nv40Emulator::new(3, &stage());
        e.handle_input(at_us(0), b"\r");
        assert_eq!(e.poll_transmit().unwrap(), b"\x13NV403CLE>\r\n\x11");
        assert_eq!(exchange(&mut e, at_us(0), "ver"), "ver,1.00\r\nsdate,01.01.2013\r\nserno,000000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "stat,0"), "STATUS,0,32791\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "cloop,1"), "cloop,1,0\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "rk,2"), "rk,2,-20.000\r\n", "open loop: volts");
        assert_eq!(exchange(&mut e, at_us(0), "measure"), "aw,-20.000,-20.000,-20.000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "ERROR"), "ERROR,0000,0000,0000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "dspclmin,0"), "dspclmin,0,0.000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "dspclmax,0"), "dspclmax,0,100.000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "dspvmin"), "dspvmin,-20.000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "dspvmax"), "dspvmax,130.000\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "unitcl,0"), "unitcl,0,um\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "unitol,0"), "unitol,0,V\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "acdescr,1"), "acdescr,1,PSH100CAP\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "accoor,2"), "accoor,2,2\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "light"), "light,128\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "light,200"), "");
        assert_eq!(exchange(&mut e, at_us(0), "LIGHT"), "light,200\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "encstcl,0.5"), "");
        assert_eq!(exchange(&mut e, at_us(0), "encstcl"), "encstcl,0.500\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "fenable,0,1"), "");
        assert_eq!(exchange(&mut e, at_us(0), "fenable,0"), "fenable,0,1\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "monwpa,0,2"), "");
        assert_eq!(exchange(&mut e, at_us(0), "stat,0"), "STATUS,0,32855\r\n", "monitor source 2 in bits 5-6");
        assert_eq!(e.malformed(), 0);
        assert_eq!(e.name(), "piezojena_nv40");
    }

    #[test]
    fn a_closed_loop_setpoint_is_reached_at_the_slew() {
        let mut e = Nv40Emulator::new(3, &stage());
        serial_closed_loop(&mut e, 0);
        assert_eq!(exchange(&mut e, at_us(0), "stat,0"), "STATUS,0,32927\r\n", "closed loop and remote");
        assert_eq!(exchange(&mut e, at_us(0), "cloop,0"), "cloop,0,1\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "rk,0"), "rk,0,0.000\r\n");
        e.handle_input(at_us(0), b"set,0,50.000\r");
        assert_eq!(e.poll_transmit().unwrap(), b"\x13\x11", "a setting: the frame alone");
        assert_eq!(exchange(&mut e, at_us(2000), "rk,0"), "rk,0,20.000\r\n", "10 um/ms");
        assert!(e.axis(0).unwrap().is_moving());
        assert_eq!(exchange(&mut e, at_us(5000), "rk,0"), "rk,0,50.000\r\n");
        assert!(!e.axis(0).unwrap().is_moving());
        assert_eq!(e.axis(0).unwrap().physical_position(), 50_000.0, "1 step = 1 nm");
        assert_eq!(exchange(&mut e, at_us(5000), "set,0,49.9995"), "");
        assert_eq!(exchange(&mut e, at_us(6000), "rk,0"), "rk,0,50.000\r\n", "whole nanometres");
        assert_eq!(e.axis(0).unwrap().physical_position(), 50_000.0);
        assert_eq!(exchange(&mut e, at_us(6000), "measure"), "aw,50.000,-20.000,-20.000\r\n");
    }

    #[test]
    fn a_stop_is_a_setpoint_at_the_position_read() {
        let mut e = Nv40Emulator::new(1, &stage());
        serial_closed_loop(&mut e, 0);
        exchange(&mut e, at_us(0), "set,0,100");
        let read = exchange(&mut e, at_us(3000), "rk,0");
        assert_eq!(read, "rk,0,30.000\r\n");
        assert_eq!(exchange(&mut e, at_us(3000), "set,0,30.000"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "rk,0"), "rk,0,30.000\r\n");
        for unknown in ["stop", "s", "home", "i1", "cl,0,1", "chloop,0,1", "ERR?"] {
            assert_eq!(exchange(&mut e, at_us(20_000), unknown), "ErrorCode,11\r\n", "{unknown}");
        }
    }

    #[test]
    fn without_serial_control_setpoints_are_ignored() {
        let mut e = Nv40Emulator::new(3, &stage());
        assert_eq!(exchange(&mut e, at_us(0), "set,1,55"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "rk,1"), "rk,1,-20.000\r\n", "still at 0 nm");
        assert_eq!(exchange(&mut e, at_us(20_000), "setk,1,1"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "set,1,55"), "", "open loop: volts");
        assert_eq!(exchange(&mut e, at_us(40_000), "rk,1"), "rk,1,55.000\r\n");
        assert_eq!(e.axis(1).unwrap().physical_position(), 50_000.0, "55 V is mid-stroke");
        assert_eq!(exchange(&mut e, at_us(40_000), "cloop,1,1"), "");
        assert_eq!(exchange(&mut e, at_us(40_000), "rk,1"), "rk,1,50.000\r\n", "the stage stays put");
        assert_eq!(exchange(&mut e, at_us(40_000), "setk,1,0"), "");
        assert_eq!(exchange(&mut e, at_us(40_000), "stat,1"), "STATUS,1,32799\r\n");
    }

    #[test]
    fn setall_moves_all_three_only_under_serial_control() {
        let mut e = Nv40Emulator::new(3, &stage());
        serial_closed_loop(&mut e, 0);
        serial_closed_loop(&mut e, 1);
        assert_eq!(exchange(&mut e, at_us(0), "setall,10,20,30"), "", "channel 2 on the knob");
        assert_eq!(exchange(&mut e, at_us(20_000), "measure"), "aw,0.000,0.000,-20.000\r\n");
        assert_eq!(exchange(&mut e, at_us(20_000), "setk,2,1"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "setall,10,20,130"), "", "channel 2 in open loop");
        assert_eq!(exchange(&mut e, at_us(40_000), "measure"), "aw,10.000,20.000,130.000\r\n");
        assert_eq!(exchange(&mut e, at_us(40_000), "setall,10,120,30"), "ErrorCode,18\r\n");
        assert_eq!(exchange(&mut e, at_us(40_000), "setall,10,20"), "ErrorCode,17\r\n");
        assert_eq!(exchange(&mut e, at_us(60_000), "measure"), "aw,10.000,20.000,130.000\r\n");
        let mut two = Nv40Emulator::new(2, &stage());
        assert_eq!(exchange(&mut two, at_us(0), "setall,1,2,3"), "", "an empty socket: ignored");
        assert_eq!(exchange(&mut two, at_us(0), "measure"), "aw,-20.000,-20.000,0.000\r\n");
    }

    #[test]
    fn the_range_is_the_only_limit() {
        let mut e = Nv40Emulator::new(1, &stage());
        serial_closed_loop(&mut e, 0);
        assert_eq!(exchange(&mut e, at_us(0), "set,0,100.001"), "ErrorCode,18\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "set,0,-0.5"), "ErrorCode,18\r\n");
        assert_eq!(exchange(&mut e, at_us(0), "set,0,100"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "rk,0"), "rk,0,100.000\r\n");
        assert_eq!(exchange(&mut e, at_us(20_000), "cloop,0,0"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "set,0,131"), "ErrorCode,18\r\n");
        assert_eq!(exchange(&mut e, at_us(20_000), "set,0,-20"), "");
        assert_eq!(exchange(&mut e, at_us(40_000), "rk,0"), "rk,0,-20.000\r\n");
        let state = e.axis(0).unwrap().state();
        assert!(!state.high_limit && !state.low_limit && state.position == 0.0, "no switch is reached");
        assert_eq!(e.malformed(), 3);
    }

    #[test]
    fn raised_errors_show_in_the_error_words() {
        let mut e = Nv40Emulator::new(2, &stage());
        serial_closed_loop(&mut e, 1);
        exchange(&mut e, at_us(0), "set,1,80");
        e.handle_input(at_us(4000), b"");
        assert!(e.raise_error(1));
        assert_eq!(exchange(&mut e, at_us(4000), "ERROR"), "ERROR,0000,2000,0001\r\n");
        assert_eq!(exchange(&mut e, at_us(20_000), "rk,1"), "rk,1,40.000\r\n", "frozen");
        assert_eq!(exchange(&mut e, at_us(20_000), "set,1,40"), "");
        assert_eq!(exchange(&mut e, at_us(20_000), "ERROR"), "ERROR,0000,0000,0001\r\n");
        assert!(!e.raise_error(2) && e.axis(2).is_none());
        assert_eq!(e.malformed(), 0);
    }

    #[test]
    fn command_errors_are_answered_and_counted() {
        let mut e = Nv40Emulator::new(2, &stage());
        let cases = [
            ("foo", 11),
            ("rk", 15),
            ("rk,x", 15),
            ("rk,3", 16),
            ("rk,2", 25),
            ("stat,2", 25),
            ("set,0", 17),
            ("setk,0", 17),
            ("set,0,abc", 17),
            ("set,0,1e3", 17),
            ("set,0,1,2", 17),
            ("rk,0,1", 17),
            ("ver,1", 17),
            ("cloop,0,2", 18),
            ("monwpa,0,3", 18),
            ("light,256", 18),
            ("enclim,0", 18),
            ("light,1.5", 17),
            (",0", 11),
        ];
        for (line, code) in cases {
            assert_eq!(exchange(&mut e, at_us(0), line), format!("ErrorCode,{code}\r\n"), "{line}");
        }
        assert_eq!(e.malformed(), cases.len());
        assert_eq!(Nv40Emulator::new(9, &stage()).channels.len(), 3);
        assert_eq!(Nv40Emulator::new(0, &stage()).channels.len(), 1);
    }

    #[test]
    fn lines_come_whole_from_pieces_and_garbage_is_refused() {
        let mut e = Nv40Emulator::new(1, &stage());
        e.handle_input(at_us(0), b"r");
        e.handle_input(at_us(0), b"k,");
        assert!(e.poll_transmit().is_none());
        e.handle_input(at_us(0), b"0\r\n\x11st");
        e.handle_input(at_us(0), b"at,0\r\n");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies, [b"\x13rk,0,-20.000\r\n\x11".to_vec(), b"\x13STATUS,0,32791\r\n\x11".to_vec()]);
        e.handle_input(at_us(0), b"\xff\xfe\r");
        assert_eq!(e.poll_transmit().unwrap(), b"\x13ErrorCode,11\r\n\x11");
        assert_eq!(e.malformed(), 1);
        e.handle_input(at_us(0), &[b'x'; 81]);
        assert!(e.poll_transmit().is_none());
        assert_eq!(e.malformed(), 2, "an overflowing buffer counts");
        assert_eq!(exchange(&mut e, at_us(0), " rk , 0 "), "rk,0,-20.000\r\n");
    }
}
