//! The benchmark's axes: b0, b1, … under the default prefix.

use zmotor_msgs::{Field, KeyLayout};

/// The name of bench axis `i`.
pub(crate) fn bench_axis(i: usize) -> String {
    format!("b{i}")
}

/// Which bench axis `name` is, if it is one.
pub(crate) fn bench_axis_index(name: &str) -> Option<usize> {
    name.strip_prefix('b')?.parse().ok()
}

/// The key of `field` on bench axis `i`.
pub(crate) fn bench_key(i: usize, field: Field) -> String {
    KeyLayout::default().field(&bench_axis(i), field)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bench_axis_name_gives_its_index_back_and_other_names_none() {
        assert_eq!(bench_axis_index(&bench_axis(42)), Some(42));
        assert_eq!(bench_axis_index("m1"), None);
        assert_eq!(bench_axis_index("b"), None);
    }
}
