//! The benchmark's axes: b0, b1, … under the default prefix.

use zmotor_msgs::{Field, KeyLayout};

/// The name of bench axis `i`.
pub(crate) fn bench_axis(i: usize) -> String {
    format!("b{i}")
}

/// The key of `field` on bench axis `i`.
pub(crate) fn bench_key(i: usize, field: Field) -> String {
    KeyLayout::default().field(&bench_axis(i), field)
}
