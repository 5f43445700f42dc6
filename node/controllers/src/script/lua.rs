//! One axis's Lua state, as motorScriptMotor makes it: the script's top level run, `DRIVER` and
//! `AXIS` given, the launch file's macros seen as globals, and the `asyn` library of the EPICS
//! lua module, whose reads and writes yield to the driver instead of doing I/O. Sandboxed: no
//! `os`, no `io`, no files but the script directory's modules, a bounded memory and a budget of
//! instructions between two exchanges.

use crate::keys::{KeyAccess, KeyName, KeyReply, KeyValue};
use crate::script_source::{MacroValue, ScriptError, ScriptSource};
use mlua::thread::ThreadStatus;
use mlua::{HookTriggers, Lua, LuaOptions, MultiValue, StdLib, Table, Thread, Value, Variadic, VmState};
use std::collections::HashMap;
use zmotor_msgs::bits::msta;

/// Instructions a script may run between two exchanges with the controller: a poll parsing
/// JSON takes tens of thousands; a loop waiting for something that never comes is stopped.
const INSTRUCTION_BUDGET: u64 = 20_000_000;

/// How often the budget is counted, in instructions.
const BUDGET_STRIDE: u32 = 10_000;

/// Memory one axis's Lua state may take.
const MEMORY_LIMIT: usize = 64 << 20;

/// The asyn motor parameters that are MSTA bits, in MSTA's order (asynMotorController.h).
const STATUS_PARAMS: [(&str, u32); 15] = [
    ("MOTOR_STATUS_DIRECTION", msta::DIRECTION),
    ("MOTOR_STATUS_DONE", msta::DONE),
    ("MOTOR_STATUS_HIGH_LIMIT", msta::PLUS_LS),
    ("MOTOR_STATUS_AT_HOME", msta::HOME),
    ("MOTOR_STATUS_SLIP", msta::SLIP),
    ("MOTOR_STATUS_POWERED", msta::POSITION),
    ("MOTOR_STATUS_FOLLOWING_ERROR", msta::SLIP_STALL),
    ("MOTOR_STATUS_HOME", msta::ENCODER_HOME),
    ("MOTOR_STATUS_HAS_ENCODER", msta::PRESENT),
    ("MOTOR_STATUS_PROBLEM", msta::PROBLEM),
    ("MOTOR_STATUS_MOVING", msta::MOVING),
    ("MOTOR_STATUS_GAIN_SUPPORT", msta::GAIN_SUPPORT),
    ("MOTOR_STATUS_COMMS_ERROR", msta::COMM_ERR),
    ("MOTOR_STATUS_LOW_LIMIT", msta::MINUS_LS),
    ("MOTOR_STATUS_HOMED", msta::HOMED),
];

/// The Lua that makes the `asyn` and `epics` libraries, `require` and the sandbox's edges. Its
/// I/O functions yield `token, kind, bytes, input terminator` to the driver, which resumes them
/// with the reply (asyn appends `OutTerminator` to what is written and reads up to
/// `InTerminator`, both looked up at each call, as the lua module does); `epics.get`/`put`
/// yield `token, kind, name[, value]` and are resumed with `true, value` or `false, why`.
const PRELUDE: &str = r##"
local token, params, find_module, log = ...
local yield, tostring, type, rawset = coroutine.yield, tostring, type, rawset

local function out(data) return tostring(data) .. (OutTerminator or "") end

asyn = {
  write = function(data) yield(token, "write", out(data)) end,
  read = function() return yield(token, "read", "", InTerminator) end,
  writeread = function(data) return yield(token, "writeread", out(data), InTerminator) end,
  setDoubleParam = function(...) params("set", "double", ...) end,
  setIntegerParam = function(...) params("set", "integer", ...) end,
  setParam = function(...) params("set", "any", ...) end,
  getDoubleParam = function(...) return params("get", "double", ...) end,
  getIntegerParam = function(...) return params("get", "integer", ...) end,
  getParam = function(...) return params("get", "any", ...) end,
  callParamCallbacks = function() end,
  setInTerminator = function(t) InTerminator = t end,
  getInTerminator = function() return InTerminator end,
  setOutTerminator = function(t) OutTerminator = t end,
  getOutTerminator = function() return OutTerminator end,
  setReadTimeout = function(t) ReadTimeout = t end,
  getReadTimeout = function() return ReadTimeout end,
  setWriteTimeout = function(t) WriteTimeout = t end,
  getWriteTimeout = function() return WriteTimeout end,
  setTrace = function() end,
  setTraceIO = function() end,
}

