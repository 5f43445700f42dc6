//! Golden transcripts: the bytes an EPICS driver module sends for each operation, read from its
//! source and kept as fixtures (`tests/golden/<protocol>.toml`) with the file and line they come
//! from. zmotor's driver sends the same bytes, or the fixture says what it sends instead and why
//! (`zmotor` and `why`: a documented improvement, never an accident); the emulator, which owes
//! nothing to either driver, answers every transcript.
//!
//! ```toml
//! protocol = "pi_gcs2"
//! epics = "epics-motor/motorPIGCS2 at commit …"   # where the bytes were read
//! channels = [1, 2]                               # the channels the operations use
//! referenced_before_moves = true                  # optional: moves and jogs after a home
//! framing = "pmac_ethernet"                       # optional: lines a port layer wraps (below)
//!
//! [[operation]]
//! name = "connect and initialise"
//! at = "connect"                                  # or "command"
//! source = "pigcsApp/src/PIGCSController.cpp:231 (init)"
//! epics = ["*IDN?\n", "SAI?\n"]                   # what the EPICS driver sends, in order
//! replies = ["(c)2015 Physik Instrumente", "1"]    # optional: each reply starts so ("" = none)
//! # zmotor = ["*IDN?\n", "CSV?\n", "SAI?\n"]      # what zmotor sends instead …
//! # why = "…"                                     # … and why
//! # controller_refuses = [["VA-2\r\n", "…"]]       # EPICS bytes the controller refuses, and why
//!
//! [[operation]]
//! name = "move absolute"
//! at = "command"
//! channel = 1
//! command = { cmd = "move", position = 1000.0, relative = false, min_velocity = 0.0, max_velocity = 5000.0, acceleration = 20000.0 }
//! source = "…:412 (move)"
//! epics = ["VEL 1 5\n", "MOV 1 1\n"]
//! ```
//!
//! A connect transcript is compared with the first requests the driver writes on a new
//! connection; a command's with the first requests written after it, the controller up and
//! idle (a poll of one channel is the command `{ cmd = "poll" }`).
//!
//! Where the EPICS module's asyn port wraps each line in a binary packet (`framing`), the
//! transcripts hold the lines: zmotor's requests are unwrapped (their header checked) before
//! they are compared, and the transcripts' lines wrapped before the emulator gets them.
#![allow(dead_code)] // each protocol's test file uses it

use super::{bring_up, home_and_wait, loopback};
use serde::Deserialize;
use std::time::Duration;
use zmotor_controllers::ProtocolKind;
use zmotor_core::Instant;
use zmotor_emulators::Faults;
use zmotor_msgs::DriverCommand;

/// A protocol's transcripts.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Transcripts {
    /// The protocol, as launch files name it.
    pub(crate) protocol: String,
    /// The EPICS driver module the bytes were read from, and its commit.
    pub(crate) epics: String,
    /// The channels the operations use.
    pub(crate) channels: Vec<usize>,
    /// The controller moves only referenced axes (zmotor refuses the move unsent otherwise): a
    /// move's or a jog's bytes are those sent once the channel is homed.
    #[serde(default)]
    pub(crate) referenced_before_moves: bool,
    /// How each line goes on the wire.
    #[serde(default)]
    pub(crate) framing: Framing,
    /// The operations.
    pub(crate) operation: Vec<Operation>,
}

/// One operation's bytes.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Operation {
    /// What it is.
    pub(crate) name: String,
    /// When: on connection, or after a command.
    pub(crate) at: At,
    /// Where in the EPICS driver module the bytes are sent (file:line and function).
    pub(crate) source: String,
    /// The channel a command goes to.
    pub(crate) channel: Option<usize>,
    /// The record's command.
    pub(crate) command: Option<DriverCommand>,
    /// What the EPICS driver sends, in order.
    pub(crate) epics: Vec<String>,
    /// How each reply to `epics` begins, "" where the controller answers nothing.
    pub(crate) replies: Option<Vec<String>>,
    /// What zmotor sends instead, where it differs.
    pub(crate) zmotor: Option<Vec<String>>,
    /// Why zmotor differs.
    pub(crate) why: Option<String>,
    /// Requests of `epics` the controller refuses, by the vendor's manual (an EPICS driver's
    /// bug the emulator witnesses), each with why: (request, why).
    pub(crate) controller_refuses: Option<Vec<(String, String)>>,
}

/// When an operation's bytes are sent.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub(crate) enum At {
    /// On a new connection.
    Connect,
    /// After the operation's command, the controller up and idle.
    Command,
}

/// How a transcript's line goes on the wire.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub(crate) enum Framing {
    /// As the transcript writes it, terminator included.
    #[default]
    AsWritten,
    /// Behind Delta Tau's 8-byte Ethernet header, `VR_DOWNLOAD` `VR_PMAC_GETRESPONSE` 0 0
    /// and the line's length big-endian (DiamondLightSource/pmac pmacAsynIPPort.c:527-531).
    PmacEthernet,
}

impl Framing {
    const PMAC_HEADER: [u8; 6] = [0x40, 0xBF, 0, 0, 0, 0];

