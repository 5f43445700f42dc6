//! zmotor-node: serves zmotor's sans-IO axes on a Zenoh session. It only moves bytes: samples
//! and queries become inputs of each axis's `AxisService` (zmotor-core), the wall clock becomes
//! ticks, and what the services hand back becomes publications, replies and puts. Each axis
//! takes its inputs, from any thread, one at a time and in order (`zmotor_inbox`). Controllers
//! (zmotor-controllers) run on their TCP sockets or serial ports; calc links (zmotor-bridge)
//! and value holders run beside the axes; autosave keeps each axis's state in a file. What to
//! serve comes from a deployment (`zmotor_deploy::NodeContents`); a node is no client.

mod autosave;
mod axis_core;
mod axis_task;
mod controllers;
mod demand;
mod event_posts;
mod holds;
mod input;
mod links;
mod node;
mod refusal;
mod router;
mod routes;
mod streamed;
mod ticker;
mod tokens;
mod writer;

pub use autosave::{state_dir, AutosaveConfig, AutosaveError, RestoreError, SavedAxis, StateStore, STATE_DIR_ENV};
pub use links::PostsFollowed;
pub use node::{Node, NodeError};

/// A mutex's guard, even after a thread panicked holding it: what it guards stays usable.
fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}
