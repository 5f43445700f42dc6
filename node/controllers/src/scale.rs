//! How a channel's record steps map onto the controller's units, and whether the record's MRES
//! and EGU agree with it. A controller counts in its own unit (PI and Newport stages in mm or
//! deg, SmarAct's in pm or n°); the protocol knows, or reads, how many of them one record step
//! is. A record whose MRES says otherwise would move every target by the ratio of the two,
//! silently: the controller layer compares them when the link comes up and refuses motion on a
//! channel where they disagree.

use zmotor_msgs::{Dimension, Unit};

/// The unit a controller counts a channel in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ControllerUnit {
    /// The stage's physical unit: `linear` on a linear stage, `rotary` on a rotary one (the
    /// axis's EGU tells which the stage is).
    Physical {
        /// A linear stage's unit.
        linear: Unit,
        /// A rotary stage's unit.
        rotary: Unit,
    },
    /// The unit the controller says it counts the channel in (an ESP300's `SN?`).
    Known(Unit),
    /// Motor steps, or whatever unit the controller was configured in: nothing to compare an
    /// EGU with.
    Steps,
}

/// Where a scale comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScaleSource {
    /// Read from the controller at connection, by these queries.
    Controller(&'static str),
    /// The launch file's `units_per_step`.
    Installation,
    /// The protocol's default, nothing given.
    ProtocolDefault,
}

impl std::fmt::Display for ScaleSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ScaleSource::Controller(queries) => write!(f, "read from the controller: {queries}"),
            ScaleSource::Installation => f.write_str("the launch file's units_per_step"),
            ScaleSource::ProtocolDefault => f.write_str("the protocol's default; units_per_step sets it"),
        }
    }
}

/// How many of the controller's units one record step of a channel is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    /// The controller's units in one record step.
    pub units_per_step: f64,
    /// The controller's unit.
    pub unit: ControllerUnit,
    /// Where `units_per_step` comes from.
    pub source: ScaleSource,
}

impl Scale {
    /// One motor step a record step: a controller counting steps, nothing to scale or compare.
    pub fn motor_steps() -> Self {
        Scale { units_per_step: 1.0, unit: ControllerUnit::Steps, source: ScaleSource::ProtocolDefault }
    }
}

/// An axis's own idea of its step: its EGU and MRES, as the deployment configures them.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordUnits {
    /// The record's engineering units.
    pub egu: String,
    /// The record's motor resolution (EGU per step).
    pub mres: f64,
}

/// What comparing a record's units with its controller's scale found.
#[derive(Clone, Debug, PartialEq)]
pub enum ScaleCheck {
    /// They agree.
    Agrees,
    /// They cannot be compared (an EGU of no known unit, a controller counting steps), and why.
    Unchecked(&'static str),
    /// They disagree.
    Disagrees(ScaleMismatch),
}

/// A record step that is not the controller's.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error(
    "MRES {mres} {egu} per step disagrees with the controller's step of {units_per_step} {unit} ({origin}): \
     every position would be off by a factor of {ratio:.3}; set MRES to {expected_mres} {egu} \
     (or units_per_step to match MRES)"
)]
pub struct ScaleMismatch {
    /// The record's MRES.
    pub mres: f64,
    /// The record's EGU.
    pub egu: String,
    /// The controller's step, in its unit.
    pub units_per_step: f64,
    /// The controller's unit.
    pub unit: &'static str,
    /// Where the controller's step comes from.
    pub origin: ScaleSource,
    /// MRES over the controller's step (in one unit).
    pub ratio: f64,
    /// The MRES that agrees.
    pub expected_mres: f64,
}

/// Two steps agree to this fraction.
const AGREEMENT: f64 = 1e-6;

impl Scale {
    /// Whether `record` (EGU and MRES) agrees with this scale.
    #[must_use]
    pub fn check(&self, record: &RecordUnits) -> ScaleCheck {
        let Some(egu) = Unit::parse(&record.egu) else {
            return ScaleCheck::Unchecked("the EGU is no unit of length or angle zmotor knows");
        };
        let controller = match self.unit {
            ControllerUnit::Physical { linear, .. } if egu.dimension == Dimension::Length => linear,
            ControllerUnit::Physical { rotary, .. } => rotary,
            ControllerUnit::Known(unit) if unit.dimension == egu.dimension => unit,
            ControllerUnit::Known(_) => {
                return ScaleCheck::Unchecked("the EGU and the controller's unit measure different things")
            }
            ControllerUnit::Steps => return ScaleCheck::Unchecked("the controller counts steps"),
        };
        let mres = record.mres.abs();
        if !(mres.is_finite() && mres > 0.0 && self.units_per_step.is_finite() && self.units_per_step > 0.0) {
            return ScaleCheck::Unchecked("MRES or the controller's step is not a positive number");
        }
        let record_step = mres * egu.size() / controller.size();
        let ratio = record_step / self.units_per_step;
        if (ratio - 1.0).abs() <= AGREEMENT {
            return ScaleCheck::Agrees;
        }
        ScaleCheck::Disagrees(ScaleMismatch {
            mres: record.mres,
            egu: record.egu.clone(),
            units_per_step: self.units_per_step,
            unit: controller.name,
            origin: self.source,
            ratio,
            expected_mres: record.mres / ratio,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn physical(units_per_step: f64) -> Scale {
        Scale {
            units_per_step,
            unit: ControllerUnit::Physical { linear: Unit::MM, rotary: Unit::DEG },
            source: ScaleSource::Controller("SPA? 14/15"),
        }
    }

    fn record(egu: &str, mres: f64) -> RecordUnits {
        RecordUnits { egu: egu.into(), mres }
    }

    #[test]
    fn the_same_step_in_any_spelling_of_its_unit_agrees() {
        let scale = physical(0.0001);
        for (egu, mres) in [("mm", 0.0001), ("MM", 0.0001), ("um", 0.1), ("µm", -0.1), ("nm", 100.0)] {
            assert_eq!(scale.check(&record(egu, mres)), ScaleCheck::Agrees, "{egu} {mres}");
        }
        assert_eq!(physical(0.001).check(&record("mdeg", 1.0)), ScaleCheck::Agrees, "a rotary stage in deg");
    }

    #[test]
    fn another_step_is_a_mismatch_naming_the_mres_that_agrees() {
        let ScaleCheck::Disagrees(mismatch) = physical(0.0001).check(&record("mm", 0.001)) else { panic!() };
        assert!((mismatch.ratio - 10.0).abs() < 1e-9 && (mismatch.expected_mres - 0.0001).abs() < 1e-15);
        let words = mismatch.to_string();
        assert!(words.contains("MRES 0.001 mm") && words.contains("SPA? 14/15"), "{words}");
    }

    #[test]
    fn what_cannot_be_compared_is_said_so() {
        assert!(matches!(physical(0.0001).check(&record("steps", 1.0)), ScaleCheck::Unchecked(_)));
        assert!(matches!(physical(0.0001).check(&record("mm", 0.0)), ScaleCheck::Unchecked(_)));
        let steps = Scale::motor_steps();
        assert!(matches!(steps.check(&record("mm", 0.01)), ScaleCheck::Unchecked(_)));
        let mm =
            Scale { units_per_step: 0.0001, unit: ControllerUnit::Known(Unit::MM), source: ScaleSource::Installation };
        assert!(matches!(mm.check(&record("deg", 0.0001)), ScaleCheck::Unchecked(_)), "a linear stage in degrees");
        assert_eq!(mm.check(&record("um", 0.1)), ScaleCheck::Agrees);
    }
}
