//! The EPICS calc expression language (calc/calcout records), parsed once and evaluated many
//! times. Semantics follow EPICS base: operator precedence (from high to low: prefix operators
//! and functions; `^ **`; `* / %`; `+ -`; comparisons; `& && << >> >>> AND`; `| || OR XOR`;
//! `?:`), left associativity (`2^3^2` is 64, `-2^2` is 4), integer `%` (NaN on a zero divisor),
//! 32-bit bitwise operators, `ATAN2(a, b)` = atan2(b, a), statements separated by `;` with
//! `X := expr` assignments to the inputs A–L, and names case-insensitive. A transform record's
//! expressions have the same language over its sixteen fields, A–P (`Expression::parse_over`).
//! Errors name the 1-based column of the offending text.

use std::f64::consts::PI;

/// Number of inputs, A to L.
pub const INPUTS: usize = 12;
/// Number of a transform record's fields, A to P, its expressions' variables.
pub const TRANSFORM_FIELDS: usize = 16;

/// Why an expression does not parse, and where.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("column {column}: {message}")]
#[non_exhaustive]
pub struct CalcError {
    /// 1-based column of the offending text.
    pub column: usize,
    /// What is wrong there.
    pub message: String,
}

fn error<T>(column: usize, message: impl Into<String>) -> Result<T, CalcError> {
    Err(CalcError { column, message: message.into() })
}

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Number(f64),
    Word(String),
    Symbol(&'static str),
}

/// Symbols, longest first so that `>>>` wins over `>>` and `>`.
const SYMBOLS: &[&str] = &[
    ">>>", ":=", "**", "&&", "||", "<<", ">>", "<=", ">=", "==", "!=", "+", "-", "*", "/", "%", "^", "(", ")", ",",
    "?", ":", ";", "<", ">", "=", "#", "!", "~", "&", "|",
];

fn lex(source: &str) -> Result<Vec<(Token, usize)>, CalcError> {
    let bytes = source.as_bytes();
    let mut tokens = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i] as char;
        let column = i + 1;
        if c.is_ascii_whitespace() {
            i += 1;
        } else if c.is_ascii_digit() || (c == '.' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit)) {
            let (value, len) =
                number(&source[i..]).ok_or(CalcError { column, message: "bad numeric literal".into() })?;
            tokens.push((Token::Number(value), column));
            i += len;
        } else if c.is_ascii_alphabetic() || c == '_' {
            let len =
                source[i..].find(|ch: char| !(ch.is_ascii_alphanumeric() || ch == '_')).unwrap_or(source.len() - i);
            tokens.push((Token::Word(source[i..i + len].to_ascii_uppercase()), column));
            i += len;
        } else if let Some(symbol) = SYMBOLS.iter().find(|s| source[i..].starts_with(**s)) {
            tokens.push((Token::Symbol(symbol), column));
            i += symbol.len();
        } else {
            return error(column, format!("unexpected character '{c}'"));
        }
    }
    Ok(tokens)
}

