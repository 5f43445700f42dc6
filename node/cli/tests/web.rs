//! `zmotor web` in headless Chromium (tests/python/web_screen.py, Selenium): the index lists the
//! axis, tweak-forward moves it on the page and in the plot, a target beyond the soft limit
//! shows the node's refusal, a socket closed is opened again; the screenshot is kept (`target/tmp/web-screen.png`).

mod common;

use common::{monitor_jogf, time_to_release, Host, Namespaces, RELEASE_MARGIN, RELEASE_PROMISE};
use std::process::Command;
use zmotor_client::free_local_endpoint;
use zmotor_tests::environment;

const AXIS: &str = r#"
[autosave]
enabled = false

[[axis]]
name = "m1"
driver = "sim"
[axis.fields]
DESC = "slit top blade"
EGU = "mm"
MRES = 0.001
VELO = 2
ACCL = 0.2
TWV = 1
DHLM = 100
DLLM = -100
PREC = 3
"#;

#[test]
fn the_motor_screen_moves_an_axis_plots_it_and_shows_a_refusal() {
    // The screen of the launch file's [web], in the node's process.
    let dir = tempfile::tempdir().unwrap();
    let (address, endpoint, here) = (free_address(), free_local_endpoint().unwrap(), Host::default());
    let _node = node_with_screens(&here, dir.path(), &address, &endpoint);

    let screenshot = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("web-screen.png");
    let output =
        environment::run_script(&mut page(&[&format!("http://{address}/"), "m1", screenshot.to_str().unwrap()]));
    let seen = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{seen}\n{}", String::from_utf8_lossy(&output.stderr));
    for check in [
        "lists the axis",
        "tweak forward moves",
        "plot follows",
        "refused with the node's words",
        "screenshot",
        "reconnects",
        "said to be not served",
    ] {
        assert!(seen.lines().any(|l| l.starts_with("ok") && l.contains(check)), "'{check}' not passed:\n{seen}");
    }
    assert!(std::fs::metadata(&screenshot).unwrap().len() > 10_000, "a screenshot of the screen");

    // `zmotor web`, a process of its own, lists the same axis.
    let address = free_address();
    let _web = here.spawn(&["web", "--address", &address, "--name", "Lab-Screen", "--connect", &endpoint], dir.path());
    let (status, axes) = http_get(&address, &address, "/api/axes");
    let m1 = r#""name":"m1","desc":"slit top blade","egu":"mm","rbv":2.0,"prec":3,"moving":false"#;
    assert!(status.contains(" 200 ") && axes.contains(m1), "{status}: {axes}");
    // A page served under another name (DNS rebinding) reaches nothing; the name given does.
    let port = address.rsplit_once(':').unwrap().1;
    let (status, words) = http_get(&address, &format!("evil.example:{port}"), "/api/axes");
    assert!(status.contains(" 421 ") && words.contains("not served as 'evil.example"), "{status}: {words}");
    let (status, axes) = http_get(&address, &format!("lab-screen:{port}"), "/api/axes");
    assert!(status.contains(" 200 ") && axes.contains(m1), "{status}: {axes}");
}

/// A node of `AXIS` on `host`, listening on `endpoint`, whose launch file serves the screens at
/// `address` ([web], in its process); its axis answers.
fn node_with_screens(host: &Host, dir: &std::path::Path, address: &str, endpoint: &str) -> common::Running {
    let file = dir.join("axis.toml");
    std::fs::write(&file, format!("{AXIS}\n[web]\naddress = \"{address}\"\n")).unwrap();
    let node = host.spawn(&["launch", file.to_str().unwrap(), "--listen", endpoint], dir);
    host.wait_for(endpoint, "m1", "DMOV", |v| v == 1.0);
    node
}

/// The page's script in headless Chromium (Selenium, with the stock clients' Python).
fn page(args: &[&str]) -> Command {
    let (chromium, chromedriver) = environment::browser();
    let mut command = environment::python_script("web_screen.py");
    command.args(args).env("ZMOTOR_CHROMIUM", chromium).env("ZMOTOR_CHROMEDRIVER", chromedriver);
    command
}

fn free_address() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    format!("127.0.0.1:{port}")
}

