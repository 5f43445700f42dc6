--[[
  Faulhaber motion controllers of the MCDC 300x / MCBL 300x family (and the drives with the
  same ASCII command set) on RS-232, several drives on one line, for zmotor's script driver (the
  motorScriptMotor interface: copy this file to add a family).

  Bytes as Faulhaber's communication and function manual (RS232) gives them and as EPICS's
  motorFaulhaber (devMCDC2805.cc, drvMCDC2805.cc) sends them: "<node><mnemonic>[argument]"
  ended by CR, the node number first, replies ended by CR LF. AXIS is the node number (1 to
  255; 0 would reach every drive on the line at once, and is refused).

  - Every command is sent in answer mode 2 (ANSW2, set again before each command, as a drive
    powered up since may have forgotten it): the drive confirms it with OK, or answers why
    not ("Unknown command", "Invalid parameter", "Command not available", "Overtemperature -
    drive disabled"), which is the axis's problem. motorFaulhaber sends commands unconfirmed.
  - Speeds are rpm and accelerations revolutions/s^2: a record's steps (encoder increments) are
    turned into revolutions with ENCRES increments a revolution, a macro, else read once from
    the drive (GENCRES); this script never writes ENCRES (motorFaulhaber writes the record's
    SREV there, which changes how the drive measures speed).
  - A move sets SP, AC and DEC, loads the absolute target (LA; a relative move is from where
    the drive is, read with POS) and starts it (M). A jog sets SP and AC, then V at a signed
    speed; a stop is V0 (decelerating at DEC), as motorFaulhaber's. A home sets HOSP (its sign
    the direction) and starts the homing sequence the lab configured in the drive (GOHOSEQ).
    A position set is HO. A speed under 1 rpm is refused, never rounded up.
  - A poll reads OST (the operation status: homing running, overtemperature, deviation error,
    overvoltage, the switch inputs, position attained), GN (the speed, rpm), then POS: read
    after them, the position of the poll that finds a motion over is the final one. The
    inputs wired to the home switch and the limit switches are macros (HOME_INPUT,
    HIGH_LIMIT_INPUT, LOW_LIMIT_INPUT: status inputs 1 to 5, default 1, 2 and 3).
  - A positioning is done once the drive reports the position attained; a motion that stands
    still for three polls without attaining it (blocked, disabled) is done with a problem.
--]]

InTerminator = "\r\n"
OutTerminator = "\r"

IdlePollPeriod = 1.0
MovingPollPeriod = 0.1
ForcedFastPolls = 2

