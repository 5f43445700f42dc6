//! The axes of a node by name, and the key spaces that name them: the fields under the prefix,
//! and the simulator's keys.

use crate::input::Deliver;
use std::collections::HashMap;
use std::sync::Arc;
use zenoh::key_expr::KeyExpr;
use zmotor_msgs::{keys, KeyLayout};

/// The node's axes, by name.
pub(crate) type Routes = HashMap<String, Arc<dyn Deliver>>;

/// The keys a router serves: the axes' fields under a prefix, or the simulator's.
#[derive(Clone)]
pub(crate) enum Space {
    Fields(KeyLayout),
    Sim,
}

impl Space {
    /// The axis chunk of a key in this space.
    pub(crate) fn axis_chunk<'k>(&self, key: &'k str) -> Option<&'k str> {
        match self {
            Space::Fields(layout) => layout.axis_chunk(key),
            Space::Sim => keys::sim_axis_chunk(key),
        }
    }

    /// Every key of one axis in this space.
    pub(crate) fn everything_of(&self, axis: &str) -> String {
        match self {
            Space::Fields(layout) => layout.axis_all(axis),
            Space::Sim => keys::sim_key(axis, "**"),
        }
    }

    /// The axes of ours a key expression covers, any of their keys.
    pub(crate) fn covered<'r>(
        &'r self,
        routes: &'r Routes,
        key: &'r KeyExpr<'_>,
    ) -> impl Iterator<Item = &'r Arc<dyn Deliver>> + 'r {
        routes.iter().filter_map(move |(axis, handle)| {
            KeyExpr::try_from(self.everything_of(axis)).is_ok_and(|all| key.intersects(&all)).then_some(handle)
        })
    }

    /// The axis of ours a key names, and the name of the field or setting it names.
    pub(crate) fn target<'r>(&self, routes: &'r Routes, key: &str) -> Option<(&'r Arc<dyn Deliver>, String)> {
        let axis = self.axis_chunk(key)?;
        let handle = routes.get(axis)?;
        let name = match self {
            Space::Fields(layout) => layout.field_name(axis, key)?,
            Space::Sim => key.rsplit('/').next()?,
        };
        Some((handle, name.to_string()))
    }
}
