--[[
  Kohzu SC-200 / SC-400 / SC-800 stepping motor controllers, for zmotor's script driver (the
  motorScriptMotor interface: copy this file to add a family).

  Bytes as Kohzu's SC-series communication chapter gives them and as EPICS's motorKohzu
  (drvSC800.cc, devSC800.cc) sends them: a command is STX, a three-letter mnemonic, the axis and
  its parameters separated by '/', CR LF; the controller answers every command with one line,
  "C<TAB>..." when it did it, "W<TAB>..." for a warning, "E<TAB><command><TAB><code>" when it
  refused it. AXIS 0 is the controller's axis 1.

  - Speeds are set per move with ASI (start speed, top speed, acceleration and deceleration time
    in 10 ms), then APS/RPS move on speed table 2 and answer at once (the last parameter 1);
    FRP jogs, ORG searches the origin (method 3, as motorKohzu), STP/0 decelerates to a stop
    (answered once stopped: give the controller a timeout longer than a deceleration).
  - A poll reads STR (driving, origin, limits, error), RDP (position) and system parameter 21
    (0: the motor is excited).
  - A speed outside 1..4,095,500 pulses/s is refused, never clamped; so is a position that is
    not a 32-bit pulse count.
--]]

InTerminator = "\r\n"
OutTerminator = "\r\n"

IdlePollPeriod = 1.0
MovingPollPeriod = 0.1
ForcedFastPolls = 2

local STX = "\2"
local TOP_SPEED = 4095500

local function axis()
  return math.floor(AXIS) + 1
end

-- The controller's answer to a command, as its fields; an error when it refused it.
local function send(command)
  local reply = asyn.writeread(STX .. command, PORT)
  if reply == nil then
    error(string.format("no answer to %s", command))
  end
  local fields = {}
  for field in string.gmatch(reply, "[^\t]+") do
    fields[#fields + 1] = field
  end
  if fields[1] == "E" then
    error(string.format("the controller refused %s: error %s", command, fields[3] or "?"))
  elseif fields[1] ~= "C" and fields[1] ~= "W" then
    error(string.format("%s was answered %q", command, reply))
  end
  return fields
end

local function pulses(what, value)
  local n = math.floor(value + 0.5)
  if math.type(n) ~= "integer" or n < -2147483648 or n > 2147483647 then
    error(string.format("%s %s is not a pulse count the controller takes", what, tostring(value)))
  end
  return n
end

local function speed(what, value)
  local n = math.floor(math.abs(value) + 0.5)
  if n > TOP_SPEED then
    error(string.format("%s %s pulses/s is above the controller's %d", what, tostring(value), TOP_SPEED))
  end
  return math.max(n, 1)
end

-- Start and top speed, and the ramp's time (10 ms units) from the record's acceleration.
local function set_speeds(minVel, maxVel, accel)
  local top = speed("speed", maxVel)
  local start = math.min(speed("base speed", minVel), top)
  local ramp = 0
  if accel > 0 then
    ramp = math.floor((top - start) / accel * 100 + 0.5)
  end
  send(string.format("ASI%d/%d/%d/%d/%d/0/0/0/0/0/0/0/0/0", axis(), start, top, ramp, ramp))
end

function move(position, relative, minVel, maxVel, accel)
  set_speeds(minVel, maxVel, accel)
  if relative then
    send(string.format("RPS%d/2/0/0/%d/0/0/1", axis(), pulses("distance", position)))
  else
    send(string.format("APS%d/2/0/0/%d/0/0/1", axis(), pulses("position", position)))
  end
end

function moveVelocity(minVel, maxVel, accel)
  set_speeds(minVel, maxVel, accel)
  local clockwise = 0
  if maxVel > 0 then clockwise = 1 end
  send(string.format("FRP%d/2/0/0/%d/1", axis(), clockwise))
end

function home(minVel, maxVel, accel, forwards)
  set_speeds(minVel, maxVel, accel)
  send(string.format("ORG%d/2/0/0/3/1", axis()))
end

function stop(accel)
  send(string.format("STP%d/0", axis()))
end

function setPosition(position)
  send(string.format("WRP%d/%d", axis(), pulses("position", position)))
end

function setClosedLoop(on)
  -- COF 0 excites the motor, COF 1 frees it.
  if on then send(string.format("COF%d/0", axis())) else send(string.format("COF%d/1", axis())) end
end

local last_position = nil

function poll()
  local status = send(string.format("STR1/%d", axis()))
  local position = tonumber(send(string.format("RDP%d/0", axis()))[3])
  local excited = tonumber(send(string.format("RSY%d/21", axis()))[4])
  if #status < 10 or position == nil or excited == nil then
    error("a status the controller should not give")
  end
  local driving = tonumber(status[4]) ~= 0
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", position)
  if last_position ~= nil and position ~= last_position then
    asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DIRECTION", position > last_position and 1 or 0)
  end
  last_position = position
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", driving and 0 or 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", driving and 1 or 0)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_AT_HOME", tonumber(status[6]))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HIGH_LIMIT", tonumber(status[7]))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_LOW_LIMIT", tonumber(status[8]))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_PROBLEM", tonumber(status[10]))
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_POWERED", excited == 0 and 1 or 0)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return driving
end
