//! A whole launch: the main file with its includes and databases merged, checked, and cut
//! into a deployment per host.

use crate::db::{import_db, Macros};
use crate::deployment::{Deployment, NodeContents, ValueSpec};
use crate::file::{
    read_text, AxisSection, CalcSection, ControllerSection, LaunchError, LaunchFile, Origin, ScriptFiles, ValueSection,
};
use crate::front_ends::{CaConfig, WebConfig};
use crate::locate::{self, line_of, Seg};
use crate::network::ZenohConfig;
use crate::plans::check_wiring;
use crate::problem::{keys_path, Problem};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use zmotor_controllers::{ProtocolKind, RecordUnits};
use zmotor_msgs::{keys, KeyLayout};

/// A file that took part in a launch, kept to point errors at their line.
#[derive(Clone, Debug, PartialEq)]
struct Source {
    name: String,
    text: String,
    /// A database's: its records' host is its `[[database]]` entry's.
    database: bool,
}

/// A whole launch: the main file with its includes merged, checked.
#[derive(Clone, Debug, PartialEq)]
pub struct Launch {
    /// Every item, the includes merged in.
    pub file: LaunchFile,
    /// Directory relative paths of the main file are resolved against.
    base: PathBuf,
    sources: Vec<Source>,
    /// What importing its databases warned of.
    warnings: Vec<String>,
}

impl Launch {
    /// Read and check a launch file and everything it includes.
    pub fn load(path: &Path) -> Result<Self, LaunchError> {
        let name = path.display().to_string();
        let text = read_text(path)?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::build(&name, &text, &base, std::fs::canonicalize(path).ok())
    }

    /// Check a launch file's text; includes are resolved against `base`.
    pub fn from_text(name: &str, text: &str, base: &Path) -> Result<Self, LaunchError> {
        Self::build(name, text, base, None)
    }

    /// `canonical`: the main file's own path, so that including it is found out.
    fn build(name: &str, text: &str, base: &Path, canonical: Option<PathBuf>) -> Result<Self, LaunchError> {
        let mut launch =
            Self { file: LaunchFile::default(), base: base.to_path_buf(), sources: Vec::new(), warnings: Vec::new() };
        let main = launch.read_source(name, text)?;
        if let Some(zenoh) = main.zenoh.clone() {
            launch.file.zenoh = Some(zenoh);
        }
        launch.file.state_dir = main.state_dir.clone();
        launch.file.autosave = main.autosave.clone();
        launch.file.channel_access = main.channel_access.clone();
        launch.file.web = main.web.clone();
        launch.file.ros2 = main.ros2.clone();
        let mut visited: BTreeSet<PathBuf> = canonical.into_iter().collect();
        launch.merge(main, base, &mut visited)?;
        launch.check().map_err(|p| launch.error(p))?;
        let f = &launch.file;
        if f.axes.is_empty() && f.calcs.is_empty() && f.values.is_empty() && f.controllers.is_empty() {
            launch.warnings.push(format!("{name}: no axis, calc link, value holder or controller: nothing to serve"));
        }
        Ok(launch)
    }

    /// A launch built in memory (an imported database): checked like a file.
    pub fn from_file(name: &str, file: LaunchFile) -> Result<Self, LaunchError> {
        let text = toml::to_string(&file).unwrap_or_default();
        Self::from_text(name, &text, Path::new(""))
    }

    /// Check a launch file's text with no includes and no name (tests, examples).
    pub fn parse(text: &str) -> Result<Self, LaunchError> {
        Self::from_text("<launch>", text, Path::new(""))
    }

