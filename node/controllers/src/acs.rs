//! ACS MCB-4B: ASCII over a serial line (19200 8N1) or a terminal server's TCP socket, every
//! line ended by `\r`, every command answered by one line. A command is `#NN` (the 0-based
//! axis, two digits), a letter, and its argument: `#01G+12000` moves axis 1 to step 12000.
//! Speeds and accelerations are indexes: speed = 115200 / V steps/s (V 2–255), acceleration =
//! 720000 / (256 − R) steps/s² (R 1–255). The controller has no jog: a jog is a relative move
//! of a million steps. Status is polled per axis: `X` (moving), `P` (position), `E` (limit
//! switches and home switch), `W` (drive power). As the EPICS driver MCB4BDriver.cpp does, but
//! for the order of `P` and `X`: read after `X`, the position of the poll that finds a motion
//! over is the final one (read before, the motor's last steps could show a poll later).

use crate::protocol::{
    line_frame, line_text, set_bit, state_of, whole_steps, CommandError, Frame, Protocol, Purpose, ReplyError,
    ReplyEvent, Request,
};
use crate::scale::Scale;
use zmotor_core::DeviceStatus;
use zmotor_msgs::bits::msta;
use zmotor_msgs::DriverCommand;

/// The protocol's name in launch files.
pub(crate) const NAME: &str = "acs_mcb4b";

/// The line terminator, both ways.
pub(crate) const TERMINATOR: &[u8] = b"\r";

/// The distance of a jog, in steps: the controller has no move at constant velocity.
pub(crate) const JOG_STEPS: i32 = 1_000_000;

/// The speed index of `velocity` steps/s: speed = 115200 / V.
pub(crate) fn speed_index(velocity: f64) -> u32 {
    if velocity == 0.0 || !velocity.is_finite() {
        return 255;
    }
    (115_200.0 / velocity.abs()).round().clamp(2.0, 255.0) as u32
}

/// The ramp index of `acceleration` steps/s²: acceleration = 720000 / (256 − R).
pub(crate) fn ramp_index(acceleration: f64) -> u32 {
    if acceleration <= 0.0 || !acceleration.is_finite() {
        return 255;
    }
    (256.0 - 720_000.0 / acceleration).round().clamp(1.0, 255.0) as u32
}

/// A request of the MCB-4B.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Step {
    /// One reading of a channel's poll.
    Read {
        /// The channel polled.
        channel: usize,
        /// Which reading.
        reading: Reading,
    },
    /// A command, acknowledged by a line whose text means nothing.
    Command {
        /// The channel commanded.
        channel: usize,
    },
}

/// The readings of a channel's poll, in the order they are asked for: the last completes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reading {
    /// `X`: moving or not.
    Moving,
    /// `P`: the position, steps.
    Position,
    /// `E`: the limit switches and the home switch.
    Switches,
    /// `W`: drive power.
    Power,
}

/// The MCB-4B protocol, with the status of each channel being assembled from its poll.
#[derive(Debug, Default)]
pub(crate) struct Mcb4b {
    partial: Vec<(usize, DeviceStatus)>,
}

impl Mcb4b {
    /// A protocol with nothing polled yet.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    fn partial(&mut self, channel: usize) -> &mut DeviceStatus {
        state_of(&mut self.partial, channel)
    }
}

/// `#NN` and the rest, as one request line.
fn line(channel: usize, rest: &str) -> Vec<u8> {
    format!("#{channel:02}{rest}\r").into_bytes()
}

fn command_request(channel: usize, rest: &str) -> Request<Step> {
    Request::query(line(channel, rest), Step::Command { channel })
}

/// Speed and ramp, as every motion sets them first.
fn speed_and_ramp(channel: usize, velocity: f64, acceleration: f64) -> Vec<Request<Step>> {
    vec![
        command_request(channel, &format!("V={}", speed_index(velocity))),
        command_request(channel, &format!("R={}", ramp_index(acceleration))),
    ]
}

impl Protocol for Mcb4b {
    type Step = Step;