epics = {
  get = function(name)
    local ok, value = yield(token, "get", tostring(name))
    if not ok then error("epics.get(" .. tostring(name) .. "): " .. value, 2) end
    return value
  end,
  put = function(name, value)
    local ok, why = yield(token, "put", tostring(name), value)
    if not ok then error("epics.put(" .. tostring(name) .. "): " .. why, 2) end
  end,
}

package = { loaded = { asyn = asyn, epics = epics }, path = "", cpath = "" }
for _, name in ipairs({ "string", "table", "math", "coroutine", "utf8" }) do
  package.loaded[name] = _G[name]
end

function require(name)
  local loaded = package.loaded[name]
  if loaded ~= nil then return loaded end
  local chunk = find_module(name)
  local result = chunk(name)
  if result == nil then result = true end
  package.loaded[name] = result
  return result
end

print = function(...)
  local parts = {}
  for i = 1, select("#", ...) do parts[i] = tostring(select(i, ...)) end
  log(table.concat(parts, "\t"))
end

local load_ = load
load = function(chunk, name, _, env) return load_(chunk, name, "t", env) end
dofile, loadfile = nil, nil
"##;

/// What a script call did when it stopped running.
#[derive(Debug)]
pub(super) enum Ran {
    /// It waits for a reply to these bytes (the bytes may be empty: a read after a write
    /// already sent), read up to the input terminator (none: one read's worth).
    Exchange {
        /// What to write.
        bytes: Vec<u8>,
        /// Where the reply ends.
        terminator: Vec<u8>,
    },
    /// It waits for the node's key space (`epics.get`/`epics.put`), after the bytes it wrote
    /// unanswered before.
    Key {
        /// The read or write.
        access: KeyAccess,
        /// What it wrote last without reading.
        written: Vec<u8>,
    },
    /// It returned; these bytes were written before, unanswered.
    Returned {
        /// What it wrote last without reading.
        written: Vec<u8>,
    },
}

/// The asyn parameters of one axis, as the script set them.
#[derive(Debug, Default)]
pub(super) struct Params {
    doubles: HashMap<String, f64>,
    integers: HashMap<String, i64>,
    /// MSTA as the `MOTOR_STATUS_*` parameters set it.
    pub(super) msta: u32,
}

impl Params {
    /// A double parameter (0 until set).
    pub(super) fn double(&self, name: &str) -> f64 {
        self.doubles.get(name).copied().unwrap_or(0.0)
    }
}

/// What the instruction budget counts, per resume.
#[derive(Debug, Default)]
struct Budget {
    used: u64,
}

/// One axis's Lua state and the call running in it.
pub(super) struct AxisLua {
    lua: Lua,
    token: Table,
    /// The call under way: its coroutine, and the bytes written since its last read.
    call: Option<(Thread, Vec<u8>)>,
}

impl std::fmt::Debug for AxisLua {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AxisLua").field("running", &self.call.is_some()).finish_non_exhaustive()
    }
}

