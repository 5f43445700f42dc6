//! Autosave and restore, as EPICS autosave does for motor records: each axis's position (DVAL,
//! OFF) and settings are kept in one small TOML file per axis, written atomically (a temporary
//! file, fsync, rename, fsync of the directory), so a node killed at any instant leaves either
//! the previous file or the new one. At boot the saved values are laid over the launch file's
//! before the record initialises; RSTM then decides whether the saved DVAL is loaded into the
//! driver (`MotorRecord::restore_commands`).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;
use zmotor_core::{AxisPlan, Unusable};
use zmotor_msgs::{field_value, to_toml};
use zmotor_msgs::{Autosave, CodecError, Field, Fields};

/// The environment variable that overrides the launch file's `state_dir`.
pub const STATE_DIR_ENV: &str = "ZMOTOR_STATE_DIR";

/// Why state could not be found, read or restored.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AutosaveError {
    /// Neither the environment nor the launch file names a state directory, and there is no home.
    #[error("no state directory: set state_dir in the launch file or {STATE_DIR_ENV}")]
    NoStateDir,
    /// The state directory cannot be created.
    #[error("state directory {}: {source}", path.display())]
    Directory {
        /// The directory.
        path: PathBuf,
        /// What the file system said.
        source: std::io::Error,
    },
    /// A state file cannot be read.
    #[error("{}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the file system said.
        source: std::io::Error,
    },
    /// A state file is not valid TOML of the expected shape.
    #[error("{}: {source}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the TOML reader said.
        source: toml::de::Error,
    },
    /// An entry of a state file cannot be restored (edited by hand, another version).
    #[error("{}: {source}", path.display())]
    Restore {
        /// The file.
        path: PathBuf,
        /// The entry at fault.
        source: RestoreError,
    },
}

/// An entry of a saved state that cannot be laid over the fields.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RestoreError {
    /// The name is not a field autosave keeps.
    #[error("{0}: not a field autosave keeps")]
    NotKept(String),
    /// The value is not valid for its field.
    #[error(transparent)]
    Value(#[from] CodecError),
    /// A value the record refuses whatever its state (a resolution of 0).
    #[error("{field}: {reason}")]
    Unusable {
        /// The field.
        field: Field,
        /// Why.
        reason: Unusable,
    },
    /// No position: autosave always keeps one, so the file was emptied or cut short.
    #[error("no position (DVAL): the file was emptied or cut short")]
    NoPosition,
    /// A position whose raw steps (DVAL / MRES) do not fit the record's 32 bits.
    #[error("DVAL {dval} is {steps:e} steps at MRES {mres}, beyond the raw 32-bit range")]
    BeyondRawRange {
        /// The saved dial position.
        dval: f64,
        /// The resolution it would have.
        mres: f64,
        /// The raw position.
        steps: f64,
    },
}

/// Where state is kept: `ZMOTOR_STATE_DIR`, else the launch file's `state_dir`, else the
/// per-user state directory (`$XDG_STATE_HOME/zmotor`, `~/.local/state/zmotor`). Never the
/// current directory by surprise.
pub fn state_dir(configured: Option<&Path>) -> Result<PathBuf, AutosaveError> {
    let env = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(dir) = env(STATE_DIR_ENV) {
        return Ok(dir);
    }
    if let Some(dir) = configured {
        return Ok(dir.to_path_buf());
    }
    if let Some(state_home) = env("XDG_STATE_HOME").filter(|d| d.is_absolute()) {
        return Ok(state_home.join("zmotor"));
    }
    env("HOME").map(|home| home.join(".local/state/zmotor")).ok_or(AutosaveError::NoStateDir)
}

/// The saved fields of one axis, by EPICS name.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedAxis {
    /// DVAL and OFF.
    #[serde(default)]
    pub position: BTreeMap<String, toml::Value>,
    /// Every setting a user configures.
    #[serde(default)]
    pub settings: BTreeMap<String, toml::Value>,
}

impl SavedAxis {
    /// What autosave keeps of these fields.
    pub fn of(fields: &Fields) -> Self {
        let mut saved = Self::default();
        for field in Field::all() {
            let section = match field.autosave() {
                Some(Autosave::Position) => &mut saved.position,
                Some(Autosave::Setting) => &mut saved.settings,
                None => continue,
            };
            section.insert(field.name().to_string(), to_toml(fields.get(field)));
        }
        saved
    }