    /// `line` as it goes on the wire.
    fn wrap(self, line: &str) -> Vec<u8> {
        match self {
            Framing::AsWritten => line.as_bytes().to_vec(),
            Framing::PmacEthernet => {
                let length = u16::try_from(line.len()).expect("a short line").to_be_bytes();
                [&Self::PMAC_HEADER[..], &length, line.as_bytes()].concat()
            }
        }
    }

    /// The line of a request on the wire.
    fn unwrap(self, bytes: &[u8]) -> String {
        match self {
            Framing::AsWritten => text(bytes),
            Framing::PmacEthernet => {
                let (header, line) = bytes.split_at(8.min(bytes.len()));
                assert_eq!(header[..6], Self::PMAC_HEADER, "a GETRESPONSE header: {bytes:?}");
                assert_eq!(usize::from(u16::from_be_bytes([header[6], header[7]])), line.len(), "wLength: {bytes:?}");
                text(line)
            }
        }
    }
}

impl Operation {
    /// What zmotor's driver is to send.
    pub(crate) fn expected(&self) -> &[String] {
        self.zmotor.as_deref().unwrap_or(&self.epics)
    }
}

/// The transcripts of `protocol` (tests/golden/<protocol>.toml), checked for form.
pub(crate) fn load(protocol: &str) -> Transcripts {
    let path = format!("{}/tests/golden/{protocol}.toml", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let transcripts: Transcripts = toml::from_str(&text).unwrap_or_else(|e| panic!("{path}: {e}"));
    assert_eq!(transcripts.protocol, protocol, "{path}");
    for op in &transcripts.operation {
        assert!(!op.epics.is_empty(), "{}: {} sends nothing", path, op.name);
        assert_eq!(op.zmotor.is_some(), op.why.is_some(), "{path}: {}: zmotor's bytes differ only with a why", op.name);
        if op.at == At::Command {
            assert!(op.channel.is_some() && op.command.is_some(), "{path}: {}: a command and its channel", op.name);
        }
        if let Some(replies) = &op.replies {
            assert_eq!(replies.len(), op.epics.len(), "{path}: {}: one reply pattern per request", op.name);
        }
    }
    transcripts
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// zmotor's driver sends each operation's bytes (the EPICS driver's, or those the fixture
/// gives with its reason), against its emulator.
pub(crate) fn driver_sends_the_transcripts(kind: ProtocolKind) {
    let transcripts = load(kind.name());
    for op in &transcripts.operation {
        let mut lb = loopback(kind, &transcripts.channels, Faults::default());
        let from = match op.at {
            At::Connect => {
                lb.run_for(Duration::from_millis(100));
                0
            }
            At::Command => {
                bring_up(&mut lb);
                let channel = op.channel.unwrap_or_default();
                let command = op.command.as_ref().expect("checked by load");
                let moves = matches!(command, DriverCommand::Move { .. } | DriverCommand::MoveVelocity { .. });
                if moves && transcripts.referenced_before_moves {
                    home_and_wait(&mut lb, channel);
                }
                let from = lb.written().len();
                lb.command(channel, command);
                lb.run_for(Duration::from_millis(50));
                from
            }
        };
        let sent: Vec<String> = lb.written()[from..].iter().map(|b| transcripts.framing.unwrap(b)).collect();
        let expected = op.expected();
        assert!(
            sent.len() >= expected.len() && sent[..expected.len()] == *expected,
            "{} ({}): zmotor sent {:?}, the transcript {:?} (from {})",
            op.name,
            kind.name(),
            &sent[..sent.len().min(expected.len() + 2)],
            expected,
            op.source
        );
    }
}

/// The emulator answers every transcript as EPICS sends it: each request well-formed, each
/// reply as EPICS expects it to begin. A fresh emulator gets the connect transcripts first.
pub(crate) fn emulator_answers_the_transcripts(kind: ProtocolKind) {
    let transcripts = load(kind.name());
    let model = zmotor_emulators::Model::speaking(kind.name()).expect("every protocol has its witness");
    let channels = transcripts.channels.iter().max().map_or(1, |c| c + 1);
    let mut emulator = model.emulator(channels);
    let mut now = Instant::ZERO;
    let connect = transcripts.operation.iter().filter(|op| op.at == At::Connect);
    for op in connect.chain(transcripts.operation.iter().filter(|op| op.at == At::Command)) {
        for (index, request) in op.epics.iter().enumerate() {
            now = now + Duration::from_millis(10);
            let malformed = emulator.malformed();
            emulator.handle_input(now, &transcripts.framing.wrap(request));
            let mut reply = Vec::new();
            while let Some(bytes) = emulator.poll_transmit() {
                reply.extend(bytes);
            }
            let refused = op.controller_refuses.iter().flatten().any(|(bytes, _)| bytes == request);
            assert_eq!(
                emulator.malformed() - malformed,
                usize::from(refused),
                "{} ({}): {request:?} {}",
                op.name,
                op.source,
                if refused {
                    "is refused by the controller, the fixture says; the emulator took it"
                } else {
                    "was not taken by the emulator"
                }
            );
            if let Some(begins) = op.replies.as_ref().map(|r| &r[index]) {
                let reply = text(&reply);
                let fits = if begins.is_empty() { reply.is_empty() } else { reply.starts_with(begins.as_str()) };
                assert!(fits, "{}: {request:?} answered {reply:?}, EPICS expects {begins:?} ({})", op.name, op.source);
            }
        }
    }
}
