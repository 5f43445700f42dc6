use super::*;
use crate::script_source::MacroValue;
use zmotor_msgs::bits::msta;

fn source(text: &str) -> ScriptSource {
    ScriptSource {
        path: "scripts/test.lua".into(),
        text: text.into(),
        driver: "MC1".into(),
        macros: [("PORT".to_string(), MacroValue::Text("IP1".into()))].into(),
        ..ScriptSource::default()
    }
}

fn script(text: &str) -> Script {
    let options = ProtocolOptions { script: Some(source(text)), ..ProtocolOptions::default() };
    let mut script = Script::new(&options);
    assert!(script.init(&[0, 1]).is_empty(), "a script sends nothing at connection");
    script
}

/// What the layer does with a call's first request: prepare it as it goes out.
fn start(script: &mut Script, channel: usize, command: &DriverCommand) -> Prepared<ScriptStep> {
    let mut requests = script.command(channel, command).expect("a script takes every command");
    assert_eq!(requests.len(), 1, "a call is one request until it runs");
    script.prepare(requests.remove(0))
}

/// The reply `text` to `request`: its events, and the next request if the call goes on.
fn answer(
    script: &mut Script,
    request: &Request<ScriptStep>,
    text: &str,
) -> (Vec<ReplyEvent<ScriptStep>>, Option<Request<ScriptStep>>) {
    let mut events = script.reply(request, text.as_bytes()).expect("a reply to the call under way");
    let next = events.iter().position(|e| matches!(e, ReplyEvent::FollowUp(_))).map(|at| match events.remove(at) {
        ReplyEvent::FollowUp(mut requests) => requests.remove(0),
        _ => unreachable!(),
    });
    (events, next)
}

fn text(request: &Request<ScriptStep>) -> String {
    String::from_utf8_lossy(&request.bytes).into_owned()
}

const POLLING: &str = r#"
InTerminator = "\r\n"
OutTerminator = "\r"
function poll()
  asyn.write(string.format("%d POS?", AXIS + 1), PORT)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", tonumber(asyn.read(PORT)))
  local status = tonumber(asyn.writeread(string.format("%d ST?", AXIS + 1), PORT))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", status & 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", (status & 1) ~ 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HOMED", 1)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return status & 1 == 0
end
function move(position, relative, minVel, maxVel, accel)
  asyn.write(string.format("%d VEL %g", AXIS + 1, maxVel), PORT)
  asyn.writeread(string.format("%d %s %d", AXIS + 1, relative and "MR" or "MV", position), PORT)
end
"#;

#[test]
fn a_poll_is_exchanges_in_turn_and_its_parameters_are_the_status() {
    let mut script = script(POLLING);
    let first = start(&mut script, 1, &DriverCommand::Poll);
    let request = first.request.expect("the poll asks");
    assert!(first.events.is_empty());
    assert_eq!((text(&request).as_str(), request.answered), ("2 POS?\r", true), "a write then a read is one exchange");
    assert_eq!(script.frame(b"1250\r\n2"), Frame::Complete(6), "the reply ends at InTerminator");
    let (events, next) = answer(&mut script, &request, "1250\r\n");
    assert!(events.is_empty());
    let next = next.expect("the poll goes on");
    assert_eq!(text(&next), "2 ST?\r");
    let (events, after) = answer(&mut script, &next, "1\r\n");
    assert!(after.is_none(), "the poll is over");
    let status = DeviceStatus { position: 1250.0, msta: msta::DONE | msta::HOMED, ..DeviceStatus::default() };
    assert_eq!(events, vec![ReplyEvent::Status { channel: 1, status }]);
}

#[test]
fn a_move_passes_the_record_s_numbers_as_motor_script_motor_does() {
    let mut script = script(POLLING);
    let command = DriverCommand::Move {
        position: 1500.0,
        relative: false,
        min_velocity: 10.0,
        max_velocity: 400.5,
        acceleration: 1000.0,
    };
    let request = start(&mut script, 0, &command).request.expect("the move sends");
    assert_eq!(text(&request), "1 VEL 400.5\r1 MV 1500\r");
    let (events, next) = answer(&mut script, &request, "OK\r\n");
    assert!(events.is_empty() && next.is_none());
    assert_eq!(Script::purpose(request.step), Purpose::Command { channel: 0 });
}

#[test]
fn a_function_the_script_lacks_succeeds_without_a_word() {
    let mut script = script(POLLING);
    let prepared = start(
        &mut script,
        0,
        &DriverCommand::Home { forward: true, min_velocity: 1.0, max_velocity: 2.0, acceleration: 3.0 },
    );
    assert!(prepared.request.is_none() && prepared.events.is_empty());
}