    /// Lay the saved values over `fields`; an entry that cannot be restored (the file was
    /// edited by hand or comes from another version) is named, and nothing is changed then.
    pub fn restore_into(&self, fields: &mut Fields) -> Result<(), RestoreError> {
        let mut restored = fields.clone();
        if !self.position.contains_key(Field::DVAL.name()) {
            return Err(RestoreError::NoPosition);
        }
        for (name, raw) in self.position.iter().chain(&self.settings) {
            let field = Field::from_name(name)
                .filter(|f| f.autosave().is_some())
                .ok_or_else(|| RestoreError::NotKept(name.clone()))?;
            let value = field_value(field, raw)?;
            if let Some(reason) = Unusable::of(field, &value) {
                return Err(RestoreError::Unusable { field, reason });
            }
            restored.set(field, &value);
        }
        let steps = (restored.dval / restored.mres).round();
        if !(f64::from(i32::MIN)..=f64::from(i32::MAX)).contains(&steps) {
            return Err(RestoreError::BeyondRawRange { dval: restored.dval, mres: restored.mres, steps });
        }
        // The saved dial limits win over raw limits given in the launch file (the boot
        // reconciliation otherwise prefers non-zero raw limits).
        if self.settings.contains_key("DHLM") || self.settings.contains_key("DLLM") {
            restored.rhlm = 0.0;
            restored.rllm = 0.0;
        }
        *fields = restored;
        Ok(())
    }
}

/// One directory of per-axis state files: `<state_dir>/<prefix>/<axis>.toml`.
#[derive(Clone, Debug)]
pub struct StateStore {
    dir: PathBuf,
}

impl StateStore {
    /// The store of one key prefix under `state_dir`, created if missing.
    pub fn open(state_dir: &Path, prefix: &str) -> Result<Self, AutosaveError> {
        let dir = state_dir.join(prefix);
        std::fs::create_dir_all(&dir).map_err(|source| AutosaveError::Directory { path: dir.clone(), source })?;
        Ok(Self { dir })
    }

    /// Where the files are.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The state file of an axis.
    pub fn path(&self, axis: &str) -> PathBuf {
        self.dir.join(format!("{axis}.toml"))
    }

    /// The saved state of an axis; None when nothing was saved yet.
    pub fn load(&self, axis: &str) -> Result<Option<SavedAxis>, AutosaveError> {
        let path = self.path(axis);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(AutosaveError::Read { path, source }),
        };
        toml::from_str(&text).map(Some).map_err(|source| AutosaveError::Parse { path, source })
    }

    /// Lay an axis's saved state, if any, over `fields`.
    pub fn restore(&self, axis: &str, fields: &mut Fields) -> Result<Option<SavedAxis>, AutosaveError> {
        let saved = self.load(axis)?;
        if let Some(saved) = &saved {
            saved.restore_into(fields).map_err(|source| AutosaveError::Restore { path: self.path(axis), source })?;
        }
        Ok(saved)
    }

    /// Write an axis's state atomically and durably.
    pub fn save(&self, axis: &str, saved: &SavedAxis) -> std::io::Result<()> {
        let text = toml::to_string(saved).map_err(std::io::Error::other)?;
        let path = self.path(axis);
        let temporary = self.dir.join(format!(".{axis}.toml.tmp"));
        let mut file = std::fs::File::create(&temporary)?;
        writeln!(file, "# zmotor autosave of axis '{axis}': written by the node; edit only while it is stopped.")?;
        file.write_all(text.as_bytes())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&temporary, &path)?;
        // The rename itself must reach the disk before the save counts as done.
        std::fs::File::open(&self.dir)?.sync_all()
    }
}

/// Autosave of a node's axes: where state is kept, and how long a change may wait before it
/// is written (changes within that time are written together).
#[derive(Clone, Debug)]
pub struct AutosaveConfig {
    /// The state files.
    pub store: StateStore,
    /// How long a change waits before it is written.
    pub delay: Duration,
}

/// The autosave of one axis: a change arms a deadline `delay` ahead; at the deadline the
/// saved fields are written if they differ from what the file holds. Writes run off the
/// runtime's threads; the axis waits for each (a few milliseconds, at most once per `delay`).
pub(crate) struct Saver {
    store: StateStore,
    delay: Duration,
    /// What the file holds.
    written: SavedAxis,
    due: Option<tokio::time::Instant>,
}

impl Saver {
    /// Lay the saved state over the plan's fields, and be ready to save the axis.
    pub(crate) fn restore(config: &AutosaveConfig, plan: &mut AxisPlan) -> Result<Self, AutosaveError> {
        let saved = config.store.restore(&plan.name, &mut plan.fields)?;
        if saved.is_some() {
            tracing::info!(axis = %plan.name, file = %config.store.path(&plan.name).display(), "restored saved state");
        }
        Ok(Self { store: config.store.clone(), delay: config.delay, written: saved.unwrap_or_default(), due: None })
    }

    /// When the next write is due, if a change waits.
    pub(crate) fn due(&self) -> Option<tokio::time::Instant> {
        self.due
    }

    pub(crate) fn changed(&mut self, now: tokio::time::Instant) {
        self.due.get_or_insert(now + self.delay);
    }

