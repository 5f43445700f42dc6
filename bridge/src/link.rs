//! Calc links: calcout records over keys. Inputs A–L (A–P: a transform record's fields) are
//! bound to keys; a CP input recomputes and may write the output on each update, an NPP input
//! holds the latest value and is read afresh when the link processes, as EPICS reads a link's
//! source then. A key the link is processed by (an EPICS forward link into it: a record that
//! writes there processes it) recomputes on each update after the link has started, not on the
//! value it finds then. The output is written to a key every time, or only when the result
//! changes (OOPT).

use crate::calc::{input_name, CalcError, Expression, TRANSFORM_FIELDS};

/// How many inputs a calc link has: a calcout's A–L, and a transform record's M–P beside them.
const VARIABLES: usize = TRANSFORM_FIELDS;

/// How an input reacts to an update of its key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputMode {
    /// Recompute on each update (EPICS CP).
    Process,
    /// Keep the latest value without recomputing (EPICS NPP).
    NoProcess,
}

/// When the result is written to the output key (calcout OOPT).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputOption {
    /// Write the result on every recomputation (OOPT "Every Time").
    EveryTime,
    /// Write the result only when it differs from the previous one (OOPT "On Change").
    OnChange,
}

/// One input of a calc link: which letter, bound to which key, and how it reacts.
#[derive(Clone, Debug, PartialEq)]
pub struct InputSpec {
    /// 0 for A … 15 for P.
    pub index: usize,
    /// The key whose values feed the input.
    pub key: String,
    /// Whether an update recomputes (CP) or is only held (NPP).
    pub mode: InputMode,
}

/// A calc link as configured.
#[derive(Clone, Debug, PartialEq)]
pub struct CalcLinkSpec {
    /// The link's name, used in messages (the record name for an imported calcout).
    pub name: String,
    /// The calc expression (CALC).
    pub expression: String,
    /// The inputs bound to keys.
    pub inputs: Vec<InputSpec>,
    /// Values of inputs before any update (EPICS fields A–P given in the database), by index.
    pub constants: Vec<(usize, f64)>,
    /// Where the result is written.
    pub output: String,
    /// When the result is written (OOPT).
    pub option: OutputOption,
    /// Keys whose every update processes the link, as a forward link into a record processes it
    /// (a motor's FLNK writes its target's PROC, a value is processed by each write): not
    /// inputs, and not read when the link starts (EPICS processes no record at start for a
    /// forward link). An input on the same key takes the update's value first.
    pub processed_by: Vec<String>,
}

/// Why a calc link's configuration was refused.
#[derive(Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// The expression does not parse.
    #[error("calc '{name}': expression '{expression}': {error}")]
    Expression {
        /// The link's name.
        name: String,
        /// The expression's text.
        expression: String,
        /// Where and why it does not parse.
        error: CalcError,
    },
    /// Two bindings of the same input letter.
    #[error("calc '{name}': input {input} is bound twice")]
    DuplicateInput {
        /// The link's name.
        name: String,
        /// The input's letter (A–P).
        input: char,
    },
}

/// The running state of one calc link.
#[derive(Clone, Debug)]
pub struct CalcLink {
    spec: CalcLinkSpec,
    expression: Expression,
    values: [f64; VARIABLES],
    last_output: Option<f64>,
    /// Its result is its own record's value (read by others), not a write elsewhere.
    own_record: bool,
}

impl CalcLink {
    /// A link from its configuration: the expression parsed, the constants loaded.
    pub fn new(spec: CalcLinkSpec) -> Result<Self, LinkError> {
        let expression = Expression::parse_over(&spec.expression, VARIABLES).map_err(|error| {
            LinkError::Expression { name: spec.name.clone(), expression: spec.expression.clone(), error }
        })?;
        let mut seen = 0u16;
        for input in &spec.inputs {
            if seen & (1 << input.index) != 0 {
                return Err(LinkError::DuplicateInput { name: spec.name.clone(), input: input_name(input.index) });
            }
            seen |= 1 << input.index;
        }
        let mut values = [0.0; VARIABLES];
        for &(index, value) in &spec.constants {
            values[index] = value;
        }
        Ok(Self { spec, expression, values, last_output: None, own_record: false })
    }

    /// The same link, its result its own record's value (a calc record answering reads), not a
    /// write elsewhere: it processes on values found too (`found`).
    #[must_use]
    pub fn serving_its_record(self) -> Self {
        Self { own_record: true, ..self }
    }

    /// The configuration the link was built from.
    pub fn spec(&self) -> &CalcLinkSpec {
        &self.spec
    }