/// A decimal or hexadecimal literal at the start of `text`: its value and length.
fn number(text: &str) -> Option<(f64, usize)> {
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        let len = hex.find(|c: char| !c.is_ascii_hexdigit()).unwrap_or(hex.len());
        return u32::from_str_radix(&hex[..len], 16).ok().map(|v| (f64::from(v), len + 2));
    }
    let bytes = text.as_bytes();
    let mut len = bytes.iter().take_while(|b| b.is_ascii_digit() || **b == b'.').count();
    if matches!(bytes.get(len), Some(b'e' | b'E')) {
        let sign = usize::from(matches!(bytes.get(len + 1), Some(b'+' | b'-')));
        let digits = bytes[len + 1 + sign..].iter().take_while(|b| b.is_ascii_digit()).count();
        if digits > 0 {
            len += 1 + sign + digits;
        }
    }
    text[..len].parse::<f64>().ok().map(|v| (v, len))
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Unary {
    Neg,
    Not,
    BitNot,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Binary {
    Pow,
    Mul,
    Div,
    Mod,
    Add,
    Sub,
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
    BitAnd,
    And,
    Shl,
    Shr,
    ShrLogical,
    BitOr,
    Or,
    Xor,
}

impl Binary {
    fn from_token(token: &Token) -> Option<(Self, u8)> {
        let (op, level) = match token {
            Token::Symbol(s) => match *s {
                "**" | "^" => (Binary::Pow, 6),
                "*" => (Binary::Mul, 5),
                "/" => (Binary::Div, 5),
                "%" => (Binary::Mod, 5),
                "+" => (Binary::Add, 4),
                "-" => (Binary::Sub, 4),
                "<" => (Binary::Lt, 3),
                "<=" => (Binary::Le, 3),
                ">" => (Binary::Gt, 3),
                ">=" => (Binary::Ge, 3),
                "=" | "==" => (Binary::Eq, 3),
                "!=" | "#" => (Binary::Ne, 3),
                "&" => (Binary::BitAnd, 2),
                "&&" => (Binary::And, 2),
                "<<" => (Binary::Shl, 2),
                ">>" => (Binary::Shr, 2),
                ">>>" => (Binary::ShrLogical, 2),
                "|" => (Binary::BitOr, 1),
                "||" => (Binary::Or, 1),
                _ => return None,
            },
            Token::Word(w) => match w.as_str() {
                "AND" => (Binary::BitAnd, 2),
                "OR" => (Binary::BitOr, 1),
                "XOR" => (Binary::Xor, 1),
                _ => return None,
            },
            Token::Number(_) => return None,
        };
        Some((op, level))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Function {
    Abs,
    Acos,
    Asin,
    Atan,
    Atan2,
    Ceil,
    Cos,
    Cosh,
    Exp,
    Finite,
    Floor,
    Fmod,
    IsInf,
    IsNan,
    Ln,
    Log,
    Max,
    Min,
    Nint,
    Sin,
    Sinh,
    Sqrt,
    Tan,
    Tanh,
}

impl Function {
    fn from_name(name: &str) -> Option<Self> {
        use Function::*;
        Some(match name {
            "ABS" => Abs,
            "ACOS" => Acos,
            "ASIN" => Asin,
            "ATAN" => Atan,
            "ATAN2" => Atan2,
            "CEIL" => Ceil,
            "COS" => Cos,
            "COSH" => Cosh,
            "EXP" => Exp,
            "FINITE" => Finite,
            "FLOOR" => Floor,
            "FMOD" => Fmod,
            "ISINF" => IsInf,
            "ISNAN" => IsNan,
            "LN" | "LOGE" => Ln,
            "LOG" => Log,
            "MAX" => Max,
            "MIN" => Min,
            "NINT" => Nint,
            "SIN" => Sin,
            "SINH" => Sinh,
            "SQR" | "SQRT" => Sqrt,
            "TAN" => Tan,
            "TANH" => Tanh,
            _ => return None,
        })
    }

    /// Allowed argument counts: (min, max).
    fn arity(self) -> (usize, usize) {
        match self {
            Function::Atan2 | Function::Fmod => (2, 2),
            Function::Max | Function::Min | Function::Finite | Function::IsNan => (1, usize::MAX),
            _ => (1, 1),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Expr {
    Literal(f64),
    Input(usize),
    Random,
    Unary(Unary, Box<Expr>),
    Binary(Binary, Box<Expr>, Box<Expr>),
    Call(Function, Vec<Expr>),
    Conditional(Box<Expr>, Box<Expr>, Box<Expr>),
}

#[derive(Clone, Debug, PartialEq)]
enum Statement {
    Assign(usize, Expr),
    Value(Expr),
}

/// A parsed calc expression.
#[derive(Clone, Debug, PartialEq)]
pub struct Expression {
    statements: Vec<Statement>,
    source: String,
}

struct Parser {
    tokens: Vec<(Token, usize)>,
    /// How many variables there are (A and on).
    variables: usize,
    pos: usize,
    end_column: usize,
    /// Parentheses, calls, conditionals and prefix operators open now.
    depth: usize,
}

/// The longest expression taken (EPICS's calc fields hold 80 to 160 characters): it bounds the
/// evaluation's recursion.
pub const MAX_LENGTH: usize = 1000;

/// The deepest nesting taken: it bounds the parser's recursion (found by fuzzing: 3,000 nested
/// parentheses overflowed the stack).
pub const MAX_NESTING: usize = 64;

impl Parser {
    fn peek(&self) -> Option<&Token> {
        self.tokens.get(self.pos).map(|(t, _)| t)
    }

    fn column(&self) -> usize {
        self.tokens.get(self.pos).map_or(self.end_column, |(_, c)| *c)
    }

    fn next(&mut self) -> Option<(Token, usize)> {
        let t = self.tokens.get(self.pos).cloned();
        self.pos += 1;
        t
    }

    fn expect(&mut self, symbol: &'static str, what: &str) -> Result<(), CalcError> {
        match self.peek() {
            Some(Token::Symbol(s)) if *s == symbol => {
                self.pos += 1;
                Ok(())
            }
            _ => error(self.column(), format!("expected '{symbol}' {what}")),
        }
    }

    fn statement(&mut self) -> Result<Statement, CalcError> {
        if let (Some((Token::Word(w), column)), Some((Token::Symbol(":="), _))) =
            (self.tokens.get(self.pos), self.tokens.get(self.pos + 1))
        {
            let column = *column;
            let last = input_name(self.variables - 1);
            let target = input_index(w, self.variables)
                .ok_or(CalcError { column, message: format!("cannot assign to '{w}'; only A to {last}") })?;
            self.pos += 2;
            return Ok(Statement::Assign(target, self.conditional()?));
        }
        Ok(Statement::Value(self.conditional()?))
    }

    /// One level deeper, or an error past `MAX_NESTING`.
    fn nested<T>(&mut self, parse: impl FnOnce(&mut Self) -> Result<T, CalcError>) -> Result<T, CalcError> {
        if self.depth >= MAX_NESTING {
            return error(self.column(), format!("nested more than {MAX_NESTING} deep"));
        }
        self.depth += 1;
        let parsed = parse(self);
        self.depth -= 1;
        parsed
    }

    /// `c ? a : b`, the lowest precedence, grouping to the right.
    fn conditional(&mut self) -> Result<Expr, CalcError> {
        self.nested(Self::conditional_here)
    }

    fn conditional_here(&mut self) -> Result<Expr, CalcError> {
        let condition = self.binary(1)?;
        if self.peek() == Some(&Token::Symbol("?")) {
            self.pos += 1;
            let then = self.conditional()?;
            self.expect(":", "to complete the conditional")?;
            let otherwise = self.conditional()?;
            return Ok(Expr::Conditional(Box::new(condition), Box::new(then), Box::new(otherwise)));
        }
        Ok(condition)
    }

    /// Binary operators of `level` and above, left associative.
    fn binary(&mut self, level: u8) -> Result<Expr, CalcError> {
        let mut left = self.prefix()?;
        while let Some((op, op_level)) = self.peek().and_then(Binary::from_token) {
            if op_level < level {
                break;
            }
            self.pos += 1;
            let right = self.binary(op_level + 1)?;
            left = Expr::Binary(op, Box::new(left), Box::new(right));
        }
        Ok(left)
    }

    /// Prefix operators bind tighter than every binary operator (so `-2^2` is 4).
    fn prefix(&mut self) -> Result<Expr, CalcError> {
        let unary = match self.peek() {
            Some(Token::Symbol("-")) => Some(Unary::Neg),
            Some(Token::Symbol("!")) => Some(Unary::Not),
            Some(Token::Symbol("~")) => Some(Unary::BitNot),
            Some(Token::Word(w)) if w == "NOT" => Some(Unary::BitNot),
            _ => None,
        };
        if let Some(op) = unary {
            self.pos += 1;
            return Ok(Expr::Unary(op, Box::new(self.nested(Self::prefix)?)));
        }
        self.operand()
    }

    fn operand(&mut self) -> Result<Expr, CalcError> {
        let column = self.column();
        match self.next() {
            None => error(column, "an operand is missing at the end"),
            Some((Token::Number(x), _)) => Ok(Expr::Literal(x)),
            Some((Token::Symbol("("), _)) => {
                let inner = self.conditional()?;
                self.expect(")", "to close the parenthesis")?;
                Ok(inner)
            }
            Some((Token::Word(w), _)) => {
                if let Some(index) = input_index(&w, self.variables) {
                    return Ok(Expr::Input(index));
                }
                let constant = match w.as_str() {
                    "PI" => Some(PI),
                    "D2R" => Some(PI / 180.0),
                    "R2D" => Some(180.0 / PI),
                    "INF" => Some(f64::INFINITY),
                    "NAN" => Some(f64::NAN),
                    _ => None,
                };
                if let Some(value) = constant {
                    return Ok(Expr::Literal(value));
                }
                if w == "RNDM" {
                    return Ok(Expr::Random);
                }
                let function =
                    Function::from_name(&w).ok_or(CalcError { column, message: format!("unknown name '{w}'") })?;
                self.expect("(", &format!("after {w}"))?;
                let mut args = vec![self.conditional()?];
                while self.peek() == Some(&Token::Symbol(",")) {
                    self.pos += 1;
                    args.push(self.conditional()?);
                }
                self.expect(")", &format!("to close the arguments of {w}"))?;
                let (min, max) = function.arity();
                if args.len() < min || args.len() > max {
                    return error(
                        column,
                        format!(
                            "{w} takes {} argument(s), not {}",
                            if min == max { min.to_string() } else { format!("at least {min}") },
                            args.len()
                        ),
                    );
                }
                Ok(Expr::Call(function, args))
            }
            Some((Token::Symbol(s), _)) => error(column, format!("an operand is expected here, not '{s}'")),
        }
    }
}

/// The index of a variable's letter among `variables` (A = 0).
fn input_index(word: &str, variables: usize) -> Option<usize> {
    match word.as_bytes() {
        [c @ b'A'..=b'Z'] => Some(usize::from(c - b'A')).filter(|&index| index < variables),
        _ => None,
    }
}

/// The letter of variable `index` (A = 0; past P, P).
pub fn input_name(index: usize) -> char {
    char::from(b'A' + u8::try_from(index.min(TRANSFORM_FIELDS - 1)).unwrap_or(15))
}

impl Expression {
    /// Parse a calc record's expression, over the inputs A–L.
    pub fn parse(source: &str) -> Result<Self, CalcError> {
        Self::parse_over(source, INPUTS)
    }

    /// Parse an expression over `variables` variables from A (`TRANSFORM_FIELDS` for a transform
    /// record's, and at most that many).
    pub fn parse_over(source: &str, variables: usize) -> Result<Self, CalcError> {
        let variables = variables.clamp(1, TRANSFORM_FIELDS);
        if source.chars().count() > MAX_LENGTH {
            return error(MAX_LENGTH + 1, format!("the expression is longer than {MAX_LENGTH} characters"));
        }
        let tokens = lex(source)?;
        if tokens.is_empty() {
            return error(1, "the expression is empty");
        }
        let mut parser = Parser { tokens, variables, pos: 0, end_column: source.len() + 1, depth: 0 };
        let mut statements = Vec::new();
        loop {
            statements.push(parser.statement()?);
            match parser.next() {
                None => break,
                Some((Token::Symbol(";"), _)) if parser.peek().is_some() => {}
                Some((Token::Symbol(";"), _)) => break,
                Some((token, column)) => {
                    let text = match token {
                        Token::Number(x) => x.to_string(),
                        Token::Word(w) => w,
                        Token::Symbol(s) => s.to_string(),
                    };
                    return error(column, format!("unexpected '{text}' after a complete expression"));
                }
            }
        }
        if !matches!(statements.last(), Some(Statement::Value(_))) {
            return error(parser.end_column, "the expression must end with a value, not an assignment");
        }
        Ok(Self { statements, source: source.to_string() })
    }

    /// The text the expression was parsed from.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Bit i set when input i (A = 0) is read before being assigned.
    pub fn inputs_used(&self) -> u16 {
        fn walk(e: &Expr, used: &mut u16, stored: u16) {
            match e {
                Expr::Input(i) => *used |= (1 << i) & !stored,
                Expr::Unary(_, a) => walk(a, used, stored),
                Expr::Binary(_, a, b) => {
                    walk(a, used, stored);
                    walk(b, used, stored);
                }
                Expr::Call(_, args) => args.iter().for_each(|a| walk(a, used, stored)),
                Expr::Conditional(c, a, b) => {
                    walk(c, used, stored);
                    walk(a, used, stored);
                    walk(b, used, stored);
                }
                Expr::Literal(_) | Expr::Random => {}
            }
        }
        let (mut used, mut stored) = (0, 0);
        for statement in &self.statements {
            match statement {
                Statement::Assign(target, e) => {
                    walk(e, &mut used, stored);
                    stored |= 1 << target;
                }
                Statement::Value(e) => walk(e, &mut used, stored),
            }
        }
        used
    }

    /// Evaluate with the inputs from A (assignments write back into them); a variable beyond the
    /// array reads NaN and takes no assignment.
    pub fn eval<const N: usize>(&self, inputs: &mut [f64; N]) -> f64 {
        let mut result = f64::NAN;
        for statement in &self.statements {
            match statement {
                Statement::Assign(target, e) => {
                    let value = eval(e, inputs);
                    if let Some(slot) = inputs.get_mut(*target) {
                        *slot = value;
                    }
                }
                Statement::Value(e) => result = eval(e, inputs),
            }
        }
        result
    }
}

/// EPICS `d2i`: negative doubles through i32, positive ones through u32, so bit 31 survives.
fn d2i(x: f64) -> i32 {
    if x < 0.0 {
        x as i32
    } else {
        x as u32 as i32
    }
}

fn d2ui(x: f64) -> u32 {
    if x < 0.0 {
        x as i32 as u32
    } else {
        x as u32
    }
}

fn truth(b: bool) -> f64 {
    if b {
        1.0
    } else {
        0.0
    }
}

fn eval<const N: usize>(e: &Expr, inputs: &mut [f64; N]) -> f64 {
    match e {
        Expr::Literal(x) => *x,
        Expr::Input(i) => inputs.get(*i).copied().unwrap_or(f64::NAN),
        Expr::Random => random(),
        Expr::Unary(op, a) => {
            let a = eval(a, inputs);
            match op {
                Unary::Neg => -a,
                Unary::Not => truth(a == 0.0),
                Unary::BitNot => f64::from(!d2i(a)),
            }
        }
        Expr::Binary(op, a, b) => {
            let (a, b) = (eval(a, inputs), eval(b, inputs));
            match op {
                Binary::Pow => a.powf(b),
                Binary::Mul => a * b,
                Binary::Div => a / b,
                Binary::Mod => match b as i32 {
                    0 => f64::NAN,
                    d => f64::from((a as i32).wrapping_rem(d)),
                },
                Binary::Add => a + b,
                Binary::Sub => a - b,
                Binary::Lt => truth(a < b),
                Binary::Le => truth(a <= b),
                Binary::Gt => truth(a > b),
                Binary::Ge => truth(a >= b),
                Binary::Eq => truth(a == b),
                Binary::Ne => truth(a != b),
                Binary::And => truth(a != 0.0 && b != 0.0),
                Binary::Or => truth(a != 0.0 || b != 0.0),
                Binary::BitAnd => f64::from(d2i(a) & d2i(b)),
                Binary::BitOr => f64::from(d2i(a) | d2i(b)),
                Binary::Xor => f64::from(d2i(a) ^ d2i(b)),
                Binary::Shl => f64::from(d2i(a).wrapping_shl((d2i(b) & 31) as u32)),
                Binary::Shr => f64::from(d2i(a) >> (d2i(b) & 31)),
                Binary::ShrLogical => f64::from(d2ui(a) >> (d2ui(b) & 31)),
            }
        }
        Expr::Conditional(c, then, otherwise) => {
            if eval(c, inputs) != 0.0 {
                eval(then, inputs)
            } else {
                eval(otherwise, inputs)
            }
        }
        Expr::Call(f, args) => {
            let values: Vec<f64> = args.iter().map(|a| eval(a, inputs)).collect();
            let x = values[0];
            match f {
                Function::Abs => x.abs(),
                Function::Acos => x.acos(),
                Function::Asin => x.asin(),
                Function::Atan => x.atan(),
                // EPICS passes the arguments to atan2 the other way round.
                Function::Atan2 => values[1].atan2(x),
                Function::Ceil => x.ceil(),
                Function::Cos => x.cos(),
                Function::Cosh => x.cosh(),
                Function::Exp => x.exp(),
                Function::Finite => truth(values.iter().all(|v| v.is_finite())),
                Function::Floor => x.floor(),
                Function::Fmod => x % values[1],
                Function::IsInf => truth(x.is_infinite()),
                Function::IsNan => truth(values.iter().any(|v| v.is_nan())),
                Function::Ln => x.ln(),
                Function::Log => x.log10(),
                Function::Max => values.iter().skip(1).fold(x, |m, &v| if m < v || v.is_nan() { v } else { m }),
                Function::Min => values.iter().skip(1).fold(x, |m, &v| if m > v || v.is_nan() { v } else { m }),
                Function::Nint => f64::from(if x >= 0.0 { (x + 0.5) as i32 } else { (x - 0.5) as i32 }),
                Function::Sin => x.sin(),
                Function::Sinh => x.sinh(),
                Function::Sqrt => x.sqrt(),
                Function::Tan => x.tan(),
                Function::Tanh => x.tanh(),
            }
        }
    }
}

/// RNDM: a uniform number in [0, 1], as EPICS's small linear congruential generator.
fn random() -> f64 {
    use std::sync::atomic::{AtomicU16, Ordering};
    static SEED: AtomicU16 = AtomicU16::new(0xa3bf);
    let next = |s: u16| s.wrapping_mul(191 * 8 + 5).wrapping_add(0x3141);
    let previous = SEED.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |s| Some(next(s))).unwrap_or(0);
    f64::from(next(previous)) / 65535.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calc(source: &str) -> f64 {
        calc_with(source, [0.0; INPUTS])
    }

    fn calc_with(source: &str, mut inputs: [f64; INPUTS]) -> f64 {
        Expression::parse(source).unwrap_or_else(|e| panic!("{source}: {e}")).eval(&mut inputs)
    }

    #[test]
    fn nesting_and_length_are_bounded_with_a_clear_error() {
        let deep = |n: usize| format!("{}A{}", "(".repeat(n), ")".repeat(n));
        assert_eq!(calc(&deep(MAX_NESTING - 1)), 0.0);
        let error = Expression::parse(&deep(400)).unwrap_err();
        assert!(error.message.contains("nested more than 64 deep"), "{error}");
        assert!(Expression::parse(&"~".repeat(500)).unwrap_err().message.contains("nested"));
        let long = vec!["A"; MAX_LENGTH].join("+");
        assert!(Expression::parse(&long).unwrap_err().message.contains("longer than 1000 characters"));
        let sum = vec!["1"; MAX_LENGTH / 2].join("+");
        assert_eq!(calc(&sum), (MAX_LENGTH / 2) as f64, "a long flat sum still evaluates");
    }

    fn inputs(values: &[f64]) -> [f64; INPUTS] {
        let mut all = [0.0; INPUTS];
        all[..values.len()].copy_from_slice(values);
        all
    }

    #[test]
    fn arithmetic_and_precedence() {
        assert_eq!(calc("1+2*3"), 7.0);
        assert_eq!(calc("(1+2)*3"), 9.0);
        assert_eq!(calc("10-4-3"), 3.0);
        assert_eq!(calc("2^3^2"), 64.0, "left associative, as in EPICS");
        assert_eq!(calc("2**10"), 1024.0);
        assert_eq!(calc("-2^2"), 4.0, "prefix minus binds tighter than ^");
        assert_eq!(calc("2*-3"), -6.0);
        assert_eq!(calc("7%3"), 1.0);
        assert_eq!(calc("-7%3"), -1.0);
        assert!(calc("7%0").is_nan());
        assert_eq!(calc("7.9%3.9"), 1.0, "integer modulo");
        assert_eq!(calc("1/4"), 0.25);
        assert_eq!(calc("1/0"), f64::INFINITY);
        assert_eq!(calc(".5+1e1+2.5E-1"), 10.75);
        assert_eq!(calc("0x1F"), 31.0);
    }

    #[test]
    fn comparisons_and_logic() {
        assert_eq!(calc("1<2"), 1.0);
        assert_eq!(calc("2<=1"), 0.0);
        assert_eq!(calc("3=3") + calc("3==3") + calc("3!=4") + calc("3#4"), 4.0);
        assert_eq!(calc("1+1>1"), 1.0, "comparison below arithmetic");
        assert_eq!(calc("1&&0||1"), 1.0);
        assert_eq!(calc("!0+1"), 2.0, "! binds tightest");
        assert_eq!(calc("!(0+1)"), 0.0);
        assert_eq!(calc("1<2&&2<3"), 1.0);
    }

    #[test]
    fn bitwise_operators_work_on_32_bits() {
        assert_eq!(calc("6&3"), 2.0);
        assert_eq!(calc("6 AND 3"), 2.0);
        assert_eq!(calc("6|3"), 7.0);
        assert_eq!(calc("6 OR 3"), 7.0);
        assert_eq!(calc("6 XOR 3"), 5.0);
        assert_eq!(calc("~0"), -1.0);
        assert_eq!(calc("NOT 5"), -6.0);
        assert_eq!(calc("1<<4"), 16.0);
        assert_eq!(calc("-16>>2"), -4.0);
        assert_eq!(calc("-16>>>28"), 15.0);
        assert_eq!(calc("1|2&3"), 3.0, "& above |");
        assert_eq!(calc("0xFFFFFFFF&1"), 1.0);
    }

    #[test]
    fn conditionals_nest_to_the_right() {
        assert_eq!(calc("1?2:3"), 2.0);
        assert_eq!(calc("0?2:3"), 3.0);
        assert_eq!(calc("0?1:0?2:3"), 3.0);
        assert_eq!(calc("1?0?4:5:6"), 5.0);
        assert_eq!(calc_with("A>0?A:-A", inputs(&[-3.0])), 3.0);
    }

    #[test]
    fn functions_and_constants() {
        assert_eq!(calc("ABS(-2)+SQRT(16)+SQR(9)"), 9.0);
        assert_eq!(calc("MIN(3,1,2)+MAX(3,1,2)"), 4.0);
        assert!(calc("MAX(1,NAN,2)").is_nan());
        assert_eq!(calc("FLOOR(2.7)+CEIL(2.2)"), 5.0);
        assert_eq!(calc("NINT(2.5)+NINT(-2.5)"), 0.0);
        assert_eq!(calc("NINT(2.4)"), 2.0);
        assert!((calc("EXP(1)") - std::f64::consts::E).abs() < 1e-12);
        assert!((calc("LN(EXP(2))") - 2.0).abs() < 1e-12);
        assert_eq!(calc("LOG(1000)"), 3.0);
        assert!((calc("LOGE(1)")).abs() < 1e-12);
        assert!((calc("SIN(PI/2)") - 1.0).abs() < 1e-12);
        assert!((calc("COS(0)+TAN(0)+SINH(0)+COSH(0)+TANH(0)") - 2.0).abs() < 1e-12);
        assert!((calc("ASIN(1)+ACOS(1)+ATAN(1)") - (PI / 2.0 + PI / 4.0)).abs() < 1e-12);
        assert!((calc("ATAN2(1,0)") - 0.0).abs() < 1e-12, "ATAN2(a,b) = atan2(b,a)");
        assert!((calc("ATAN2(0,1)") - PI / 2.0).abs() < 1e-12);
        assert!((calc("90*D2R") - PI / 2.0).abs() < 1e-12);
        assert!((calc("PI*R2D") - 180.0).abs() < 1e-12);
        assert_eq!(calc("FMOD(7.5,2)"), 1.5);
        assert_eq!(calc("ISNAN(1,NAN)+ISINF(INF)+FINITE(1,2)"), 3.0);
        let r = calc("RNDM");
        assert!((0.0..=1.0).contains(&r));
    }

    #[test]
    fn inputs_assignments_and_case() {
        let i = inputs(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]);
        assert_eq!(calc_with("A+B+C+D+E+F+G+H+I+J+K+L", i), 78.0);
        assert_eq!(calc_with("a*b", i), 2.0, "names are case-insensitive");
        assert_eq!(calc_with("sin(0)+abs(-l)", i), 12.0);
        let e = Expression::parse("C:=A+B; D:=C*2; D+1").unwrap();
        let mut values = inputs(&[1.0, 2.0]);
        assert_eq!(e.eval(&mut values), 7.0);
        assert_eq!((values[2], values[3]), (3.0, 6.0));
        assert_eq!(e.inputs_used(), 0b11, "C and D are stored before use");
    }

    #[test]
    fn the_tangent_arm_conversions() {
        let drive = Expression::parse("TAN(A/57.296)*1000").unwrap();
        let read = Expression::parse("ATAN(A/1000)*57.296").unwrap();
        let linear = drive.eval(&mut inputs(&[30.0]));
        assert!((linear - 577.35).abs() < 0.01, "{linear}");
        let angle = read.eval(&mut inputs(&[linear]));
        assert!((angle - 30.0).abs() < 1e-9, "{angle}");
    }

    #[test]
    fn errors_point_at_the_column() {
        let err = |s: &str| Expression::parse(s).unwrap_err();
        assert_eq!(err("1+"), CalcError { column: 3, message: "an operand is missing at the end".into() });
        assert_eq!(err("(1+2"), CalcError { column: 5, message: "expected ')' to close the parenthesis".into() });
        assert_eq!(err("1+2)").column, 4);
        assert_eq!(err("A+FOO").message, "unknown name 'FOO'");
        assert_eq!(err("A+FOO").column, 3);
        assert_eq!(err("1 $ 2"), CalcError { column: 3, message: "unexpected character '$'".into() });
        assert_eq!(err("1?2").message, "expected ':' to complete the conditional");
        assert_eq!(err("ATAN2(1)").message, "ATAN2 takes 2 argument(s), not 1");
        assert_eq!(err("M:=1;M").column, 1);
        assert!(err("A:=1").message.contains("must end with a value"));
        assert_eq!(err("1 2").message, "unexpected '2' after a complete expression");
        assert_eq!(err("").column, 1);
        assert_eq!(err("SIN 1").message, "expected '(' after SIN");
        assert_eq!(err("*2"), CalcError { column: 1, message: "an operand is expected here, not '*'".into() });
        assert_eq!(err("1e").message, "unexpected 'E' after a complete expression");
    }
}