    /// Write `saved` now if it differs from the file, and wait until it is written.
    pub(crate) async fn flush(&mut self, axis: &str, saved: SavedAxis) {
        self.due = None;
        if saved == self.written {
            return;
        }
        self.written = saved.clone();
        let (store, axis) = (self.store.clone(), axis.to_string());
        let write = tokio::task::spawn_blocking(move || {
            if let Err(e) = store.save(&axis, &saved) {
                tracing::error!(axis, file = %store.path(&axis).display(), "autosave failed: {e}");
            }
        });
        let _ = write.await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn configured() -> Fields {
        Fields {
            dval: 12.5,
            off: -1.0,
            velo: 3.0,
            mres: 0.001,
            urev: 0.2,
            egu: "mm".into(),
            rstm: 1,
            homf: 1,
            ..Fields::default()
        }
    }

    #[test]
    fn positions_and_settings_survive_a_round_trip_through_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let store = StateStore::open(dir.path(), "motor").unwrap();
        assert!(store.load("m1").unwrap().is_none());
        store.save("m1", &SavedAxis::of(&configured())).unwrap();
        let mut restored = Fields::default();
        store.restore("m1", &mut restored).unwrap().unwrap();
        assert_eq!((restored.dval, restored.off, restored.velo), (12.5, -1.0, 3.0));
        assert_eq!((restored.egu.as_str(), restored.rstm), ("mm", 1));
        assert_eq!(restored.homf, 0, "a command is never saved, so a restart moves nothing");
        let leftovers: Vec<_> = std::fs::read_dir(store.dir()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(leftovers, vec![std::ffi::OsString::from("m1.toml")], "no temporary file is left behind");
    }

    #[test]
    fn a_hand_edited_file_with_a_bad_entry_changes_nothing() {
        let mut saved = SavedAxis::of(&configured());
        saved.settings.insert("DIR".into(), toml::Value::String("Sideways".into()));
        let mut fields = Fields::default();
        assert!(saved.restore_into(&mut fields).unwrap_err().to_string().contains("'Sideways' is not a choice"));
        assert_eq!(fields, Fields::default());
        saved.settings.remove("DIR");
        saved.settings.insert("RBV".into(), toml::Value::Float(1.0));
        assert_eq!(saved.restore_into(&mut fields).unwrap_err(), RestoreError::NotKept("RBV".into()));
        assert_eq!(saved.restore_into(&mut fields).unwrap_err().to_string(), "RBV: not a field autosave keeps");
    }

    #[test]
    fn a_file_emptied_or_holding_values_the_record_refuses_changes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let store = StateStore::open(dir.path(), "motor").unwrap();
        std::fs::write(store.path("m1"), "").unwrap();
        let mut fields = Fields { dval: 3.0, ..Fields::default() };
        let error = store.restore("m1", &mut fields).unwrap_err().to_string();
        assert!(error.contains("m1.toml") && error.contains("no position (DVAL)"), "{error}");
        let refused = |field: &str, value: toml::Value| {
            let mut saved = SavedAxis::of(&configured());
            saved.position.insert(field.into(), value.clone());
            saved.settings.insert(field.into(), value);
            saved.position.retain(|name, _| Field::from_name(name).unwrap().autosave() == Some(Autosave::Position));
            saved.settings.retain(|name, _| Field::from_name(name).unwrap().autosave() == Some(Autosave::Setting));
            let mut fields = Fields::default();
            let error = saved.restore_into(&mut fields).unwrap_err();
            assert_eq!(fields, Fields::default(), "{field}: nothing changed");
            error
        };
        assert!(matches!(refused("MRES", toml::Value::Float(0.0)), RestoreError::Unusable { field: Field::MRES, .. }));
        assert!(matches!(refused("DVAL", toml::Value::Float(1e12)), RestoreError::BeyondRawRange { .. }));
        assert_eq!(fields.dval, 3.0);
    }

    #[test]
    fn saved_dial_limits_win_over_raw_limits_of_the_launch_file() {
        let saved = SavedAxis::of(&Fields { dhlm: 7.0, mres: 0.001, urev: 0.2, ..Fields::default() });
        let mut fields = Fields { rhlm: 500.0, ..Fields::default() };
        saved.restore_into(&mut fields).unwrap();
        assert_eq!((fields.dhlm, fields.rhlm), (7.0, 0.0));
    }

    #[test]
    fn the_environment_overrides_the_launch_file() {
        // One test owns the variable: tests in this binary run in parallel.
        std::env::set_var(STATE_DIR_ENV, "/from/env");
        assert_eq!(state_dir(Some(Path::new("/from/file"))).unwrap(), PathBuf::from("/from/env"));
        std::env::remove_var(STATE_DIR_ENV);
        assert_eq!(state_dir(Some(Path::new("/from/file"))).unwrap(), PathBuf::from("/from/file"));
        let default = state_dir(None).unwrap();
        assert!(default.ends_with("zmotor") && default.is_absolute(), "{default:?}");
    }
}
