//! Units an axis's EGU may name: the lengths and angles a controller's scale or a ROS joint's
//! SI units are compared with (EGU itself stays free text).

/// A unit of length or angle an EGU may name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Unit {
    /// Its usual spelling.
    pub name: &'static str,
    /// Length or angle.
    pub dimension: Dimension,
    /// Its size in the dimension's base unit (metres, degrees).
    size: f64,
}

/// What a unit measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dimension {
    /// Metres and their parts.
    Length,
    /// Degrees, radians and their parts.
    Angle,
}

/// The units an EGU is recognised as, by every spelling taken (in any case).
const UNITS: &[(&[&str], Unit)] = &[
    (&["m", "metre", "meter"], unit("m", Dimension::Length, 1.0)),
    (&["mm", "millimetre", "millimeter"], unit("mm", Dimension::Length, 1e-3)),
    (&["um", "µm", "μm", "micron", "microns", "micrometre", "micrometer"], unit("µm", Dimension::Length, 1e-6)),
    (&["nm", "nanometre", "nanometer"], unit("nm", Dimension::Length, 1e-9)),
    (&["pm", "picometre", "picometer"], unit("pm", Dimension::Length, 1e-12)),
    (&["deg", "degree", "degrees", "°"], unit("deg", Dimension::Angle, 1.0)),
    (&["mdeg", "millidegree", "millidegrees"], unit("mdeg", Dimension::Angle, 1e-3)),
    (&["udeg", "µdeg", "μdeg", "microdegree", "microdegrees"], unit("µdeg", Dimension::Angle, 1e-6)),
    (&["ndeg", "n°", "nanodegree", "nanodegrees"], unit("ndeg", Dimension::Angle, 1e-9)),
    (&["rad", "radian", "radians"], unit("rad", Dimension::Angle, 180.0 / std::f64::consts::PI)),
    (&["mrad", "milliradian", "milliradians"], unit("mrad", Dimension::Angle, 0.18 / std::f64::consts::PI)),
    (
        &["urad", "µrad", "μrad", "microradian", "microradians"],
        unit("µrad", Dimension::Angle, 1.8e-4 / std::f64::consts::PI),
    ),
];

const fn unit(name: &'static str, dimension: Dimension, size: f64) -> Unit {
    Unit { name, dimension, size }
}

impl Unit {
    /// Its size in the dimension's base unit (metres, degrees).
    pub fn size(self) -> f64 {
        self.size
    }

    /// Its size in SI (metres, radians), as ROS counts positions.
    pub fn si(self) -> f64 {
        match self.dimension {
            Dimension::Length => self.size,
            Dimension::Angle => self.size.to_radians(),
        }
    }

    /// The unit an EGU names, if it is one of length or angle zmotor knows.
    pub fn parse(egu: &str) -> Option<Unit> {
        let egu = egu.trim();
        UNITS.iter().find(|(names, _)| names.iter().any(|n| n.eq_ignore_ascii_case(egu))).map(|(_, unit)| *unit)
    }

    /// Millimetres, the unit of PI's and Newport's linear stages.
    pub const MM: Unit = unit("mm", Dimension::Length, 1e-3);
    /// Degrees, the unit of PI's and Newport's rotary stages.
    pub const DEG: Unit = unit("deg", Dimension::Angle, 1.0);
    /// Picometres, SmarAct's linear unit.
    pub const PM: Unit = unit("pm", Dimension::Length, 1e-12);
    /// Nanodegrees, SmarAct's rotary unit.
    pub const NDEG: Unit = unit("ndeg", Dimension::Angle, 1e-9);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn egus_are_read_in_any_spelling_and_converted_to_si() {
        assert_eq!(Unit::parse("MM"), Some(Unit::MM));
        assert_eq!(Unit::parse(" µm ").map(Unit::si), Some(1e-6));
        assert!((Unit::parse("deg").unwrap().si() - std::f64::consts::PI / 180.0).abs() < 1e-15);
        assert!((Unit::parse("mrad").unwrap().si() - 1e-3).abs() < 1e-15);
        assert_eq!(Unit::parse("steps"), None);
    }
}
