//! Values as caget and camonitor show them: a menu field by its choice's name, a double at the
//! precision the record gives its clients (the axis's PREC), or, where PREC is 0 or not known,
//! in its shortest exact form.

use zmotor_msgs::{Field, Kind, Value};

/// `value` of `field` as text, on an axis whose PREC is `prec` (None when it is not known).
pub fn show(field: Field, value: &Value, prec: Option<i16>) -> String {
    match (field.def().kind, value) {
        (Kind::Menu(menu), Value::Int(index)) => usize::try_from(*index)
            .ok()
            .and_then(|i| menu.choices.get(i))
            .map_or_else(|| index.to_string(), |choice| (*choice).to_string()),
        (_, Value::Float(x)) => match prec.map(|prec| field.precision(prec)) {
            Some(decimals) if decimals > 0 && x.is_finite() => format!("{x:.*}", decimals as usize),
            _ => x.to_string(),
        },
        _ => value.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn menus_show_their_choice_and_doubles_their_precision() {
        assert_eq!(show(Field::SPMG, &Value::Int(1), None), "Pause");
        assert_eq!(show(Field::SPMG, &Value::Int(9), None), "9", "an index no choice has stays a number");
        assert_eq!(show(Field::RBV, &Value::Float(6.991_000_000_000_000_5), Some(3)), "6.991");
        assert_eq!(show(Field::RBV, &Value::Float(10.0), Some(3)), "10.000");
        assert_eq!(show(Field::VERS, &Value::Float(1.0), Some(5)), "1.00", "VERS has two decimals");
        assert_eq!(show(Field::RBV, &Value::Float(0.25), None), "0.25", "shortest exact form");
        assert_eq!(show(Field::RBV, &Value::Float(0.25), Some(0)), "0.25");
        assert_eq!(show(Field::RBV, &Value::Float(f64::NAN), Some(3)), "NaN");
        assert_eq!(show(Field::RRBV, &Value::Int(-12), Some(3)), "-12");
        assert_eq!(show(Field::DESC, &Value::Text("slit".into()), Some(3)), "slit");
    }
}
