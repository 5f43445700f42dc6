//! An ACS MCB-4B: `#NN<letter>[argument]\r`, every line answered by one line. A command that
//! sets something is answered with its own echo; a query with `#NN<letter>=<value>`.

use super::{axes, Emulator};
use crate::acs::{acceleration_of_index, speed_of_index, JOG_STEPS, NAME, TERMINATOR};
use std::collections::VecDeque;
use zmotor_core::{Driver, Instant, SimAxis, SimConfig};
use zmotor_msgs::bits::msta;

/// An MCB-4B with `channels` axes (`#00` …).
pub(crate) struct Mcb4bEmulator {
    axes: Vec<SimAxis>,
    speed: Vec<u32>,
    ramp: Vec<u32>,
    power: Vec<bool>,
    input: Vec<u8>,
    output: VecDeque<Vec<u8>>,
    malformed: usize,
}

impl Mcb4bEmulator {
    /// A controller of `channels` axes on `mechanics`, drives powered.
    pub(crate) fn new(channels: usize, mechanics: &SimConfig) -> Self {
        Self {
            axes: axes(channels, mechanics),
            speed: vec![58; channels],
            ramp: vec![180; channels],
            power: vec![true; channels],
            input: Vec::new(),
            output: VecDeque::new(),
            malformed: 0,
        }
    }

    /// The answer to one line (without its terminator); None when the line is not a command
    /// of the protocol.
    fn answer(&mut self, line: &str) -> Option<String> {
        let rest = line.strip_prefix('#').filter(|rest| rest.len() >= 3 && rest.is_char_boundary(2))?;
        let (number, rest) = rest.split_at(2);
        let n = number.parse::<usize>().ok().filter(|n| *n < self.axes.len())?;
        let (letter, argument) = rest.split_at(rest.chars().next()?.len_utf8());
        let value = || argument.strip_prefix('=').unwrap_or(argument).parse::<i64>().ok();
        let (speed, accel) = (speed_of_index(self.speed[n]), acceleration_of_index(self.ramp[n]));
        let axis = &mut self.axes[n];
        let reply = |value: String| Some(format!("#{number}{letter}={value}"));
        match (letter, argument) {
            ("P", "") => return reply(format!("{:+}", axis.status().position.round() as i64)),
            ("X", "") => return reply(u8::from(axis.is_moving()).to_string()),
            ("E", "") => {
                let bits = axis.status().msta;
                let flag = |on: bool| if on { '1' } else { '0' };
                let (plus, minus) = (bits & msta::PLUS_LS != 0, bits & msta::MINUS_LS != 0);
                return reply(format!("{}{}{}", flag(plus), flag(minus), flag(axis.on_home_switch())));
            }
            ("W", "") => return reply(u8::from(self.power[n]).to_string()),
            ("V", _) if argument.starts_with('=') => self.speed[n] = value().filter(|v| (2..=255).contains(v))? as u32,
            ("R", _) if argument.starts_with('=') => self.ramp[n] = value().filter(|r| (1..=255).contains(r))? as u32,
            ("P", _) if argument.starts_with('=') => axis.set_position(value()? as f64),
            ("W", "=1" | "=0") => self.power[n] = argument == "=1",
            ("Q", "") => axis.stop(accel),
            ("G", _) if argument.starts_with(['+', '-']) => {
                let target = value()?;
                if self.power[n] {
                    axis.move_to(target as f64, false, 0.0, speed, accel);
                }
            }
            ("I", _) if argument.starts_with(['+', '-']) => {
                let distance = value()?;
                // A million steps is how the driver jogs: run at speed until stopped.
                match (self.power[n], distance.unsigned_abs() == u64::from(JOG_STEPS.unsigned_abs())) {
                    (false, _) => {}
                    (true, true) => axis.move_velocity(0.0, speed * distance.signum() as f64, accel),
                    (true, false) => axis.move_to(distance as f64, true, 0.0, speed, accel),
                }
            }
            ("H", "+" | "-") if self.power[n] => axis.home(argument == "+", 0.0, speed, accel),
            ("H", "+" | "-") => {}
            _ => return None,
        }
        Some(format!("#{number}{letter}{argument}"))
    }
}

impl Emulator for Mcb4bEmulator {
    fn name(&self) -> &'static str {
        NAME
    }

    fn handle_input(&mut self, now: Instant, bytes: &[u8]) {
        for axis in &mut self.axes {
            axis.advance(now);
        }
        self.input.extend_from_slice(bytes);
        while let Some(end) = self.input.iter().position(|b| *b == TERMINATOR[0]) {
            let line: Vec<u8> = self.input.drain(..=end).collect();
            let text = String::from_utf8_lossy(&line[..line.len() - 1]).trim().to_string();
            if text.is_empty() {
                continue;
            }
            let answer = self.answer(&text).unwrap_or_else(|| {
                self.malformed += 1;
                "?".to_string()
            });
            self.output.push_back(format!("{answer}\r").into_bytes());
        }
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.output.pop_front()
    }

    fn malformed(&self) -> usize {
        self.malformed
    }

    fn axis(&mut self, channel: usize) -> Option<&mut SimAxis> {
        self.axes.get_mut(channel)
    }

    fn raise_error(&mut self, _channel: usize) -> bool {
        // The MCB-4B reports no errors: a command it does not take is answered like any other.
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emulation::stage;

    #[test]
    fn garbage_from_a_client_is_refused_never_a_panic() {
        let mut e = Mcb4bEmulator::new(2, &stage());
        e.handle_input(Instant::ZERO, b"#01\xc3\xa9\r#01I-9223372036854775808\r#9\r\xff\r");
        let replies: Vec<Vec<u8>> = std::iter::from_fn(|| e.poll_transmit()).collect();
        assert_eq!(replies.len(), 4);
        assert_eq!(e.malformed(), 3, "the huge relative move is a move; the rest are not commands");
    }
}