    fn read_source(&mut self, name: &str, text: &str) -> Result<LaunchFile, LaunchError> {
        self.sources.push(Source { name: name.to_string(), text: text.to_string(), database: false });
        toml::from_str(text).map_err(|e: toml::de::Error| {
            let message = e.message().trim();
            // Named by its key, unless the message names it already.
            let key = e.span().and_then(|span| locate::key_at(text, span.start)).filter(|key| {
                let last = key.rsplit(['.', ' ']).next().unwrap_or(key);
                !message.starts_with(key.as_str()) && !message.starts_with(&format!("{last}:"))
            });
            LaunchError {
                file: name.to_string(),
                line: e.span().map(|span| locate::line_at(text, span.start)),
                message: match key {
                    Some(key) => format!("{key}: {message}"),
                    None => message.to_string(),
                },
            }
        })
    }

    /// Append a file's items (and, depth first, those of its includes).
    fn merge(&mut self, file: LaunchFile, dir: &Path, visited: &mut BTreeSet<PathBuf>) -> Result<(), LaunchError> {
        let source = self.sources.len() - 1;
        let origin = |index| Origin { source, index };
        self.file.hosts.extend(file.hosts);
        for (index, controller) in file.controllers.into_iter().enumerate() {
            let script_files = match &controller.script {
                Some(script) => {
                    let files = ScriptFiles::read(&dir.join(script)).map_err(|message| {
                        let path = vec![Seg::Key("controller".into()), Seg::Index(index), Seg::Key("script".into())];
                        self.error(Problem::at(
                            source,
                            path,
                            format!("controller '{}': script: {message}", controller.name),
                        ))
                    })?;
                    Some(files)
                }
                None => None,
            };
            self.file.controllers.push(ControllerSection { origin: origin(index), script_files, ..controller });
        }
        self.file.axes.extend(file.axes.into_iter().enumerate().map(|(i, a)| AxisSection { origin: origin(i), ..a }));
        self.file.calcs.extend(file.calcs.into_iter().enumerate().map(|(i, c)| CalcSection { origin: origin(i), ..c }));
        self.file
            .values
            .extend(file.values.into_iter().enumerate().map(|(i, v)| ValueSection { origin: origin(i), ..v }));
        for database in &file.databases {
            let path = dir.join(&database.file);
            let macros = Macros::from(database.macros.clone());
            // Its motors are served under the launch's prefix, and their links name them there.
            let prefix = self.file.zenoh.as_ref().map_or(keys::DEFAULT_PREFIX, |z| z.prefix.as_str());
            let (imported, warnings) = import_db(&path, &macros, prefix)?;
            let name = path.display().to_string();
            self.warnings.extend(warnings.into_iter().map(|w| format!("{name}: {w}")));
            // Errors found later in its records name the database (its lines are its own).
            self.sources.push(Source { name, text: String::new(), database: true });
            let mut imported = LaunchFile { include: Vec::new(), databases: Vec::new(), ..imported };
            let hosts = imported.axes.iter_mut().map(|a| &mut a.host);
            let hosts = hosts.chain(imported.calcs.iter_mut().map(|c| &mut c.host));
            hosts.chain(imported.values.iter_mut().map(|v| &mut v.host)).for_each(|h| *h = database.host.clone());
            self.merge(imported, dir, visited)?;
        }
        for (index, include) in file.include.iter().enumerate() {
            let at = |message: String| {
                self.error(Problem::at(source, vec![Seg::Key("include".into()), Seg::Index(index)], message))
            };
            let path = dir.join(include);
            let canonical = std::fs::canonicalize(&path).map_err(|e| at(format!("{}: {e}", path.display())))?;
            if !visited.insert(canonical) {
                return Err(at(format!("{} is included twice (or includes itself)", path.display())));
            }
            let text = crate::file::read_bounded(&path).map_err(|e| at(format!("{}: {e}", path.display())))?;
            let included = self.read_source(&path.display().to_string(), &text)?;
            let included_source = self.sources.len() - 1;
            for (key, present) in [
                ("zenoh", included.zenoh.is_some()),
                ("state_dir", included.state_dir.is_some()),
                ("autosave", included.autosave.is_some()),
                ("channel_access", included.channel_access.is_some()),
                ("web", included.web.is_some()),
                ("ros2", included.ros2.is_some()),
            ] {
                if present {
                    let message = format!("{key} may only be set in the main launch file");
                    return Err(self.error(Problem::at(included_source, vec![Seg::Key(key.into())], message)));
                }
            }
            let included_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
            self.merge(included, &included_dir, visited)?;
        }
        Ok(())
    }