    fn name(&self) -> &'static str {
        NAME
    }

    fn scale(&self, _channel: usize) -> Scale {
        // Motor steps, one per record step: the MCB-4B knows no other unit.
        Scale::motor_steps()
    }

    fn purpose(step: Step) -> Purpose {
        match step {
            Step::Read { channel, .. } => Purpose::Poll { channel },
            Step::Command { channel } => Purpose::Command { channel },
        }
    }

    fn frame(&self, buffer: &[u8]) -> Frame {
        match line_frame(buffer, TERMINATOR) {
            // A stray terminator is not a reply.
            Frame::Complete(1) => Frame::Junk(1),
            frame => frame,
        }
    }

    fn init(&mut self, _channels: &[usize]) -> Vec<Request<Step>> {
        // The EPICS driver sends nothing but the first poll: nothing moves, nothing powers up.
        Vec::new()
    }

    fn poll(&mut self, channels: &[usize]) -> Vec<Request<Step>> {
        let mut requests = Vec::new();
        for &channel in channels {
            for (reading, letter) in
                [(Reading::Moving, "X"), (Reading::Position, "P"), (Reading::Switches, "E"), (Reading::Power, "W")]
            {
                requests.push(Request::query(line(channel, letter), Step::Read { channel, reading }));
            }
        }
        requests
    }

    fn command(&mut self, channel: usize, command: &DriverCommand) -> Result<Vec<Request<Step>>, CommandError> {
        let requests = match command {
            DriverCommand::Move { position, relative, max_velocity, acceleration, .. } => {
                let steps = whole_steps("target", *position)?;
                let mut requests = speed_and_ramp(channel, *max_velocity, *acceleration);
                let verb = if *relative { "I" } else { "G" };
                requests.push(command_request(channel, &format!("{verb}{steps:+}")));
                requests
            }
            DriverCommand::MoveVelocity { max_velocity, acceleration, .. } => {
                let mut requests = speed_and_ramp(channel, *max_velocity, *acceleration);
                let distance = if *max_velocity >= 0.0 { JOG_STEPS } else { -JOG_STEPS };
                requests.push(command_request(channel, &format!("I{distance:+}")));
                requests
            }
            DriverCommand::Home { forward, max_velocity, acceleration, .. } => {
                let mut requests = speed_and_ramp(channel, *max_velocity, *acceleration);
                requests.push(command_request(channel, if *forward { "H+" } else { "H-" }));
                requests
            }
            DriverCommand::Stop { .. } => vec![command_request(channel, "Q")],
            DriverCommand::SetPosition { position } => {
                vec![command_request(channel, &format!("P={:+}", whole_steps("position", *position)?))]
            }
            DriverCommand::Enable { on } => vec![command_request(channel, if *on { "W=1" } else { "W=0" })],
            DriverCommand::Raw { text } => {
                vec![Request::query(format!("{text}\r"), Step::Command { channel })]
            }
            // The MCB-4B keeps no soft limits, gains or encoder ratio; a status refresh is a poll.
            DriverCommand::SetEncoderRatio { .. }
            | DriverCommand::SetHighLimit { .. }
            | DriverCommand::SetLowLimit { .. }
            | DriverCommand::SetGain { .. }
            | DriverCommand::Poll => Vec::new(),
        };
        Ok(requests)
    }

    fn reply(&mut self, request: &Request<Step>, frame: &[u8]) -> Result<Vec<ReplyEvent<Step>>, ReplyError> {
        let text = line_text(frame, TERMINATOR);
        let (channel, reading) = match request.step {
            Step::Read { channel, reading } => (channel, reading),
            // A command's acknowledgement: its text is not defined, only that it comes.
            Step::Command { .. } => return Ok(Vec::new()),
        };
        let asked = line_text(&request.bytes, TERMINATOR);
        let value = text
            .strip_prefix(asked.as_str())
            .and_then(|rest| rest.strip_prefix('='))
            .ok_or_else(|| ReplyError::new(request, frame, "not the echo of the query"))?;
        let flag = |at: usize| value.as_bytes().get(at).map(|b| *b == b'1');
        let status = self.partial(channel);
        match reading {
            Reading::Position => {
                let steps: f64 = value.trim().parse().map_err(|_| ReplyError::new(request, frame, "not a position"))?;
                let moved_up = steps > status.position;
                status.msta = if moved_up { status.msta | msta::DIRECTION } else { status.msta & !msta::DIRECTION };
                status.position = steps;
                status.encoder_position = steps;
            }
            Reading::Moving => {
                let moving = value.as_bytes().first().ok_or_else(|| ReplyError::new(request, frame, "empty"))? != &b'0';
                set_bit(&mut status.msta, msta::DONE, !moving);
                set_bit(&mut status.msta, msta::MOVING, moving);
            }
            Reading::Switches => {
                let (Some(plus), Some(minus), Some(home)) = (flag(0), flag(1), flag(2)) else {
                    return Err(ReplyError::new(request, frame, "fewer than three switch flags"));
                };
                set_bit(&mut status.msta, msta::PLUS_LS, plus);
                set_bit(&mut status.msta, msta::MINUS_LS, minus);
                set_bit(&mut status.msta, msta::HOME, home);
            }
            Reading::Power => {
                let powered = flag(0).ok_or_else(|| ReplyError::new(request, frame, "empty"))?;
                set_bit(&mut status.msta, msta::POSITION, powered);
                // The direction bit tells the current motion, not the last one.
                if status.msta & msta::DONE != 0 {
                    status.msta &= !msta::DIRECTION;
                }
                return Ok(vec![ReplyEvent::Status { channel, status: *status }]);
            }
        }
        Ok(Vec::new())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sent(requests: &[Request<Step>]) -> Vec<String> {
        requests.iter().map(|r| String::from_utf8_lossy(&r.bytes).into_owned()).collect()
    }

    #[test]
    fn indexes_follow_the_controller_formulas_and_its_ranges() {
        assert_eq!((speed_index(2000.0), ramp_index(9500.0)), (58, 180));
        assert_eq!((speed_index(1.0), speed_index(1e9), ramp_index(1.0), ramp_index(1e9)), (255, 2, 1, 255));
    }

    #[test]
    fn moves_set_speed_and_ramp_then_go() {
        let mut p = Mcb4b::new();
        let go = DriverCommand::Move {
            position: 12000.0,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 2000.0,
            acceleration: 9500.0,
        };
        assert_eq!(sent(&p.command(1, &go).unwrap()), ["#01V=58\r", "#01R=180\r", "#01G+12000\r"]);
        let by = DriverCommand::Move {
            position: -500.4,
            relative: true,
            min_velocity: 0.0,
            max_velocity: 2000.0,
            acceleration: 9500.0,
        };
        assert_eq!(sent(&p.command(3, &by).unwrap())[2], "#03I-500\r");
        let jog = DriverCommand::MoveVelocity { min_velocity: 0.0, max_velocity: -1000.0, acceleration: 9500.0 };
        assert_eq!(sent(&p.command(0, &jog).unwrap())[2], "#00I-1000000\r");
        let home = DriverCommand::Home { forward: true, min_velocity: 0.0, max_velocity: 1000.0, acceleration: 9500.0 };
        assert_eq!(sent(&p.command(0, &home).unwrap())[2], "#00H+\r");
        assert_eq!(sent(&p.command(2, &DriverCommand::Stop { acceleration: 1.0 }).unwrap()), ["#02Q\r"]);
        assert_eq!(sent(&p.command(2, &DriverCommand::SetPosition { position: 0.0 }).unwrap()), ["#02P=+0\r"]);
        let far = DriverCommand::Move {
            position: 3e9,
            relative: false,
            min_velocity: 0.0,
            max_velocity: 1.0,
            acceleration: 1.0,
        };
        assert!(matches!(p.command(0, &far), Err(CommandError::OutOfRange { .. })), "refused, not clamped");
    }

    #[test]
    fn a_poll_reads_motion_position_switches_and_power() {
        let mut p = Mcb4b::new();
        let poll = p.poll(&[1]);
        assert_eq!(sent(&poll), ["#01X\r", "#01P\r", "#01E\r", "#01W\r"]);
        assert_eq!(p.reply(&poll[0], b"#01X=1\r").unwrap(), []);
        assert_eq!(p.reply(&poll[1], b"#01P=+1500\r").unwrap(), []);
        assert_eq!(p.reply(&poll[2], b"#01E=101\r").unwrap(), []);
        let events = p.reply(&poll[3], b"#01W=1\r").unwrap();
        let [ReplyEvent::Status { channel: 1, status }] = &events[..] else { panic!("{events:?}") };
        assert_eq!(status.position, 1500.0);
        let expected = msta::MOVING | msta::PLUS_LS | msta::HOME | msta::POSITION | msta::DIRECTION;
        assert_eq!(status.msta, expected);
    }

    #[test]
    fn a_reply_that_is_not_the_echo_of_its_query_is_refused() {
        let mut p = Mcb4b::new();
        let poll = p.poll(&[1]);
        assert!(p.reply(&poll[1], b"#02P=+1500\r").is_err(), "another axis's reply");
        assert!(p.reply(&poll[1], b"#01P=lots\r").is_err());
        assert!(p.reply(&poll[2], b"#01E=1\r").is_err());
    }
}