/// The status line and body of a GET with `host` as its Host header, once the server answers.
fn http_get(address: &str, host: &str, path: &str) -> (String, String) {
    use std::io::{Read, Write};
    let deadline = std::time::Instant::now() + common::PATIENCE;
    loop {
        if let Ok(mut stream) = std::net::TcpStream::connect(address) {
            write!(stream, "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").unwrap();
            let mut response = String::new();
            stream.read_to_string(&mut response).unwrap();
            if let Some((head, body)) = response.split_once("\r\n\r\n") {
                let status = head.lines().next().unwrap_or_default().to_string();
                return (status, body.to_string());
            }
        }
        assert!(std::time::Instant::now() < deadline, "nothing answers at {address}");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

#[test]
fn a_jog_from_a_page_whose_browser_is_killed_ends_within_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let (address, endpoint, here) = (free_address(), free_local_endpoint().unwrap(), Host::default());
    let _node = node_with_screens(&here, dir.path(), &address, &endpoint);
    let (_monitor, lines) = monitor_jogf(&here, &endpoint);
    let screenshot = dir.path().join("unused.png");
    let output =
        environment::run_script(&mut page(&[&format!("http://{address}/"), "m1", screenshot.to_str().unwrap(), "jog"]));
    let said = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{said}\n{}", String::from_utf8_lossy(&output.stderr));
    let killed: f64 = said.lines().find_map(|l| l.strip_prefix("killed ")).and_then(|t| t.parse().ok()).unwrap();
    // The monitor's line says when JOGF 0 arrived (UTC, µs).
    let released = std::cell::Cell::new(None);
    lines.wait_for(common::PATIENCE, |line| {
        let Some((_, "0")) = common::monitored(line).filter(|(channel, _)| *channel == "m1.JOGF") else { return false };
        let stamp = line.split_whitespace().skip(1).take(2).collect::<Vec<_>>().join("T") + "Z";
        released.set(humantime::parse_rfc3339(&stamp).ok());
        true
    });
    let released = released.get().expect("JOGF went back to 0");
    let released = released.duration_since(std::time::UNIX_EPOCH).unwrap().as_secs_f64();
    let took = released - killed;
    eprintln!("released {took:.3} s after the browser was killed");
    let margin = RELEASE_MARGIN.as_secs_f64();
    assert!(
        (0.0..margin).contains(&took),
        "released {took:.3} s after the browser was killed (promised: {RELEASE_PROMISE:?})"
    );
}

#[test]
fn a_jog_from_a_page_cut_off_by_the_network_ends_within_a_second() {
    let hosts = [("zwbn", "10.80.0.1"), ("zwbc", "10.80.0.2")];
    let Some(net) = Namespaces::create(&hosts) else {
        let test = "a_jog_from_a_page_cut_off_by_the_network_ends_within_a_second";
        return environment::untestable(test, "network namespaces", common::NETNS_NEEDS);
    };
    let (server, browser) = (net.host(0), net.host(1));
    let endpoint = "tcp/10.80.0.1:7447";
    let dir = tempfile::tempdir().unwrap();
    let _node = node_with_screens(&server, dir.path(), "10.80.0.1:8080", endpoint);
    let screenshot = dir.path().join("unused.png");
    let (chromium, chromedriver) = environment::browser();
    let page = Command::new("ip")
        .args(["netns", "exec", browser.netns.as_deref().unwrap()])
        .arg(environment::python())
        .arg(common::repo_file("tests/python/web_screen.py"))
        .args(["http://10.80.0.1:8080/", "m1", screenshot.to_str().unwrap(), "hold"])
        .env("ZMOTOR_CHROMIUM", chromium)
        .env("ZMOTOR_CHROMEDRIVER", chromedriver)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let took = time_to_release(&server, endpoint, || assert!(net.cut(1), "the link is cut"));
    // The script closes its browser on SIGTERM (a SIGKILL would leave the browser running).
    Command::new("kill").args(["-TERM", &page.id().to_string()]).status().unwrap();
    let mut page = page;
    if common::exited_within(&mut page, common::STOP_PATIENCE).is_none() {
        let _ = page.kill();
        let _ = page.wait();
        panic!("the page's script did not end within {:?} of SIGTERM", common::STOP_PATIENCE);
    }
    assert!(took < RELEASE_MARGIN, "released {took:?} after the page was cut off (promised: {RELEASE_PROMISE:?})");
}
