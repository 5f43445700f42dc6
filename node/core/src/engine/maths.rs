//! Unit conversions of §4: positions, speeds and accelerations in device (raw) units.

use zmotor_msgs::menus::choice;
use zmotor_msgs::Fields;

/// C-style NINT: round half away from zero, stored as a 32-bit LONG.
pub fn nint(x: f64) -> i32 {
    x.round() as i32
}

/// A raw position (steps) as the driver holds it: NINT in 32 bits, or None when `x` is not a
/// number or beyond (never clamped: a clamped target drives the carriage somewhere unasked).
pub(super) fn raw_position(x: f64) -> Option<i32> {
    let rounded = x.round();
    (rounded.abs() <= f64::from(i32::MAX)).then_some(rounded as i32)
}

/// Everything a move, jog or home needs in raw units, computed from the current fields.
#[derive(Clone, Copy, Debug)]
pub(super) struct MoveMaths {
    pub rbvpos: f64,
    /// The previous target (LDVL), not the readback: absolute maths start from it.
    pub currpos: f64,
    pub newpos: f64,
    pub vbase: f64,
    pub vel: f64,
    pub acc: f64,
    pub bpos: f64,
    pub bvel: f64,
    pub bacc: f64,
    pub hvel: f64,
    pub hacc: f64,
    pub jacc: f64,
    pub relpos: f64,
    pub relbpos: f64,
    /// Backlash distance in steps, plus one.
    pub rbdst1: f64,
    /// Retry deadband in steps.
    pub rdbdpos: i32,
}

impl MoveMaths {
    pub(super) fn new(f: &Fields) -> Self {
        let m = f.mres.abs();
        let vbase = f.vbas / m;
        let vel = f.velo / m;
        let bvel = f.bvel / m;
        let hvel = f.hvel / m;
        let acc_egu = if f.accu == choice::ACCU_USE_ACCS {
            f.accs
        } else if f.velo.abs() > f.vbas {
            (f.velo.abs() - f.vbas) / f.accl
        } else {
            f.velo.abs() / f.accl
        };
        let above_base = |v: f64, time: f64| {
            if v - vbase > 0.0 {
                (v - vbase) / time
            } else {
                v / time
            }
        };
        Self {
            rbvpos: f.drbv / f.mres,
            currpos: f.ldvl / f.mres,
            newpos: f.dval / f.mres,
            vbase,
            vel,
            acc: acc_egu / m,
            bpos: (f.dval - f.bdst) / f.mres,
            bvel,
            bacc: above_base(bvel, f.bacc),
            hvel,
            hacc: above_base(hvel, f.accl),
            jacc: f.jar / m,
            relpos: f.diff / f.mres,
            relbpos: ((f.dval - f.bdst) - f.drbv) / f.mres,
            rbdst1: 1.0 + f.bdst.abs() / m,
            rdbdpos: nint(f.rdbd / m),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nint_rounds_half_away_from_zero() {
        assert_eq!((nint(2.5), nint(-2.5), nint(2.4999), nint(-0.4)), (3, -3, 2, 0));
        assert_eq!((raw_position(-2.5), raw_position(f64::from(i32::MAX))), (Some(-3), Some(i32::MAX)));
        assert_eq!(
            (raw_position(2f64.powi(31)), raw_position(f64::NAN), raw_position(f64::INFINITY)),
            (None, None, None)
        );
    }
}