    fn error(&self, problem: Problem) -> LaunchError {
        let source = &self.sources[problem.source];
        LaunchError { file: source.name.clone(), line: line_of(&source.text, &problem.path), message: problem.message }
    }

    /// What importing the launch's databases warned of (hardware simulated, records skipped),
    /// and a launch that serves nothing.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The `[zenoh]` section, or its defaults.
    pub fn zenoh(&self) -> ZenohConfig {
        self.file.zenoh.clone().unwrap_or_default()
    }

    fn check(&self) -> Result<(), Problem> {
        let zenoh = self.zenoh();
        // Every key of the deployment starts with it: one plain key, no wildcard.
        if let Err(e) = keys::validate_plain_key(&zenoh.prefix) {
            return Err(Problem::at(0, keys_path(&["zenoh", "prefix"]), format!("zenoh.prefix: {e}")));
        }
        if self.file.state_dir.as_deref().is_some_and(|dir| dir.trim().is_empty()) {
            // Joined to the file's folder it would be that folder: state beside the launch files.
            let message = "state_dir: empty: name a directory (relative to this file), or leave it out for the \
                           default ($XDG_STATE_HOME/zmotor)";
            return Err(Problem::at(0, keys_path(&["state_dir"]), message.to_string()));
        }
        if let Some(autosave) = &self.file.autosave {
            if !(autosave.delay >= 0.0 && autosave.delay <= 3600.0) {
                let message = format!("autosave.delay: {} s is outside [0, 3600]", autosave.delay);
                return Err(Problem::at(0, keys_path(&["autosave", "delay"]), message));
            }
        }
        for (index, rule) in zenoh.access.iter().enumerate() {
            let at = |key: &str, message: String| {
                let path =
                    vec![Seg::Key("zenoh".into()), Seg::Key("access".into()), Seg::Index(index), Seg::Key(key.into())];
                Problem::at(0, path, format!("zenoh.access '{}': {message}", rule.name))
            };
            if rule.may.is_empty() {
                return Err(at("may", "grants nothing: say what its members may (read, drive, configure, all)".into()));
            }
            if rule.cert_common_names.is_empty() && rule.usernames.is_empty() && rule.interfaces.is_empty() {
                let message = "has no members: name cert_common_names, usernames or interfaces".to_string();
                return Err(at("name", message));
            }
            if zenoh.access[..index].iter().any(|r| r.name == rule.name) {
                return Err(at("name", "is defined twice".into()));
            }
        }
        let items = self.items();
        let mut seen = BTreeMap::new();
        for (table, name, host, origin) in &items {
            if seen.insert((*table, *name), origin).is_some() {
                return Err(Problem::in_item(table, *origin, &["name"], format!("{table} '{name}' is defined twice")));
            }
            match host {
                Some(host) if !self.file.hosts.contains_key(*host) => {
                    let known = self.file.hosts.keys().cloned().collect::<Vec<_>>().join(", ");
                    let message =
                        format!("{table} '{name}': host '{host}' is not declared under [hosts] (known: {known})");
                    return Err(Problem::in_item(table, *origin, &["host"], message));
                }
                None if !self.file.hosts.is_empty() => {
                    let mut message = format!("{table} '{name}': names no host, and this launch declares hosts");
                    if self.sources[origin.source].database {
                        message += " (its [[database]] entry names the host of its records)";
                    }
                    return Err(Problem::in_item(table, *origin, &["name"], message));
                }
                _ => {}
            }
        }
        for controller in &self.file.controllers {
            controller.spec(Vec::new())?;
        }
        let front_ends = [
            ("channel_access", self.file.channel_access.as_ref().map(|ca| ca.host.as_ref())),
            ("web", self.file.web.as_ref().map(|web| web.host.as_ref())),
            ("ros2", self.file.ros2.as_ref().map(|ros2| ros2.host.as_ref())),
        ];
        for (section, host) in front_ends.into_iter().filter_map(|(section, host)| Some((section, host?))) {
            match host {
                Some(host) if !self.file.hosts.contains_key(host) => {
                    let message = format!("{section}.host: '{host}' is not declared under [hosts]");
                    return Err(Problem::at(0, keys_path(&[section, "host"]), message));
                }
                // Under --host it would run on no host at all.
                None if !self.file.hosts.is_empty() => {
                    let message = format!("[{section}] names no host, and this launch declares hosts");
                    return Err(Problem::at(0, keys_path(&[section]), message));
                }
                _ => {}
            }
        }
        self.check_axes_on_controllers()?;
        self.check_controller_connections()?;
        self.check_ros2()?;
        let plans = self.file.axes.iter().map(AxisSection::plan).collect::<Result<Vec<_>, _>>()?;
        let calcs = self.file.calcs.iter().map(CalcSection::spec).collect::<Result<Vec<_>, _>>()?;
        let layout = KeyLayout::new(&zenoh.prefix);
        for value in &self.file.values {
            let key = value.key();
            keys::validate_plain_key(&key)
                .map_err(|e| Problem::in_item("value", value.origin, &["key"], e.to_string()))?;
            if key == zenoh.prefix || layout.axis_chunk(&key).is_some() {
                let default = if value.key.is_none() { ", its key by default," } else { "" };
                let message = format!(
                    "'{key}'{default} is under the axes' prefix '{}': a value holder there would answer for an \
                     axis (or the axes' queries); give it a key outside the prefix",
                    zenoh.prefix
                );
                return Err(Problem::in_item("value", value.origin, &["key"], message));
            }
            if !value.value.is_finite() {
                return Err(Problem::in_item("value", value.origin, &["value"], "must be a finite number"));
            }
        }
        let axis_origins: Vec<Origin> = self.file.axes.iter().map(|a| a.origin).collect();
        let calc_origins: Vec<Origin> = self.file.calcs.iter().map(|c| c.origin).collect();
        check_wiring(&layout, &plans, &axis_origins, &calcs, &calc_origins)
    }

