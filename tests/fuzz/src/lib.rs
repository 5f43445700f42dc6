//! Entry points for fuzzing: every parser that a stranger (a client's payload, a controller's
//! bytes) or a file (a launch file, an EPICS database) can reach, each as a function of raw
//! bytes that must return, whatever the bytes, without panicking. `cargo-fuzz/` runs them under
//! libFuzzer (nightly); `tests/corpus.rs` replays the committed corpus and random inputs on the
//! stable toolchain, in the test suite.

use std::time::Duration;
use zmotor_bridge::Expression;
use zmotor_bridge::INPUTS;
use zmotor_controllers::{ControllerConfig, ProtocolKind, ProtocolOptions};
use zmotor_core::Instant;
use zmotor_msgs::{decode_write, Attached, Hold, PayloadEncoding, StateMarker, FIELDS};

/// A fuzz target: takes any bytes, returns or panics.
pub type Target = fn(&[u8]);

/// The targets, by name (the corpus directories and the cargo-fuzz targets are named alike).
pub const TARGETS: &[(&str, Target)] = &[
    ("write_decoders", write_decoders),
    ("calc", calc),
    ("launch_toml", launch_toml),
    ("epics_db", epics_db),
    ("controller_replies", controller_replies),
];

/// A write as a client sends it: byte 0 picks the field, byte 1 the encoding, the rest is the
/// payload; the attachment decoders (state marker, hold) read the payload too.
pub fn write_decoders(data: &[u8]) {
    let [field, encoding, payload @ ..] = data else { return };
    let def = &FIELDS[usize::from(*field) % FIELDS.len()];
    let encoding = [PayloadEncoding::Cbor, PayloadEncoding::Json, PayloadEncoding::Text][usize::from(*encoding) % 3];
    if let Ok(value) = decode_write(def, payload, encoding) {
        // What was accepted is accepted again as it is: decoding settles on one value.
        assert_eq!(zmotor_msgs::validate(def, value.clone()).as_ref(), Ok(&value), "{}", def.name);
    }
    let _ = StateMarker::decode(payload);
    // Whatever the bytes, an attachment reads as one thing; a hold read is of kind "hold".
    match Attached::read(payload) {
        Attached::Hold(Ok(hold)) => assert_eq!(hold.kind, Hold::KIND),
        Attached::Hold(Err(_)) | Attached::State | Attached::Plain => {}
    }
}

/// A CALC expression as a launch file or a database gives it, evaluated on inputs made of the
/// same bytes.
pub fn calc(data: &[u8]) {
    let Ok(source) = std::str::from_utf8(data) else { return };
    if let Ok(expression) = Expression::parse(source) {
        let mut inputs = [0.0; INPUTS];
        for (input, byte) in inputs.iter_mut().zip(data) {
            *input = f64::from(*byte) - 128.0;
        }
        let _ = expression.eval(&mut inputs);
    }
}

/// A launch file.
pub fn launch_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(launch) = zmotor_deploy::Launch::parse(text) {
        let _ = launch.deployment(None);
        let _ = launch.to_toml();
    }
}

/// An EPICS database, with a macro defined.
pub fn epics_db(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let macros = zmotor_deploy::Macros::parse(&["P=fz:".to_string()]).expect("a macro definition");
    let _ = zmotor_deploy::import_db_text("fuzz.db", text, &macros, zmotor_msgs::keys::DEFAULT_PREFIX);
}

/// Bytes from a controller: byte 0 picks the protocol, byte 1 how many bytes arrive at a time;
/// the rest arrives on the open connections, piece by piece in turn, while the controller
/// initialises and polls, 10 ms apart.
pub fn controller_replies(data: &[u8]) {
    let [kind, chunk, bytes @ ..] = data else { return };
    let kind = ProtocolKind::ALL[usize::from(*kind) % ProtocolKind::ALL.len()];
    let channels: Vec<usize> = (0..100).filter(|c| kind.check_channel(*c).is_ok()).take(2).collect();
    let config = ControllerConfig::for_channels(channels);
    let mut controller = kind.controller(&ProtocolOptions::default(), config, Instant::ZERO);
    let mut now = Instant::ZERO;
    controller.handle_timeout(now);
    controller.handle_connected(now);
    // Pieces go to each of the controller's connections in turn (an XPS has one per channel).
    let lanes = controller.lanes();
    for (index, piece) in bytes.chunks(usize::from(*chunk).max(1)).enumerate() {
        controller.handle_input(now, lanes[index % lanes.len()], piece);
        now = now + Duration::from_millis(10);
        controller.handle_timeout(now);
        while controller.poll_transmit().is_some() {}
        while controller.poll_event().is_some() {}
    }
}
