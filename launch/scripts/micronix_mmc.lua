--[[
  Micronix MMC-100 / MMC-200 controllers (axis modules on one RS-232/RS-485 line), for zmotor's
  script driver (the motorScriptMotor interface: copy this file to add a family).

  Bytes as the MMC-200 manual gives them and EPICS's motorMicronix (MMC200Driver.cpp) sends
  them: "<axis><command>[value]" ended by CR; settings and motions are not answered, queries
  answer "#<value>" ended by LF CR. Positions are millimetres, speeds mm/s and mm/s^2; one
  record step is RESOLUTION millimetres (a macro, 1 nm = 0.000001 mm unless the launch file
  gives another). AXIS 0 is the controller's axis 1.

  - A move sets VEL, ACC and DEC, then MVA/MVR; a jog JAC then JOG at a percentage of the
    axis's top speed (VMX?, read once); a home HCG (1 forward) then HOM; STP stops.
  - The MMC sets only position 0 (ZRO): another position is refused, as nothing would set it.
  - A poll reads STA? (limits, stopped, error), POS? (theoretical and encoder positions), MOT?
    (the motor's power) and HOM? (homed since power-up; motorMicronix does not read it). An
    error flagged by STA? is read and cleared with ERR?, shown as the axis's problem and in the
    node's log. motorMicronix reads POS? first; read after STA?, the position of the poll that
    finds a motion over is the final one (DMOV 1 comes with it).
  - A jog faster than the axis's top speed is refused, never clamped; so is a speed or an
    acceleration too small to be written with the MMC's three decimals.
--]]

InTerminator = "\n\r"
OutTerminator = "\r"

IdlePollPeriod = 1.0
MovingPollPeriod = 0.1
ForcedFastPolls = 2

local function axis()
  return math.floor(AXIS) + 1
end

local function mm_per_step()
  return RESOLUTION or 0.000001
end

local function say(format, ...)
  asyn.write(string.format("%d" .. format, axis(), ...), PORT)
end

-- A query's value, without its '#'.
local function ask(query)
  local reply = asyn.writeread(string.format("%d%s", axis(), query), PORT)
  local value = reply and string.match(reply, "#(.*)")
  if value == nil then
    error(string.format("%d%s was answered %q", axis(), query, tostring(reply)))
  end
  return value
end

-- A setting as the MMC takes it (three decimals, above 0): one that would be 0.000 there is
-- refused, never raised to the least the controller takes.
local function setting(name, value, unit)
  local text = string.format("%.3f", value)
  if tonumber(text) <= 0 then
    error(string.format("%s %.6f %s is below the least the MMC takes, 0.001 %s", name, value, unit, unit))
  end
  return text
end

local function speeds(maxVel, accel)
  local velocity = setting("a speed of", math.abs(maxVel) * mm_per_step(), "mm/s")
  local acceleration = setting("an acceleration of", accel * mm_per_step(), "mm/s^2")
  say("VEL%s", velocity)
  say("ACC%s", acceleration)
  say("DEC%s", acceleration)
end

function move(position, relative, minVel, maxVel, accel)
  speeds(maxVel, accel)
  if relative then
    say("MVR%.6f", position * mm_per_step())
  else
    say("MVA%.6f", position * mm_per_step())
  end
end

local top_speed = nil

function moveVelocity(minVel, maxVel, accel)
  top_speed = top_speed or tonumber(ask("VMX?"))
  local percent = maxVel * mm_per_step() / top_speed * 100
  if math.abs(percent) > 100 then
    error(string.format("a jog at %.3f mm/s is faster than the axis's top speed, %.3f mm/s", math.abs(maxVel) * mm_per_step(), top_speed))
  end
  local acceleration = setting("a jog acceleration of", accel * mm_per_step(), "mm/s^2")
  local speed = setting("a jog at", math.abs(percent), "% of the top speed")
  say("JAC%s", acceleration)
  say("JOG%s%s", percent < 0 and "-" or "", speed)
end

function home(minVel, maxVel, accel, forwards)
  speeds(maxVel, accel)
  say("HCG%d", forwards and 1 or 0)
  say("HOM")
end

function stop(accel)
  say("STP")
end

function setPosition(position)
  if position ~= 0 then
    error("the MMC sets only position 0 (ZRO)")
  end
  say("ZRO")
end

function setClosedLoop(on)
  say("MOT%d", on and 1 or 0)
end

-- Millimetres as steps, to a thousandth of a step (the controller prints six decimals).
local function steps(mm)
  return math.floor(tonumber(mm) / mm_per_step() * 1000 + 0.5) / 1000
end

local last_position = nil

function poll()
  local status = tonumber(ask("STA?"))
  local theoretical, encoder = string.match(ask("POS?"), "^%s*([-%d.]+),([-%d.]+)")
  local powered = tonumber(ask("MOT?"))
  local homed = tonumber(ask("HOM?"))
  if theoretical == nil or status == nil or powered == nil or homed == nil then
    error("a status the controller should not give")
  end
  local problem = 0
  if status & 0x80 ~= 0 then
    print(string.format("axis %d: %s", axis(), ask("ERR?")))
    problem = 1
  end
  local done = status & 0x8 ~= 0
  local position = steps(theoretical)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", position)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_ENCODER_POSITION", steps(encoder))
  if last_position ~= nil and position ~= last_position then
    asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DIRECTION", position > last_position and 1 or 0)
  end
  last_position = position
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", done and 1 or 0)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", done and 0 or 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HIGH_LIMIT", status & 0x2)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_LOW_LIMIT", status & 0x1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_POWERED", powered)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HOMED", homed)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_PROBLEM", problem)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return not done
end