    /// A new value on `key`: the inputs there take it. Whether the link processes now (a CP
    /// input's update): then `process`, with its NPP inputs read afresh.
    #[must_use = "a CP input's update processes the link"]
    pub fn update(&mut self, key: &str, value: f64) -> bool {
        let mut process = false;
        for input in self.spec.inputs.iter().filter(|i| i.key == key) {
            self.values[input.index] = value;
            process |= input.mode == InputMode::Process;
        }
        process
    }

    /// An update of `key`, one of the keys the link is processed by (`processed_by`): the inputs
    /// on that key take `value`; the link processes now (`process`).
    pub fn processed_by(&mut self, key: &str, value: f64) {
        for input in self.spec.inputs.iter().filter(|i| i.key == key) {
            self.values[input.index] = value;
        }
    }

    /// A value found on `key` (the state a link finds when it connects or its source comes back,
    /// not a change): the inputs there take it. Whether the link processes now, as on an update
    /// of a CP input or a key it is processed by, only when its result is its own record's value
    /// (`serving_its_record`): a write elsewhere, into a motor, is never made on what a
    /// connection found, only on the next update.
    #[must_use = "a found value may process a record's link"]
    pub fn found(&mut self, key: &str, value: f64) -> bool {
        let processing = self.spec.processed_by.iter().any(|k| k == key);
        let cp = self.update(key, value);
        self.own_record && (cp || processing)
    }

    /// The NPP inputs (index, key), to read when the link processes: EPICS reads a link's source
    /// then, and the value last followed may be older than a write that processes the link (a
    /// motor's output link is written before its DVAL is posted).
    pub fn read_at_processing(&self) -> impl Iterator<Item = (usize, &str)> {
        self.spec.inputs.iter().filter(|i| i.mode == InputMode::NoProcess).map(|i| (i.index, i.key.as_str()))
    }

    /// Process: the inputs read now (`read_at_processing`: index, value; one unanswered keeps
    /// the value last followed) are taken, the expression computed; the result to write to
    /// the output key, if one is due (OOPT).
    #[must_use = "the result is the link's write"]
    pub fn process_with(&mut self, read: &[(usize, f64)]) -> Option<f64> {
        for &(index, value) in read {
            if let Some(slot) = self.values.get_mut(index) {
                *slot = value;
            }
        }
        self.process()
    }

    /// Its result, computed now, when nothing could ever process it: no input on a key and no key
    /// processing it, only constants (a calc record of `CALC "1000"`, read by others' links that
    /// process it first, as EPICS's PP input links do: its value is the same whenever processed).
    /// `None` for a link that has keys to wait for.
    #[must_use = "the result is the link's write"]
    pub fn constant_result(&mut self) -> Option<f64> {
        match self.spec.inputs.is_empty() && self.spec.processed_by.is_empty() {
            true => self.process(),
            false => None,
        }
    }

    /// Recompute; the result to write to the output key, if one is due (OOPT).
    fn process(&mut self) -> Option<f64> {
        let mut values = self.values;
        let result = self.expression.eval(&mut values);
        self.values = values;
        let changed = self.last_output.is_none_or(|last| last != result && !(last.is_nan() && result.is_nan()));
        self.last_output = Some(result);
        (self.spec.option == OutputOption::EveryTime || changed).then_some(result)
    }

    /// The keys of its inputs, in order.
    pub fn input_keys(&self) -> impl Iterator<Item = &str> {
        self.spec.inputs.iter().map(|i| i.key.as_str())
    }

    /// The keys it is processed by, in order.
    pub fn processing_keys(&self) -> impl Iterator<Item = &str> {
        self.spec.processed_by.iter().map(String::as_str)
    }
}

/// Input index of a letter A–P (case-insensitive).
pub fn input_index(letter: &str) -> Option<usize> {
    match letter.as_bytes() {
        [c] if (b'A'..=b'P').contains(&c.to_ascii_uppercase()) => Some(usize::from(c.to_ascii_uppercase() - b'A')),
        _ => None,
    }
}