    /// `[ros2]` names ROS accepts and joints on axes of this launch, and no access rules it
    /// would go around.
    fn check_ros2(&self) -> Result<(), Problem> {
        let Some(ros2) = &self.file.ros2 else { return Ok(()) };
        if self.zenoh().guarded() {
            let message = "[ros2] cannot run under [[zenoh.access]] rules yet: they do not cover ROS 2's keys, and \
                           whoever may read (query any key) could send the ROS face trajectory goals it would run \
                           with the node's rights";
            return Err(Problem::at(0, keys_path(&["ros2"]), message));
        }
        let config = ros2.config().map_err(|(key, message)| Problem::at(0, keys_path(&["ros2", key]), message))?;
        for joint in &config.joints {
            if !self.file.axes.iter().any(|a| a.name == joint.axis) {
                let known: Vec<&str> = self.file.axes.iter().map(|a| a.name.as_str()).collect();
                let message = format!(
                    "joint '{}': no axis '{}' in this launch (known: {})",
                    joint.name,
                    joint.axis,
                    known.join(", ")
                );
                return Err(Problem::at(0, keys_path(&["ros2", "joint"]), message));
            }
        }
        Ok(())
    }

    /// (table, name, host, origin) of every item.
    fn items(&self) -> Vec<(&'static str, &str, Option<&str>, Origin)> {
        let f = &self.file;
        let controllers = f.controllers.iter().map(|c| ("controller", c.name.as_str(), c.host.as_deref(), c.origin));
        let axes = f.axes.iter().map(|a| ("axis", a.name.as_str(), a.host.as_deref(), a.origin));
        let calcs = f.calcs.iter().map(|c| ("calc", c.name.as_str(), c.host.as_deref(), c.origin));
        let values = f.values.iter().map(|v| ("value", v.name.as_str(), v.host.as_deref(), v.origin));
        controllers.chain(axes).chain(calcs).chain(values).collect()
    }

