//! Every fuzz target returns on every input of its committed corpus (`corpus/<target>/`) and on
//! random inputs, quickly: the short run of the fuzzing that the test suite does on the stable
//! toolchain. The long runs are libFuzzer's (`cargo-fuzz/`, BENCHMARKS.md).

use proptest::prelude::*;
use std::path::Path;
use std::time::{Duration, Instant};
use zmotor_fuzz::{Target, TARGETS};

/// Longest an input may take (a hang is a finding too).
const PATIENCE: Duration = Duration::from_secs(1);

fn run(name: &str, target: Target, input: &[u8]) {
    let start = Instant::now();
    target(input);
    assert!(start.elapsed() < PATIENCE, "{name} took {:?} on {input:?}", start.elapsed());
}

#[test]
fn every_target_returns_on_its_committed_corpus() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus");
    for (name, target) in TARGETS {
        let dir = root.join(name);
        let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        let mut replayed = 0;
        for entry in entries {
            let input = std::fs::read(entry.unwrap().path()).unwrap();
            run(name, *target, &input);
            replayed += 1;
        }
        assert!(replayed > 0, "{name} has a corpus");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]
    #[test]
    fn every_target_returns_on_random_bytes(input in proptest::collection::vec(any::<u8>(), 0..512)) {
        for (name, target) in TARGETS {
            run(name, *target, &input);
        }
    }

    /// Text reaches further than random bytes into the parsers of text (calc, TOML, databases).
    #[test]
    fn every_target_returns_on_random_text(text in "\\PC{0,512}") {
        for (name, target) in TARGETS {
            run(name, *target, text.as_bytes());
        }
    }
}