#[test]
fn a_write_that_ends_a_call_goes_unanswered() {
    let mut script = script("OutTerminator = '\\n'\nfunction stop(a) asyn.write('AB', PORT) end");
    let request = start(&mut script, 0, &DriverCommand::Stop { acceleration: 1.0 }).request.expect("the stop sends");
    assert_eq!((text(&request).as_str(), request.answered), ("AB\n", false));
}

#[test]
fn a_script_error_refuses_the_command_naming_the_file_and_line() {
    let mut script = script("function move(p)\n  local x = nil\n  return x.field\nend");
    let command =
        DriverCommand::Move { position: 1.0, relative: false, min_velocity: 1.0, max_velocity: 2.0, acceleration: 3.0 };
    let prepared = start(&mut script, 0, &command);
    assert!(prepared.request.is_none());
    let [ReplyEvent::Refused(error)] = prepared.events.as_slice() else { panic!("{:?}", prepared.events) };
    assert_eq!(error.channel, Some(0));
    assert!(error.meaning.starts_with("move() failed: scripts/test.lua:3:"), "{}", error.meaning);
}

#[test]
fn a_poll_that_fails_is_a_controller_error_and_the_next_poll_runs_again() {
    let mut script = script("n = 0\nfunction poll()\n  n = n + 1\n  if n == 1 then error('first') end\nend");
    let prepared = start(&mut script, 0, &DriverCommand::Poll);
    let [ReplyEvent::ControllerError(error)] = prepared.events.as_slice() else { panic!("{:?}", prepared.events) };
    assert!(error.meaning.contains("scripts/test.lua:4: first"), "{}", error.meaning);
    let prepared = start(&mut script, 0, &DriverCommand::Poll);
    assert!(matches!(prepared.events.as_slice(), [ReplyEvent::Status { channel: 0, .. }]), "{:?}", prepared.events);
}

#[test]
fn a_script_that_never_yields_is_stopped_by_its_instruction_budget() {
    let mut script = script("function poll()\n  while true do end\nend\nfunction stop() asyn.write('ST') end");
    let prepared = start(&mut script, 0, &DriverCommand::Poll);
    let [ReplyEvent::ControllerError(error)] = prepared.events.as_slice() else { panic!("{:?}", prepared.events) };
    assert!(
        error.meaning.contains("scripts/test.lua:2:") && error.meaning.contains("instructions"),
        "{}",
        error.meaning
    );
    let stop = start(&mut script, 0, &DriverCommand::Stop { acceleration: 1.0 });
    assert_eq!(stop.request.map(|r| r.bytes), Some(b"ST".to_vec()), "the axis still takes calls");
}

#[test]
fn the_sandbox_has_no_os_io_or_files_and_requires_only_the_script_directory() {
    let text = r#"
      seen = { os = type(os), io = type(io), dofile = type(dofile), debug = type(debug) }
      json = require("json")
      ok, why = pcall(require, "../secret")
    "#;
    let mut with_module = source(text);
    with_module.modules.insert("json".into(), "return { encode = function() return '{}' end }".into());
    let axis = AxisLua::new(&with_module, 0).expect("loads");
    for name in ["os", "io", "dofile", "debug"] {
        assert_eq!(axis.global_text(&format!("seen.{name}")), "nil", "{name}");
    }
    assert_eq!(axis.global_text("type(json.encode)"), "function");
    assert_eq!(axis.global_text("ok"), "false");
    assert!(axis.global_text("why").contains("not found"), "{}", axis.global_text("why"));
}

#[test]
fn driver_axis_and_macros_are_globals_and_asyn_is_also_required() {
    let mut given = source("asyn = require('asyn')\nIdlePollPeriod = 2.5\nForcedFastPolls = 3\nfunction poll() end");
    given.axis_macros.insert(1, [("OPEN_LOOP".to_string(), MacroValue::Text("YES".into()))].into());
    let axis = AxisLua::new(&given, 1).expect("loads");
    assert_eq!(axis.global_text("DRIVER .. ' ' .. AXIS .. ' ' .. PORT .. ' ' .. OPEN_LOOP"), "MC1 1.0 IP1 YES");
    assert_eq!(axis.global_text("math.type(AXIS)"), "float", "AXIS is lua_pushnumber's");
    let settings = ScriptSettings::of(&given).expect("loads");
    assert_eq!(settings, ScriptSettings { idle_poll: Some(2.5), moving_poll: None, forced_fast_polls: Some(3.0) });
}