impl AxisLua {
    /// The script loaded for axis `axis` (0-based, `AXIS`) of the controller `source.driver`:
    /// its top level run, then `DRIVER` and `AXIS` set, then its macros (the controller's,
    /// and the axis's over them), as `ScriptControllerConfig` and `ScriptAxisConfig` do.
    pub(super) fn new(source: &ScriptSource, axis: usize) -> Result<Self, ScriptError> {
        let libs = StdLib::COROUTINE | StdLib::TABLE | StdLib::STRING | StdLib::UTF8 | StdLib::MATH;
        let lua = Lua::new_with(libs, LuaOptions::new()).map_err(|e| ScriptError::load(source, &e))?;
        let token = lua.create_table().map_err(|e| ScriptError::load(source, &e))?;
        let prepared = (|| -> mlua::Result<()> {
            lua.set_memory_limit(MEMORY_LIMIT)?;
            let mut given = Params::default();
            if let Some(&mres) = source.record_resolution.get(&axis) {
                given.doubles.insert("MOTOR_REC_RESOLUTION".into(), mres);
            }
            lua.set_app_data(given);
            lua.set_app_data(Budget::default());
            let every = HookTriggers::new().every_nth_instruction(BUDGET_STRIDE);
            lua.set_global_hook(every, |lua, debug| {
                let used = {
                    let mut budget = lua.app_data_mut::<Budget>().expect("set at creation");
                    budget.used += u64::from(BUDGET_STRIDE);
                    budget.used
                };
                if used <= INSTRUCTION_BUDGET {
                    return Ok(VmState::Continue);
                }
                let source = debug.source();
                let at = format!("{}:{}", source.short_src.as_deref().unwrap_or("?"), debug.current_line().unwrap_or(0));
                Err(mlua::Error::runtime(format!(
                    "{at}: {INSTRUCTION_BUDGET} instructions without an exchange with the controller (a loop that never ends?): stopped"
                )))
            })?;
            let modules = source.modules.clone();
            let directory = source.directory();
            let find_module = lua.create_function(move |lua, name: String| {
                let Some(text) = modules.get(&name) else {
                    return Err(mlua::Error::runtime(format!(
                        "module '{name}' not found: a script requires only the .lua files of its own directory"
                    )));
                };
                lua.load(text.as_str()).set_name(format!("@{directory}{name}.lua")).into_function()
            })?;
            let log = lua.create_function(|_, line: String| {
                tracing::info!(target: "zmotor::script", "{line}");
                Ok(())
            })?;
            let params = lua.create_function(params)?;
            lua.load(PRELUDE).set_name("=zmotor").call::<()>((token.clone(), params, find_module, log))
        })();
        prepared.map_err(|e| ScriptError::load(source, &e))?;
        let mut axis_lua = Self { lua, token, call: None };
        axis_lua.reset_budget();
        let name = format!("@{}", source.path);
        axis_lua.lua.load(source.text.as_str()).set_name(name).exec().map_err(|e| ScriptError::load(source, &e))?;
        let globals = axis_lua.lua.globals();
        let given = (|| -> mlua::Result<()> {
            globals.set("DRIVER", source.driver.as_str())?;
            // A float, as lua_pushnumber gives it.
            globals.set("AXIS", axis as f64)?;
            let macros = axis_lua.lua.create_table()?;
            let own = source.axis_macros.get(&axis).into_iter().flatten();
            for (name, value) in source.macros.iter().chain(own) {
                macros.set(name.as_str(), lua_value(&axis_lua.lua, value)?)?;
            }
            let scope = axis_lua.lua.create_table()?;
            scope.set("__index", macros)?;
            globals.set_metatable(Some(scope))
        })();
        given.map_err(|e| ScriptError::load(source, &e))?;
        Ok(axis_lua)
    }

    /// A number the script sets at its top level (`IdlePollPeriod`, ...), if it does.
    pub(super) fn number(&self, name: &str) -> Option<f64> {
        match self.lua.globals().get::<Value>(name) {
            Ok(Value::Number(n)) => Some(n),
            Ok(Value::Integer(n)) => Some(n as f64),
            _ => None,
        }
    }

    /// Whether the script defines the function `name`.
    pub(super) fn defines(&self, name: &str) -> bool {
        matches!(self.lua.globals().get::<Value>(name), Ok(Value::Function(_)))
    }