    /// Every axis on a controller names one of this launch, on its host, by a channel the
    /// protocol has and no other axis of that controller uses.
    fn check_axes_on_controllers(&self) -> Result<(), Problem> {
        let mut taken: BTreeMap<(&str, usize), &str> = BTreeMap::new();
        for axis in &self.file.axes {
            let at = |key: &str, message: String| {
                Problem::in_item("axis", axis.origin, &[key], format!("axis '{}': {key}: {message}", axis.name))
            };
            let (Some(name), Some(channel)) = (&axis.controller, axis.channel) else { continue };
            let Some(controller) = self.file.controllers.iter().find(|c| c.name == *name) else {
                let known: Vec<&str> = self.file.controllers.iter().map(|c| c.name.as_str()).collect();
                return Err(at("controller", format!("no [[controller]] '{name}' (known: {})", known.join(", "))));
            };
            if controller.host != axis.host {
                let message = format!("controller '{name}' runs on another host: an axis runs where its controller is");
                return Err(at("host", message));
            }
            if let Some(protocol) = ProtocolKind::from_name(&controller.protocol) {
                protocol.check_channel(channel).map_err(|e| at("channel", e.to_string()))?;
            }
            if let Some(other) = taken.insert((name.as_str(), channel), axis.name.as_str()) {
                return Err(at(
                    "channel",
                    format!("channel {channel} of controller '{name}' is already axis '{other}'"),
                ));
            }
        }
        Ok(())
    }

    /// No two controllers of one host open the same connection: two sections would be two
    /// records driving each motor of it. (An XPS takes several connections, and its axes are
    /// its positioners, by name: it is left out.)
    fn check_controller_connections(&self) -> Result<(), Problem> {
        let mut opened: BTreeMap<(Option<&str>, String), &str> = BTreeMap::new();
        for controller in &self.file.controllers {
            if controller.protocol == ProtocolKind::NewportXps.name() {
                continue;
            }
            let (key, connection) = match (&controller.tcp, &controller.serial) {
                (Some(tcp), _) => ("tcp", format!("tcp {}", tcp.trim())),
                (None, Some(serial)) => ("serial", format!("serial {}", serial.device.trim())),
                (None, None) => continue,
            };
            if let Some(other) = opened.insert((controller.host.as_deref(), connection.clone()), &controller.name) {
                let message = format!(
                    "controller '{}': {key}: {connection} is already controller '{other}': one connection, one \
                     controller (give its axes to '{other}')",
                    controller.name
                );
                return Err(Problem::in_item("controller", controller.origin, &[key], message));
            }
        }
        Ok(())
    }

    /// The names of the hosts under `[hosts]`.
    pub fn hosts(&self) -> impl Iterator<Item = &str> {
        self.file.hosts.keys().map(String::as_str)
    }