#[test]
fn a_script_that_does_not_load_is_refused_with_its_line() {
    let error = ScriptSettings::of(&source("function move() end")).expect_err("no poll");
    assert_eq!(
        error.to_string(),
        "the script scripts/test.lua does not load: defines no function poll(): its axes could never report a \
         position or the end of a motion"
    );
    let error = ScriptSettings::of(&source("x = 1\nfunction move(\n")).expect_err("a syntax error");
    assert!(
        matches!(&error, ScriptError::Load { script, message } if script == "scripts/test.lua" && message.contains("scripts/test.lua:3:")),
        "{error}"
    );
    let error = ScriptSettings::of(&source("local t = nil\nt.x = 1")).expect_err("an error at the top level");
    assert!(error.to_string().contains("scripts/test.lua:2:"), "{error}");
    let missing = Script::new(&ProtocolOptions::default()).prepare_poll();
    assert!(
        matches!(missing.as_slice(), [ReplyEvent::ControllerError(e)] if e.meaning.contains("no script")),
        "{missing:?}"
    );
}

#[test]
fn a_reply_to_a_call_given_up_is_not_taken() {
    let mut script = script(POLLING);
    let poll = start(&mut script, 0, &DriverCommand::Poll).request.expect("asks");
    // The layer gave the poll up (a stop came): the stop's call starts instead.
    let _ = start(&mut script, 0, &DriverCommand::Stop { acceleration: 1.0 });
    assert!(script.reply(&poll, b"5\r\n").is_err());
}

#[test]
fn without_an_input_terminator_a_reply_is_one_json_value() {
    let script = script("InTerminator = ''");
    assert_eq!(script.frame(b" {\"a\""), Frame::Junk(1));
    assert_eq!(script.frame(b"{\"a\":\"}\\\"\",\"b\":[1,{}]}{\"next"), Frame::Complete(22));
    assert_eq!(script.frame(b"{\"a\":["), Frame::Incomplete);
    assert_eq!(script.frame(b"OK"), Frame::Complete(2));
}

#[test]
fn a_yield_of_the_script_s_own_is_an_error_not_an_exchange() {
    let mut script = script("function poll() coroutine.yield('hello') end");
    let prepared = start(&mut script, 0, &DriverCommand::Poll);
    assert!(matches!(prepared.events.as_slice(), [ReplyEvent::ControllerError(e)] if e.meaning.contains("yielded")));
}

#[test]
fn a_raw_command_is_refused() {
    let mut script = script("");
    assert!(script.command(0, &DriverCommand::Raw { text: "X".into() }).is_err());
}

impl Script {
    fn prepare_poll(&mut self) -> Vec<ReplyEvent<ScriptStep>> {
        let mut requests = self.poll(&[0]);
        self.prepare(requests.remove(0)).events
    }
}

impl AxisLua {
    /// A Lua expression's value in this state, as text.
    fn global_text(&self, expression: &str) -> String {
        self.lua_for_tests().load(format!("return tostring({expression})")).eval::<String>().expect("evaluates")
    }
}

#[test]
fn a_stop_gives_up_a_call_of_its_axis_that_is_still_exchanging() {
    let mut script = script(
        "InTerminator = '\\n'\nOutTerminator = '\\n'\n\
         function move(p) repeat until asyn.writeread('ST?', PORT) == 'done' end\n\
         function stop(a) asyn.writeread('AB', PORT) end\n\
         function setPosition(p) asyn.writeread('SP', PORT) asyn.writeread('SP?', PORT) end",
    );
    let stop = DriverCommand::Stop { acceleration: 1.0 };
    let command =
        DriverCommand::Move { position: 1.0, relative: false, min_velocity: 1.0, max_velocity: 2.0, acceleration: 3.0 };
    let mut asking = start(&mut script, 0, &command).request.expect("the move asks");
    for _ in 0..3 {
        asking = answer(&mut script, &asking, "moving\n").1.expect("the move asks until its motion ends");
    }
    // Another axis's stop leaves the call be.
    let _other = script.command(1, &stop).expect("taken");
    asking = answer(&mut script, &asking, "moving\n").1.expect("the move goes on");
    let mut own = script.command(0, &stop).expect("taken");
    let (events, next) = answer(&mut script, &asking, "moving\n");
    assert!(events.is_empty() && next.is_none(), "the move ends at the reply in flight: {events:?} {next:?}");
    let stopping = script.prepare(own.remove(0)).request.expect("the stop sends");
    assert_eq!(text(&stopping), "AB\n");
    assert!(answer(&mut script, &stopping, "OK\n").1.is_none(), "the stop is over");
    // A setting is no motion a stop ends: it is carried out whole.
    let setting = start(&mut script, 0, &DriverCommand::SetPosition { position: 5.0 }).request.expect("it sets");
    let _stop = script.command(0, &stop).expect("taken");
    let asking = answer(&mut script, &setting, "OK\n").1.expect("the setting goes on");
    assert_eq!(text(&asking), "SP?\n");
}
