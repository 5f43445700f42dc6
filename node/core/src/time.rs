//! Time in the sans-IO core: instants on the caller's clock, passed in with every event. The
//! core never reads a clock; "nothing due" is `None`, never an infinite time.

use std::ops::{Add, Sub};
use std::time::Duration;

/// A point in time, as the time elapsed since the origin of the caller's clock (a node's start,
/// or zero in a virtual-time test).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Instant(Duration);

impl Instant {
    /// The origin of the clock.
    pub const ZERO: Instant = Instant(Duration::ZERO);

    /// The instant `elapsed` after the origin.
    pub const fn after(elapsed: Duration) -> Self {
        Self(elapsed)
    }

    /// The instant `seconds_after_origin` after the origin: negative and NaN give the origin,
    /// anything beyond `Duration::MAX` saturates.
    pub fn from_secs_f64(seconds_after_origin: f64) -> Self {
        Self(seconds(seconds_after_origin))
    }

    /// Time since the origin.
    pub const fn since_origin(self) -> Duration {
        self.0
    }

    /// Seconds since the origin, as the engine and the wire count them.
    pub fn as_secs_f64(self) -> f64 {
        self.0.as_secs_f64()
    }

    /// Time from `earlier` to this instant; zero if `earlier` is later.
    pub fn saturating_duration_since(self, earlier: Instant) -> Duration {
        self.0.saturating_sub(earlier.0)
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;

    fn add(self, rhs: Duration) -> Instant {
        Instant(self.0.saturating_add(rhs))
    }
}

impl Sub<Instant> for Instant {
    type Output = Duration;

    fn sub(self, earlier: Instant) -> Duration {
        self.saturating_duration_since(earlier)
    }
}

/// A duration from a number of seconds as fields hold them (DLY, a PREM delay): negative and
/// NaN give zero, and anything beyond `Duration::MAX` saturates, so no field value can panic.
pub(crate) fn seconds(value: f64) -> Duration {
    if value.is_nan() || value <= 0.0 {
        return Duration::ZERO;
    }
    Duration::try_from_secs_f64(value).unwrap_or(Duration::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_seconds_never_panic() {
        assert_eq!(seconds(-1.0), Duration::ZERO);
        assert_eq!(seconds(f64::NAN), Duration::ZERO);
        assert_eq!(seconds(f64::INFINITY), Duration::MAX);
        assert_eq!(seconds(1e300), Duration::MAX);
        assert_eq!(seconds(0.25), Duration::from_millis(250));
    }

    #[test]
    fn instants_add_and_subtract_without_overflow() {
        let t = Instant::from_secs_f64(1.5);
        assert_eq!(t + Duration::from_millis(500), Instant::from_secs_f64(2.0));
        assert_eq!(t - Instant::from_secs_f64(2.0), Duration::ZERO);
        assert_eq!(Instant::after(Duration::MAX) + Duration::from_secs(1), Instant::after(Duration::MAX));
    }
}
