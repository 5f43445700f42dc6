//! The processes the benchmark starts: nodes as a user starts them (`zmotor launch FILE`), and
//! the floor beside them (`zmotor-bench floor ...`: Zenoh alone, no zmotor code on its path).

use crate::Error;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use zenoh::Session;
use zmotor_client::{free_local_endpoint, Client};
use zmotor_deploy::ZenohConfig;
use zmotor_msgs::{Field, KeyLayout};

/// A child process, killed when dropped.
pub(crate) struct Process(Child);

impl Process {
    pub(crate) fn pid(&self) -> String {
        self.0.id().to_string()
    }

    /// SIGKILL it now.
    pub(crate) fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl From<Child> for Process {
    fn from(child: Child) -> Self {
        Self(child)
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        self.kill();
    }
}

/// What the benchmark runs: the `zmotor` it measures, and this program (for the floor).
#[derive(Clone, Debug)]
pub(crate) struct Programs {
    pub(crate) zmotor: PathBuf,
    pub(crate) bench: PathBuf,
    /// Where launch files and state go.
    pub(crate) dir: PathBuf,
}

impl Programs {
    /// `zmotor ARGS`, quiet.
    pub(crate) fn zmotor(&self, args: &[&str]) -> Command {
        let mut command = Command::new(&self.zmotor);
        command.args(args).env("RUST_LOG", "off").stdout(Stdio::null()).stderr(Stdio::null());
        command
    }

    /// A node as a user starts it: `zmotor launch FILE --listen ENDPOINT`, the launch file's
    /// text written here; its endpoint.
    pub(crate) fn launch(&self, name: &str, text: &str) -> Result<(Process, String), Error> {
        let file = self.dir.join(format!("{name}.toml"));
        std::fs::write(&file, text)?;
        self.launch_file(&file)
    }

    /// `zmotor launch FILE --listen ENDPOINT`, its state in the benchmark's directory.
    pub(crate) fn launch_file(&self, file: &Path) -> Result<(Process, String), Error> {
        let endpoint = free_local_endpoint()?;
        let child = self
            .zmotor(&["launch", &file.to_string_lossy(), "--listen", &endpoint])
            .env("ZMOTOR_STATE_DIR", self.dir.join("state"))
            .spawn()?;
        Ok((Process(child), endpoint))
    }

    /// The floor: `zmotor-bench floor ARGS`, Zenoh alone.
    pub(crate) fn floor(&self, args: &[&str]) -> Result<Process, Error> {
        let child = Command::new(&self.bench)
            .arg("floor")
            .args(args)
            .env("RUST_LOG", "off")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        Ok(Process(child))
    }
}

/// A client of a process that may not listen yet.
pub(crate) async fn client_when_ready(endpoint: &str) -> Result<Client, Error> {
    let since = Instant::now();
    loop {
        if let Ok(client) = Client::connect(&ZenohConfig::client(endpoint)).await {
            return Ok(client);
        }
        if since.elapsed() > Duration::from_secs(60) {
            return Err(format!("nothing listens at {endpoint} after 60 s").into());
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// How many axes answer a get of their DMOV.
async fn answering(session: &Session) -> Result<usize, Error> {
    let replies = session.get(KeyLayout::default().field("*", Field::DMOV)).timeout(Duration::from_secs(10)).await?;
    let mut n = 0;
    while let Ok(reply) = replies.recv_async().await {
        n += usize::from(reply.result().is_ok());
    }
    Ok(n)
}

/// Wait until `n` axes answer; how long it took.
pub(crate) async fn wait_for_axes(session: &Session, n: usize, limit: Duration) -> Result<Duration, Error> {
    let start = Instant::now();
    while start.elapsed() < limit {
        if answering(session).await? >= n {
            return Ok(start.elapsed());
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Err(format!("{n} axes did not all answer within {limit:?}").into())
}