    /// The parameters as the script left them.
    pub(super) fn params(&self) -> mlua::AppDataRef<'_, Params> {
        self.lua.app_data_ref::<Params>().expect("set at creation")
    }

    /// Start the script's function `name` with `args` (dropping a call left unfinished), and
    /// run it to its first exchange or its end. `Ok(None)` is a function the script lacks.
    pub(super) fn start(&mut self, name: &str, args: impl mlua::IntoLuaMulti) -> Result<Option<Ran>, String> {
        self.call = None;
        let function = match self.lua.globals().get::<Value>(name) {
            Ok(Value::Function(function)) => function,
            _ => return Ok(None),
        };
        let args = args.into_lua_multi(&self.lua).map_err(|e| message(&e))?;
        let thread = self.lua.create_thread(function).map_err(|e| message(&e))?;
        self.call = Some((thread, Vec::new()));
        self.run(args).map(Some)
    }

    /// Resume the call under way with the reply `bytes` (its terminator removed).
    pub(super) fn resume(&mut self, bytes: &[u8]) -> Result<Ran, String> {
        let reply = self.lua.create_string(bytes).map_err(|e| message(&e))?;
        self.run(MultiValue::from_iter([Value::String(reply)]))
    }

    /// Resume the call under way, which waits for the key space, with its answer.
    pub(super) fn resume_key(&mut self, reply: KeyReply) -> Result<Ran, String> {
        let answer = key_answer(&self.lua, reply).map_err(|e| message(&e))?;
        self.run(answer)
    }

    /// The Lua state, for tests to look into.
    #[cfg(test)]
    pub(super) fn lua_for_tests(&self) -> &Lua {
        &self.lua
    }

    fn reset_budget(&mut self) {
        if let Some(mut budget) = self.lua.app_data_mut::<Budget>() {
            budget.used = 0;
        }
    }

    /// Run the call until it waits for a reply or ends; writes are gathered meanwhile.
    fn run(&mut self, mut args: MultiValue) -> Result<Ran, String> {
        loop {
            self.reset_budget();
            let Some((thread, _)) = self.call.as_ref() else { return Err("no call under way".into()) };
            let thread = thread.clone();
            let values = thread.resume::<MultiValue>(args).map_err(|e| {
                self.call = None;
                message(&e)
            })?;
            if thread.status() != ThreadStatus::Resumable {
                // A poll's value (whether the axis moves) sets only asyn's poll rate; the
                // status bits the script set say it here.
                let (_, written) = self.call.take().expect("checked above");
                return Ok(Ran::Returned { written });
            }
            let mut values = values.into_iter();
            let ours = matches!(values.next(), Some(Value::Table(t)) if t == self.token);
            if !ours {
                self.call = None;
                return Err(
                    "the script yielded outside asyn.read/write/writeread: coroutine.yield is the driver's".into()
                );
            }
            let kind = text(values.next());
            if kind == "get" || kind == "put" {
                let name = text(values.next());
                match key_access(&kind, &name, values.next()) {
                    Ok(access) => {
                        let (_, written) = self.call.as_mut().expect("checked above");
                        return Ok(Ran::Key { access, written: std::mem::take(written) });
                    }
                    Err(why) => {
                        args = key_answer(&self.lua, KeyReply::Failed(why)).map_err(|e| message(&e))?;
                        continue;
                    }
                }
            }
            let data = bytes_of(values.next());
            let terminator = bytes_of(values.next());
            let (_, written) = self.call.as_mut().expect("checked above");
            written.extend_from_slice(&data);
            if kind == "write" {
                args = MultiValue::new();
                continue;
            }
            let bytes = std::mem::take(written);
            return Ok(Ran::Exchange { bytes, terminator });
        }
    }
}

/// What `epics.get(name)` or `epics.put(name, value)` asks, or why it cannot be asked.
fn key_access(kind: &str, name: &str, value: Option<Value>) -> Result<KeyAccess, String> {
    let name = KeyName::parse(name).map_err(|e| e.to_string())?;
    if kind == "get" {
        return Ok(KeyAccess::Get(name));
    }
    let value = match value {
        Some(Value::Integer(n)) => KeyValue::Number(n as f64),
        Some(Value::Number(n)) if n.is_finite() => KeyValue::Number(n),
        Some(Value::Number(n)) => return Err(format!("{n} is not a value to write")),
        Some(Value::Boolean(b)) => KeyValue::Number(f64::from(u8::from(b))),
        Some(Value::String(text)) => KeyValue::Text(text.to_string_lossy()),
        other => {
            return Err(format!("a number or a string to write, not {}", other.map_or("nothing", |v| v.type_name())))
        }
    };
    Ok(KeyAccess::Put(name, value))
}

