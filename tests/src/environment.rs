//! What the end-to-end tests need beyond Rust, as `tests/run` (the README's test command)
//! prepares it: a Python with the pinned stock clients, Chromium and its driver, and whether
//! this machine can make network namespaces. A test that misses one fails saying what is
//! missing and how to get it; none passes by skipping. Only a capability that truly cannot
//! exist here (network namespaces in an unprivileged container) is left untested, and then
//! only under `tests/run`, which lists it at the end (and fails with `--strict`, as CI runs it).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace's root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Where `tests/run` installs what the tests need.
fn test_env() -> PathBuf {
    match std::env::var_os("ZMOTOR_TEST_ENV") {
        Some(dir) => dir.into(),
        None => repo_root().join("target/test-env"),
    }
}

/// The Python that has the stock clients (eclipse-zenoh, cbor2, pyepics, ophyd, bluesky,
/// caproto, selenium, as `tests/python/requirements.txt` pins them).
pub fn python() -> PathBuf {
    let python = match std::env::var_os("ZMOTOR_PYTHON") {
        Some(python) => PathBuf::from(python),
        None => test_env().join("python/bin/python3"),
    };
    assert!(
        python.exists(),
        "{} is missing: the stock Python clients these tests drive zmotor with are not installed; \
         `tests/run` (the README's test command) installs them, or set ZMOTOR_PYTHON to a Python with \
         tests/python/requirements.txt installed",
        python.display()
    );
    python
}

/// A command running `script` (a file of `tests/python`) with the stock clients' Python.
pub fn python_script(script: &str) -> Command {
    let mut command = Command::new(python());
    command.arg(repo_root().join("tests/python").join(script));
    command
}

/// Chromium and ChromeDriver, for the web screen's tests.
pub fn browser() -> (PathBuf, PathBuf) {
    let found = |variable: &str, default: &str| {
        let path = std::env::var_os(variable).map_or_else(|| PathBuf::from(default), PathBuf::from);
        assert!(
            path.exists(),
            "{} is missing: the web screen is tested in headless Chromium; `tests/run` installs Debian's \
             chromium and chromium-driver (apt-get install chromium chromium-driver), or set {variable}",
            path.display()
        );
        path
    };
    (found("ZMOTOR_CHROMIUM", "/usr/bin/chromium"), found("ZMOTOR_CHROMEDRIVER", "/usr/bin/chromedriver"))
}

/// `test` cannot run here because `capability` cannot exist on this machine (`why`). Under
/// `tests/run` it is recorded, listed at the end of the run, and fails a strict run; anywhere
/// else the test fails now, saying so.
pub fn untestable(test: &str, capability: &str, why: &str) {
    let line = format!("{test}: {capability} cannot be made here ({why})");
    match std::env::var_os("ZMOTOR_UNTESTED") {
        Some(file) => {
            use std::io::Write;
            let mut list =
                std::fs::OpenOptions::new().create(true).append(true).open(&file).expect("the untested list");
            writeln!(list, "{line}").expect("the untested list is writable");
            eprintln!("NOT TESTED: {line}");
        }
        None => panic!("{line}; run the suite with `tests/run`, which lists what could not be tested"),
    }
}
