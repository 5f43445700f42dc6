//! A problem found while checking a launch, before it is given its file and line.

use crate::file::Origin;
use crate::locate::Seg;

/// A problem found while checking: where (file, path of keys) and what.
#[derive(Debug)]
pub(crate) struct Problem {
    pub(crate) source: usize,
    pub(crate) path: Vec<Seg>,
    pub(crate) message: String,
}

impl Problem {
    pub(crate) fn at(source: usize, path: Vec<Seg>, message: impl Into<String>) -> Self {
        Self { source, path, message: message.into() }
    }

    /// A problem of an item, at a key inside it.
    pub(crate) fn in_item(table: &str, origin: Origin, inner: &[&str], message: impl Into<String>) -> Self {
        let mut path = vec![Seg::Key(table.into()), Seg::Index(origin.index)];
        path.extend(inner.iter().map(|k| Seg::Key((*k).into())));
        Self::at(origin.source, path, message)
    }
}

/// The path of nested keys `keys` (e.g. `autosave.delay`).
pub(crate) fn keys_path(keys: &[&str]) -> Vec<Seg> {
    keys.iter().map(|k| Seg::Key((*k).into())).collect()
}
