--[[
  New Focus (Newport) 8742 open-loop picomotor controller, four axes, over Ethernet (Telnet,
  port 23), for zmotor's script driver (the motorScriptMotor interface: copy this file to add a
  family).

  Bytes as the 8742 user's manual gives them and EPICS's motorNewFocus (874xMotorDriver.cpp)
  sends them: "<axis> <command> [value]" ended by CR; commands are not answered, queries answer
  one line ended by CR LF. AXIS 0 is the controller's axis 1. The controller greets a Telnet
  connection with option bytes, which are not part of any answer.

  - A move sets AC and VA, then PA/PR; a jog AC, VA, MV+ or MV-; ST stops; DH defines the
    position (a picomotor has no encoder and no switch: its position is the steps it counted).
  - A speed outside 1 to 2,000 steps/s or an acceleration outside 1 to 200,000 steps/s^2 is
    refused before anything is sent. After every command the error queue is read (TB?): a
    command the controller refused (a motion or a position set while moving) is reported with
    the controller's words, never left unseen.
  - A home search is refused: the 8742 has neither home nor limit switches (set the position).
  - A poll reads TP? (position) and MD? (motion done).
--]]

InTerminator = "\r\n"
OutTerminator = "\r"

IdlePollPeriod = 1.0
MovingPollPeriod = 0.1
ForcedFastPolls = 2

local function axis()
  return math.floor(AXIS) + 1
end

-- A line without the Telnet option bytes (IAC sequences) the controller may send first.
local function clean(reply)
  if reply == nil then error("no answer") end
  return (string.gsub(reply, "\255[\251-\254].", ""))
end

-- The error queue's oldest entry: an error when there is one.
local function check(what)
  local code, text = string.match(clean(asyn.writeread("TB?", PORT)), "^%s*(%d+)%s*,%s*(.-)%s*$")
  if code == nil then
    error(string.format("%s: TB? was not answered as the manual says", what))
  elseif tonumber(code) ~= 0 then
    error(string.format("%s refused: %s (error %s)", what, text, code))
  end
end

local function say(format, ...)
  local command = string.format("%d " .. format, axis(), ...)
  asyn.write(command, PORT)
  return command
end

-- A whole number in [low, high], or an error naming it: the controller's ranges are refused
-- here, never clamped.
local function within(what, value, low, high, unit)
  local n = math.floor(math.abs(value) + 0.5)
  if n < low or n > high then
    error(string.format("%s %s %s is outside the 8742's %d to %d", what, tostring(value), unit, low, high))
  end
  return n
end

local function speeds(maxVel, accel)
  say("AC %d", within("acceleration", accel, 1, 200000, "steps/s^2"))
  say("VA %d", within("speed", maxVel, 1, 2000, "steps/s"))
end

function move(position, relative, minVel, maxVel, accel)
  speeds(maxVel, accel)
  local steps = math.floor(position + 0.5)
  if math.type(steps) ~= "integer" then error(string.format("%s is no step count", tostring(position))) end
  check(say(relative and "PR %d" or "PA %d", steps))
end

function moveVelocity(minVel, maxVel, accel)
  speeds(maxVel, accel)
  check(say(maxVel >= 0 and "MV +" or "MV -"))
end

function home(minVel, maxVel, accel, forwards)
  error("the 8742 has no home switch: set the position instead (it counts steps from there)")
end

function stop(accel)
  check(say("ST"))
end

function setPosition(position)
  check(say("DH %d", math.floor(position + 0.5)))
end

local last_position = nil

function poll()
  local position = tonumber(string.match(clean(asyn.writeread(string.format("%d TP?", axis()), PORT)), "[-+]?%d+"))
  local done = tonumber(string.match(clean(asyn.writeread(string.format("%d MD?", axis()), PORT)), "%d"))
  if position == nil or done == nil then
    error("a status the controller should not give")
  end
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", position)
  if last_position ~= nil and position ~= last_position then
    asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DIRECTION", position > last_position and 1 or 0)
  end
  last_position = position
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", done)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", 1 - done)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return done == 0
end