/// Calc links in which a CP input, or a key the link is processed by, is fed, directly or
/// through other calc links, by the link's own output: such a loop would recompute forever.
pub fn find_cycle(links: &[CalcLinkSpec]) -> Option<Vec<String>> {
    let feeds = |from: &CalcLinkSpec, to: &CalcLinkSpec| {
        to.inputs.iter().any(|i| i.mode == InputMode::Process && i.key == from.output)
            || to.processed_by.contains(&from.output)
    };
    fn visit(
        at: usize,
        links: &[CalcLinkSpec],
        feeds: &dyn Fn(&CalcLinkSpec, &CalcLinkSpec) -> bool,
        path: &mut Vec<usize>,
        done: &mut Vec<bool>,
    ) -> Option<Vec<String>> {
        if let Some(start) = path.iter().position(|&p| p == at) {
            let mut cycle: Vec<String> = path[start..].iter().map(|&i| links[i].name.clone()).collect();
            cycle.push(links[at].name.clone());
            return Some(cycle);
        }
        if done[at] {
            return None;
        }
        path.push(at);
        for next in 0..links.len() {
            if feeds(&links[at], &links[next]) {
                if let Some(cycle) = visit(next, links, feeds, path, done) {
                    return Some(cycle);
                }
            }
        }
        path.pop();
        done[at] = true;
        None
    }
    let mut done = vec![false; links.len()];
    (0..links.len()).find_map(|start| visit(start, links, &feeds, &mut Vec::new(), &mut done))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(
        name: &str,
        expression: &str,
        inputs: &[(usize, &str, InputMode)],
        output: &str,
        option: OutputOption,
    ) -> CalcLinkSpec {
        CalcLinkSpec {
            name: name.into(),
            expression: expression.into(),
            inputs: inputs
                .iter()
                .map(|(index, key, mode)| InputSpec { index: *index, key: (*key).into(), mode: *mode })
                .collect(),
            constants: Vec::new(),
            output: output.into(),
            option,
            processed_by: Vec::new(),
        }
    }

    /// The result due after an update of `key`, processing when it says so (nothing read).
    fn after(link: &mut CalcLink, key: &str, value: f64) -> Option<f64> {
        link.update(key, value).then(|| link.process_with(&[])).flatten()
    }

    #[test]
    fn cp_inputs_recompute_and_npp_inputs_only_hold() {
        let mut link = CalcLink::new(spec(
            "sum",
            "A+B",
            &[(0, "x", InputMode::Process), (1, "y", InputMode::NoProcess)],
            "out",
            OutputOption::EveryTime,
        ))
        .unwrap();
        assert_eq!(after(&mut link, "y", 10.0), None, "NPP: no recompute");
        assert_eq!(after(&mut link, "x", 1.0), Some(11.0));
        assert_eq!(after(&mut link, "x", 1.0), Some(11.0), "every time");
        assert_eq!(after(&mut link, "other", 5.0), None);
        // The NPP input read when the link processes is taken before the computation.
        assert_eq!(link.read_at_processing().collect::<Vec<_>>(), [(1, "y")]);
        assert!(link.update("x", 2.0));
        assert_eq!(link.process_with(&[(1, 20.0)]), Some(22.0));
        assert_eq!(after(&mut link, "x", 2.0), Some(22.0), "what was read is held");
    }

    #[test]
    fn a_link_of_constants_only_has_its_result_at_once_and_one_with_keys_waits_for_them() {
        let mut constant = spec("height", "A*2", &[], "bridge/height/VAL", OutputOption::EveryTime);
        constant.constants = vec![(0, 500.0)];
        assert_eq!(CalcLink::new(constant.clone()).unwrap().constant_result(), Some(1000.0));
        let mut processed = constant.clone();
        processed.processed_by = vec!["bridge/height/PROC".into()];
        assert_eq!(CalcLink::new(processed).unwrap().constant_result(), None, "processed when that key says");
        let linked = spec("x", "A", &[(0, "y", InputMode::NoProcess)], "out", OutputOption::EveryTime);
        assert_eq!(CalcLink::new(linked).unwrap().constant_result(), None, "waits for its input");
    }

    #[test]
    fn constants_hold_until_an_update() {
        let mut spec = spec("scale", "A*B", &[(0, "x", InputMode::Process)], "out", OutputOption::EveryTime);
        spec.constants = vec![(1, 1000.0)];
        let mut link = CalcLink::new(spec).unwrap();
        assert_eq!(after(&mut link, "x", 0.5), Some(500.0));
    }

    #[test]
    fn on_change_writes_only_new_results() {
        let mut link =
            CalcLink::new(spec("c", "A>0", &[(0, "x", InputMode::Process)], "out", OutputOption::OnChange)).unwrap();
        assert_eq!(after(&mut link, "x", 1.0), Some(1.0));
        assert_eq!(after(&mut link, "x", 2.0), None);
        assert_eq!(after(&mut link, "x", -1.0), Some(0.0));
    }

    #[test]
    fn bad_expressions_and_bindings_are_refused() {
        let e = CalcLink::new(spec("c", "A+", &[], "out", OutputOption::EveryTime)).unwrap_err();
        assert_eq!(e.to_string(), "calc 'c': expression 'A+': column 3: an operand is missing at the end");
        let e = CalcLink::new(spec(
            "c",
            "A",
            &[(0, "x", InputMode::Process), (0, "y", InputMode::Process)],
            "o",
            OutputOption::EveryTime,
        ));
        assert_eq!(e.unwrap_err().to_string(), "calc 'c': input A is bound twice");
        assert_eq!(input_index("c"), Some(2));
        assert_eq!((input_index("P"), input_index("Q")), (Some(15), None), "a transform's A–P");
    }

    #[test]
    fn a_key_it_is_processed_by_recomputes_it_with_its_inputs_on_that_key_updated_first() {
        // A dfanout's output: its value held (NPP) and written out at each write of it.
        let mut fan = spec("fan", "A", &[(0, "d", InputMode::NoProcess)], "m1/STOP", OutputOption::EveryTime);
        fan.processed_by = vec!["d".into()];
        let mut link = CalcLink::new(fan).unwrap();
        assert_eq!(after(&mut link, "d", 1.0), None, "the value found at start is held, not written");
        link.processed_by("d", 2.0);
        assert_eq!(link.process_with(&[]), Some(2.0), "a write is written out, its own value");
        // A forward link from elsewhere: processes with the inputs as they are.
        let mut count = spec("count", "A+1", &[(0, "n", InputMode::NoProcess)], "n", OutputOption::EveryTime);
        count.processed_by = vec!["count/PROC".into()];
        let mut link = CalcLink::new(count).unwrap();
        assert!(!link.update("n", 4.0));
        link.processed_by("count/PROC", 1.0);
        assert_eq!(link.process_with(&[]), Some(5.0));
        assert_eq!(link.processing_keys().collect::<Vec<_>>(), ["count/PROC"]);
    }

    #[test]
    fn cycles_through_cp_inputs_are_found() {
        let a = spec("a", "A", &[(0, "kb", InputMode::Process)], "ka", OutputOption::EveryTime);
        let b = spec("b", "A", &[(0, "ka", InputMode::Process)], "kb", OutputOption::EveryTime);
        assert_eq!(find_cycle(&[a.clone(), b.clone()]), Some(vec!["a".into(), "b".into(), "a".into()]));
        let npp = spec("b", "A", &[(0, "ka", InputMode::NoProcess)], "kb", OutputOption::EveryTime);
        assert_eq!(find_cycle(&[a.clone(), npp]), None);
        let own = spec("self", "A+1", &[(0, "k", InputMode::Process)], "k", OutputOption::EveryTime);
        assert_eq!(find_cycle(&[own]), Some(vec!["self".into(), "self".into()]));
        let chain = spec("c", "A", &[(0, "ka", InputMode::Process)], "kc", OutputOption::EveryTime);
        assert_eq!(find_cycle(&[a.clone(), chain]), None);
        let mut processed = spec("p", "1", &[], "kb", OutputOption::EveryTime);
        processed.processed_by = vec!["ka".into()];
        assert_eq!(find_cycle(&[a, processed]), Some(vec!["a".into(), "p".into(), "a".into()]), "through processed_by");
    }

    #[test]
    fn a_value_found_processes_only_a_link_whose_result_is_its_own_records_value() {
        let spec = CalcLinkSpec {
            name: "c".into(),
            expression: "A+B".into(),
            inputs: vec![
                InputSpec { index: 0, key: "a".into(), mode: InputMode::Process },
                InputSpec { index: 1, key: "b".into(), mode: InputMode::NoProcess },
            ],
            constants: vec![],
            output: "motor/m1/VAL".into(),
            option: OutputOption::EveryTime,
            processed_by: vec!["p".into()],
        };
        let mut writes_a_motor = CalcLink::new(spec.clone()).unwrap();
        assert!(!writes_a_motor.found("a", 1.0), "a CP input's value found writes no motor");
        assert!(!writes_a_motor.found("p", 1.0), "nor does a processing key's");
        assert!(writes_a_motor.update("a", 2.0), "its next update does");
        let mut record = CalcLink::new(spec).unwrap().serving_its_record();
        assert!(record.found("a", 1.0) && record.found("p", 1.0), "a record's value is computed from it");
        assert!(!record.found("b", 5.0), "an NPP input's is only held");
        assert_eq!(record.process_with(&[]), Some(6.0));
    }
}