-- OST bits (the manual's "operation status").
local HOMING_RUNNING = 0
local DEVIATION_ERROR = 5
local OVERVOLTAGE = 6
local OVERTEMPERATURE = 7
local FIRST_INPUT = 8 -- status input 1; inputs 2 to 5 follow
local POSITION_ATTAINED = 16

local function node()
  local n = math.floor(AXIS)
  if n < 1 or n > 255 then
    error(string.format("AXIS %d is not a node number (1 to 255; 0 reaches every drive)", n))
  end
  return n
end

local function bit(word, n)
  return (word >> n) & 1
end

local function input_bit(macro, default)
  local input = math.floor(macro or default)
  if input < 1 or input > 5 then
    error(string.format("status input %d does not exist (1 to 5)", input))
  end
  return FIRST_INPUT + input - 1
end

-- A query's answer, as the drive gave it.
local function ask(query)
  local reply = asyn.writeread(string.format("%d%s", node(), query), PORT)
  if reply == nil or reply == "" then
    error(string.format("no answer to %d%s", node(), query))
  end
  return reply
end

local function ask_number(query)
  local reply = ask(query)
  local value = tonumber(reply)
  if value == nil then
    error(string.format("%d%s was answered %q, not a number", node(), query, reply))
  end
  return value
end

-- A command, confirmed by OK; an error naming the drive's answer otherwise.
local function say(format, ...)
  local command = string.format("%d" .. format, node(), ...)
  local reply = asyn.writeread(command, PORT)
  if reply ~= "OK" then
    error(string.format("the drive refused %s: %s", command, tostring(reply)))
  end
end

local increments_per_revolution = nil

local function encres()
  if ENCRES ~= nil then return ENCRES end
  if increments_per_revolution == nil then
    increments_per_revolution = ask_number("GENCRES")
    if increments_per_revolution <= 0 then
      error(string.format("the drive's ENCRES is %s", tostring(increments_per_revolution)))
    end
  end
  return increments_per_revolution
end

-- Steps/s as whole rpm, at least 1 (a slower speed is refused, not rounded up).
local function rpm(what, steps_per_second)
  local value = math.floor(math.abs(steps_per_second) * 60 / encres() + 0.5)
  if value < 1 then
    error(string.format("%s %s steps/s is under 1 rpm, the drive's slowest", what, tostring(steps_per_second)))
  end
  return value
end

-- Steps/s^2 as whole revolutions/s^2, at least 1.
local function per_s2(accel)
  return math.max(math.floor(math.abs(accel) / encres() + 0.5), 1)
end

local function increments(what, value)
  local n = math.floor(value + 0.5)
  if math.type(n) ~= "integer" or n < -2147483648 or n > 2147483647 then
    error(string.format("%s %s is not an increment count the drive takes", what, tostring(value)))
  end
  return n
end

-- The answer mode in which every command is confirmed.
local function confirmed()
  say("ANSW2")
end

local positioning = false
local homing = false
local homed = 0
local missed = 0 -- the last positioning ended short of its target
local still = 0
local last_position = nil

local function started()
  still, missed = 0, 0
end

function move(position, relative, minVel, maxVel, accel)
  local speed = rpm("speed", maxVel)
  local target = position
  if relative then
    target = ask_number("POS") + position
  end
  target = increments("position", target)
  confirmed()
  say("SP%d", speed)
  say("AC%d", per_s2(accel))
  say("DEC%d", per_s2(accel))
  say("LA%d", target)
  say("M")
  positioning, homing = true, false
  started()
end

function moveVelocity(minVel, maxVel, accel)
  local speed = rpm("jog speed", maxVel)
  if maxVel < 0 then speed = -speed end
  confirmed()
  say("SP%d", math.abs(speed))
  say("AC%d", per_s2(accel))
  say("V%d", speed)
  positioning, homing = false, false
  started()
end

function home(minVel, maxVel, accel, forwards)
  local speed = rpm("home speed", maxVel)
  if not forwards then speed = -speed end
  confirmed()
  say("AC%d", per_s2(accel))
  say("HOSP%d", speed)
  say("GOHOSEQ")
  positioning, homing, homed = false, true, 0
  started()
end

function stop(accel)
  confirmed()
  say("V0")
  positioning, homing = false, false
end

function setPosition(position)
  confirmed()
  say("HO%d", increments("position", position))
end

function setClosedLoop(on)
  confirmed()
  if on then say("EN") else say("DI") end
end

function poll()
  local status = math.floor(ask_number("OST"))
  local speed = ask_number("GN")
  local position = ask_number("POS")
  local running_home = bit(status, HOMING_RUNNING) == 1
  local attained = bit(status, POSITION_ATTAINED) == 1
  local high = bit(status, input_bit(HIGH_LIMIT_INPUT, 2))
  local low = bit(status, input_bit(LOW_LIMIT_INPUT, 3))

  if speed == 0 and position == last_position then
    still = still + 1
  else
    still = 0
  end
  local stalled = still >= 3
  local moving = speed ~= 0 or running_home or (positioning and not attained and not stalled)
  if not moving then
    if positioning and not attained and high == 0 and low == 0 then missed = 1 end
    if homing and high == 0 and low == 0 then homed = 1 end
    positioning, homing = false, false
  end
  local problem = bit(status, DEVIATION_ERROR) | bit(status, OVERVOLTAGE) | bit(status, OVERTEMPERATURE) | missed

  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", position)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_ENCODER_POSITION", position)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_ACT_VELOCITY", speed * encres() / 60)
  if last_position ~= nil and position ~= last_position then
    asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DIRECTION", position > last_position and 1 or 0)
  end
  last_position = position
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", moving and 0 or 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", moving and 1 or 0)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_AT_HOME", bit(status, input_bit(HOME_INPUT, 1)))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HOMED", homed)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HIGH_LIMIT", high)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_LOW_LIMIT", low)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HAS_ENCODER", 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_PROBLEM", problem)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return moving
end