/// The values `epics.get`/`epics.put` are resumed with.
fn key_answer(lua: &Lua, reply: KeyReply) -> mlua::Result<MultiValue> {
    Ok(match reply {
        KeyReply::Value(KeyValue::Number(n)) => MultiValue::from_iter([Value::Boolean(true), Value::Number(n)]),
        KeyReply::Value(KeyValue::Text(text)) => {
            MultiValue::from_iter([Value::Boolean(true), Value::String(lua.create_string(text)?)])
        }
        KeyReply::Failed(why) => MultiValue::from_iter([Value::Boolean(false), Value::String(lua.create_string(why)?)]),
    })
}

/// A launch file's macro value as Lua sees it.
fn lua_value(lua: &Lua, value: &MacroValue) -> mlua::Result<Value> {
    Ok(match value {
        MacroValue::Text(text) => Value::String(lua.create_string(text)?),
        MacroValue::Integer(n) => Value::Integer(*n),
        MacroValue::Number(n) => Value::Number(*n),
        MacroValue::Boolean(b) => Value::Boolean(*b),
    })
}

/// `asyn.set*Param`/`get*Param(port, [addr,] name[, value])`: the port and the address are
/// this axis's (each axis has its own Lua state); a name asyn does not know is ignored.
fn params(lua: &Lua, args: Variadic<Value>) -> mlua::Result<Value> {
    let mut args = args.into_iter();
    let operation = text(args.next());
    let kind = text(args.next());
    let _port = args.next();
    let rest: Vec<Value> = args.collect();
    let (name, value) = match rest.as_slice() {
        [Value::String(name), value @ ..] => (name.to_string_lossy(), value.first().cloned()),
        [_addr, Value::String(name), value @ ..] => (name.to_string_lossy(), value.first().cloned()),
        _ => {
            return Err(mlua::Error::runtime(format!(
                "asyn.{operation}{kind}Param: give (port, [addr,] name{})",
                if operation == "set" { ", value" } else { "" }
            )))
        }
    };
    let mut params = lua.app_data_mut::<Params>().expect("set at creation");
    let bit = STATUS_PARAMS.iter().find(|(n, _)| *n == name).map(|(_, bit)| *bit);
    if operation == "get" {
        return Ok(match bit {
            Some(bit) => Value::Integer(i64::from(params.msta & bit != 0)),
            None if kind == "integer" => Value::Integer(params.integers.get(&name).copied().unwrap_or(0)),
            None => Value::Number(params.double(&name)),
        });
    }
    let number = match value {
        Some(Value::Integer(n)) => n as f64,
        Some(Value::Number(n)) => n,
        Some(Value::Boolean(b)) => f64::from(u8::from(b)),
        other => {
            let got = other.map_or("nothing", |v| v.type_name());
            return Err(mlua::Error::runtime(format!("asyn.set{kind}Param {name}: the value is {got}, not a number")));
        }
    };
    match bit {
        Some(bit) => {
            let mut bits = params.msta;
            crate::protocol::set_bit(&mut bits, bit, number != 0.0);
            params.msta = bits;
        }
        None if kind == "integer" => {
            params.integers.insert(name, number as i64);
        }
        None => {
            params.doubles.insert(name, number);
        }
    }
    Ok(Value::Nil)
}

fn text(value: Option<Value>) -> String {
    match value {
        Some(Value::String(s)) => s.to_string_lossy(),
        _ => String::new(),
    }
}

fn bytes_of(value: Option<Value>) -> Vec<u8> {
    match value {
        Some(Value::String(s)) => s.as_bytes().to_vec(),
        _ => Vec::new(),
    }
}

/// A Lua error as one line: the script's `file:line: what`, without the traceback.
fn message(error: &mlua::Error) -> String {
    let mut error = error;
    while let mlua::Error::CallbackError { cause, .. } = error {
        error = cause;
    }
    let text = match error {
        mlua::Error::RuntimeError(text) | mlua::Error::SyntaxError { message: text, .. } => text.clone(),
        other => other.to_string(),
    };
    text.lines().next().unwrap_or_default().to_string()
}

impl ScriptError {
    fn load(source: &ScriptSource, error: &mlua::Error) -> Self {
        ScriptError::Load { script: source.path.clone(), message: message(error) }
    }
}