    /// What the process for `host` runs (everything when `host` is None).
    pub fn deployment(&self, host: Option<&str>) -> Result<Deployment, LaunchError> {
        let mut zenoh = self.zenoh();
        if let Some(host) = host {
            let Some(section) = self.file.hosts.get(host) else {
                let known = self.hosts().collect::<Vec<_>>().join(", ");
                let message = if known.is_empty() {
                    format!("--host {host}: this launch declares no hosts")
                } else {
                    format!("--host {host}: no such host (known: {known})")
                };
                return Err(LaunchError { file: self.sources[0].name.clone(), line: None, message });
            };
            zenoh.mode = section.mode.unwrap_or(zenoh.mode);
            zenoh.listen = section.listen.clone().unwrap_or(zenoh.listen);
            zenoh.connect = section.connect.clone().unwrap_or(zenoh.connect);
            if let Some(own) = &section.tls {
                zenoh.tls = Some(own.over(zenoh.tls.take()).ok_or_else(|| LaunchError {
                    file: self.sources[0].name.clone(),
                    line: None,
                    message: format!("hosts.{host}.tls: ca: no certificate authority here nor in [zenoh.tls]"),
                })?);
            }
        }
        self.resolve_files(&mut zenoh);
        let runs_here = |item_host: &Option<String>| host.is_none() || item_host.as_deref() == host;
        let plan = |a: &AxisSection| a.plan().map_err(|p| self.error(p));
        let spec = |c: &CalcSection| c.spec().map_err(|p| self.error(p));
        let controller = |c: &ControllerSection| {
            let mut axes = Vec::new();
            for axis in self.file.axes.iter().filter(|a| a.controller.as_ref() == Some(&c.name)) {
                let fields = plan(axis)?.fields;
                if let Some(channel) = axis.channel {
                    axes.push((channel, RecordUnits { egu: fields.egu, mres: fields.mres }));
                }
            }
            c.spec(axes).map_err(|p| self.error(p))
        };
        let contents = NodeContents {
            plans: self.file.axes.iter().filter(|a| runs_here(&a.host)).map(plan).collect::<Result<_, _>>()?,
            calcs: self.file.calcs.iter().filter(|c| runs_here(&c.host)).map(spec).collect::<Result<_, _>>()?,
            values: self
                .file
                .values
                .iter()
                .filter(|v| runs_here(&v.host))
                .map(|v| ValueSpec { key: v.key(), initial: v.value })
                .collect(),
            controllers: self
                .file
                .controllers
                .iter()
                .filter(|c| runs_here(&c.host))
                .map(controller)
                .collect::<Result<_, _>>()?,
            guarded: zenoh.guarded(),
        };
        Ok(Deployment {
            zenoh,
            contents,
            state_dir: self.file.state_dir.as_ref().map(|dir| self.base.join(dir)),
            autosave: self.file.autosave.clone().unwrap_or_default(),
            channel_access: self.file.channel_access.as_ref().filter(|ca| runs_here(&ca.host)).map(|ca| CaConfig {
                pv_prefix: ca.pv_prefix.clone(),
                address: ca.address,
                port: ca.port,
            }),
            web: self
                .file
                .web
                .as_ref()
                .filter(|w| runs_here(&w.host))
                .map(|w| WebConfig { address: w.address, names: w.names.clone() }),
            ros2: match self.file.ros2.as_ref().filter(|r| runs_here(&r.host)) {
                Some(ros2) => Some(
                    ros2.config()
                        .map_err(|(key, message)| self.error(Problem::at(0, keys_path(&["ros2", key]), message)))?,
                ),
                None => None,
            },
        })
    }

    /// The files `[zenoh]` names (certificates, keys, users), relative to the launch file.
    fn resolve_files(&self, zenoh: &mut ZenohConfig) {
        let resolve = |file: &mut String| *file = self.base.join(&*file).display().to_string();
        if let Some(tls) = &mut zenoh.tls {
            resolve(&mut tls.ca);
            tls.certificate.iter_mut().chain(tls.key.iter_mut()).for_each(resolve);
        }
        if let Some(users) = zenoh.login.as_mut().and_then(|l| l.users_file.as_mut()) {
            resolve(users);
        }
    }

    /// The launch as one TOML file (includes merged).
    pub fn to_toml(&self) -> String {
        toml::to_string(&self.file).expect("a checked launch serialises")
    }
}
