//! Controller command primitives (INIT, PREM, POST) and their device directives. A directive
//! is `@...@`; `@PUT(key, value, delay)@` (PREM) and `@PUT(key, value)@` (POST) become Zenoh
//! puts of `value` to `key` (a key in place of the EPICS PV name), `@DPM_ON@` (INIT) is
//! accepted and has no effect here. What remains, trimmed, goes to the driver as raw text.

use std::time::Duration;

/// One `PUT` directive.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DirectivePut {
    /// The key written to.
    pub key: String,
    /// The value written, as text.
    pub value: String,
    /// How long to wait after the put before the motion starts (PREM only).
    pub delay: Duration,
}

/// A parsed primitive string.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Primitive {
    /// The `@PUT(...)@` directives, in order.
    pub puts: Vec<DirectivePut>,
    /// The controller command, if any text remains.
    pub text: Option<String>,
}

impl Primitive {
    /// The longest PUT delay.
    pub(crate) fn delay(&self) -> Duration {
        self.puts.iter().map(|p| p.delay).max().unwrap_or_default()
    }
}

/// Parse INIT/PREM/POST text. Anything between `@`s that is not a valid directive stays in the
/// text, as the manual says only valid directives are stripped.
pub(crate) fn parse(source: &str) -> Primitive {
    let mut primitive = Primitive::default();
    let mut text = String::new();
    let mut rest = source;
    while let Some(start) = rest.find('@') {
        let Some(len) = rest[start + 1..].find('@') else {
            break;
        };
        let body = &rest[start + 1..start + 1 + len];
        text.push_str(&rest[..start]);
        match directive(body) {
            Some(Some(put)) => primitive.puts.push(put),
            Some(None) => {}
            None => text.push_str(&rest[start..start + len + 2]),
        }
        rest = &rest[start + len + 2..];
    }
    text.push_str(rest);
    let text = text.trim();
    primitive.text = (!text.is_empty()).then(|| text.to_string());
    primitive
}

/// Some(Some(put)) for a PUT, Some(None) for a directive without effect, None if invalid.
fn directive(body: &str) -> Option<Option<DirectivePut>> {
    let body = body.trim();
    if body.eq_ignore_ascii_case("DPM_ON") {
        return Some(None);
    }
    let args = body.strip_prefix("PUT(").or_else(|| body.strip_prefix("put("))?.strip_suffix(')')?;
    let parts: Vec<&str> = args.split(',').map(str::trim).collect();
    let (key, value, delay) = match parts.as_slice() {
        [key, value] => (*key, *value, Duration::ZERO),
        [key, value, delay] => (*key, *value, Duration::try_from_secs_f64(delay.parse::<f64>().ok()?).ok()?),
        _ => return None,
    };
    (!key.is_empty()).then(|| Some(DirectivePut { key: key.to_string(), value: value.to_string(), delay }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directives_become_puts_and_the_rest_goes_to_the_driver() {
        let p = parse("@PUT(lab/shutter/VAL, 1, 0.5)@ MO");
        assert_eq!(
            p.puts,
            vec![DirectivePut { key: "lab/shutter/VAL".into(), value: "1".into(), delay: Duration::from_millis(500) }]
        );
        assert_eq!(p.text.as_deref(), Some("MO"));
        assert_eq!(p.delay(), Duration::from_millis(500));
        let p = parse("@PUT(lab/shutter/VAL, 0)@");
        assert_eq!((p.puts.len(), p.puts[0].delay, p.text), (1, Duration::ZERO, None));
        assert_eq!(parse("@DPM_ON@HE"), Primitive { puts: vec![], text: Some("HE".into()) });
        assert_eq!(parse("").text, None);
    }

    #[test]
    fn invalid_directives_stay_in_the_text() {
        assert_eq!(parse("@NOPE@ AB").text.as_deref(), Some("@NOPE@ AB"));
        assert_eq!(parse("@PUT(k, 1, soon)@").puts, vec![]);
        assert_eq!(parse("odd @ sign").text.as_deref(), Some("odd @ sign"));
    }
}
