//! What the end-to-end tests need beyond Rust, as `tests/run` (the README's test command)
//! prepares it: a Python with the pinned stock clients, Chromium and its driver, and whether
//! this machine can make network namespaces. A test that misses one fails saying what is
//! missing and how to get it; none passes by skipping. Only a capability that truly cannot
//! exist here (network namespaces in an unprivileged container) is left untested, and then
//! only under `tests/run`, which lists it at the end (and fails with `--strict`, as CI runs it).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

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

/// How long a script of the stock clients may run; each bounds its own waits well within it.
pub const SCRIPT_PATIENCE: Duration = Duration::from_secs(300);

/// How long a script's output may stay open after it exited.
const OUTPUT_CLOSE_PATIENCE: Duration = Duration::from_secs(5);

/// `command` (a script of the stock clients) run to its end within [`SCRIPT_PATIENCE`]: see
/// [`run_within`].
pub fn run_script(command: &mut Command) -> Output {
    run_within(command, SCRIPT_PATIENCE)
}

/// `command` run to its end, as `Command::output` would, but bounded: a process still running
/// after `patience` is killed, with every process it started (its own process group), and the
/// test fails with what it printed. A process it left
/// behind holding its output (a daemon a client library started, such as a CA repeater) fails
/// the test naming that, where `output()` would wait for ever for an end of file.
pub fn run_within(command: &mut Command, patience: Duration) -> Output {
    use std::os::unix::process::CommandExt;
    let mut child = command
        .process_group(0)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|error| panic!("{:?} could not start: {error}", command.get_args().next().unwrap_or_default()));
    let (chunks, received) = mpsc::channel();
    let readers = [
        (0, Box::new(child.stdout.take().expect("piped")) as Box<dyn Read + Send>),
        (1, Box::new(child.stderr.take().expect("piped"))),
    ];
    for (stream, mut reader) in readers {
        let chunks = chunks.clone();
        std::thread::spawn(move || {
            let mut buffer = [0; 4096];
            loop {
                let read = match reader.read(&mut buffer) {
                    Ok(0) => break,
                    Ok(read) => read,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(_) => break,
                };
                if chunks.send((stream, buffer[..read].to_vec())).is_err() {
                    break;
                }
            }
        });
    }
    drop(chunks);
    let mut printed = [Vec::new(), Vec::new()];
    let started = Instant::now();
    let status = loop {
        match received.recv_timeout(Duration::from_millis(20)) {
            Ok((stream, bytes)) => printed[stream].extend(bytes),
            Err(mpsc::RecvTimeoutError::Disconnected) => std::thread::sleep(Duration::from_millis(20)),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > patience {
            // The group is the child's, made at its start: only what this run started.
            let _ = Command::new("kill").args(["-KILL", "--", &format!("-{}", child.id())]).status();
            let _ = child.wait();
            printed_so_far(&received, &mut printed);
            panic!("{:?} still ran after {patience:?}; it printed:\n{}", command, said(&printed));
        }
    };
    let exited = Instant::now();
    loop {
        // Bounded even while something left behind keeps writing.
        if exited.elapsed() > OUTPUT_CLOSE_PATIENCE {
            printed_so_far(&received, &mut printed);
            panic!(
                "{command:?} exited ({status}) but a process it started still holds its output (a daemon left \
                 behind); it printed:\n{}",
                said(&printed)
            );
        }
        match received.recv_timeout(Duration::from_millis(50)) {
            Ok((stream, bytes)) => printed[stream].extend(bytes),
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
    }
    let [stdout, stderr] = printed;
    Output { status, stdout, stderr }
}

/// What the readers have passed on and not yet taken.
fn printed_so_far(received: &mpsc::Receiver<(usize, Vec<u8>)>, printed: &mut [Vec<u8>; 2]) {
    while let Ok((stream, bytes)) = received.try_recv() {
        printed[stream].extend(bytes);
    }
}

fn said(printed: &[Vec<u8>; 2]) -> String {
    format!("{}{}", String::from_utf8_lossy(&printed[0]), String::from_utf8_lossy(&printed[1]))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A process of the run's group, by its id: still alive (a zombie is not).
    fn alive(pid: &str) -> bool {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .is_ok_and(|stat| stat.rsplit_once(") ").is_some_and(|(_, rest)| !rest.starts_with('Z')))
    }

    #[test]
    fn a_run_past_its_time_is_killed_with_what_it_started_and_fails_saying_what_it_printed() {
        let mut command = Command::new("sh");
        command.args(["-c", "sleep 60 & echo started $!; wait"]);
        let failed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run_within(&mut command, Duration::from_millis(500))
        }));
        let message = *failed.expect_err("it ran past its time").downcast::<String>().expect("a message");
        assert!(message.contains("still ran after 500ms"), "{message}");
        // What it printed comes last (the command, also quoted, names no number).
        let pid = message.rsplit("started ").next().and_then(|rest| rest.split_whitespace().next()).expect("the pid");
        assert!(pid.parse::<u32>().is_ok(), "{message}");
        let deadline = Instant::now() + Duration::from_secs(5);
        while alive(pid) {
            assert!(Instant::now() < deadline, "the process it started ({pid}) still runs");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn a_run_that_ends_gives_its_status_and_output() {
        let output = run_within(Command::new("sh").args(["-c", "echo out; echo err >&2; exit 3"]), PATIENCE_OF_A_SHELL);
        assert_eq!(
            (output.status.code(), &output.stdout[..], &output.stderr[..]),
            (Some(3), &b"out\n"[..], &b"err\n"[..])
        );
    }

    const PATIENCE_OF_A_SHELL: Duration = Duration::from_secs(30);
}
