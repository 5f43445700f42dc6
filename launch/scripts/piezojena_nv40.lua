--[[
  piezosystem jena NV40/3 CLE, a three-channel piezo amplifier with closed-loop control, on an
  RS-232 line (19,200 baud, XON/XOFF), for zmotor's script driver (the motorScriptMotor
  interface: copy this file to add a family).

  Bytes as piezosystem jena's own library (psj-lib) and its Micro-Manager adapter send and read
  them: "<command>,<channel>[,<value>]" ended by CR; every command is answered, XOFF, the answer's
  lines each ended by CR LF, XON ("ErrorCode,<n>" when refused). Channels are numbered from 0,
  as the device numbers them: AXIS is the channel.

  - Positions are micrometres in closed loop; one record step is RESOLUTION micrometres (a macro,
    0.001 = 1 nm unless the launch file gives another). A target outside the stage's 0..100 um
    is refused, never clamped.
  - A move takes the channel under serial control (setk) with the loop closed (cloop), then
    sets the target (set). The stage settles in milliseconds: a move is done when the position
    read is within TOLERANCE steps of the target (a macro, 2 unless given), or has not changed
    for three polls (then the axis shows a problem: the target was not reached).
  - A piezo has no speed of its own, no switches and no home: a jog goes to the end of the
    range (or the record's soft limit, when it gave one), a stop sets the target to where the
    stage is, a home is refused.
  - A poll reads stat (whether the loop is closed: MSTA's closed-loop bit), rk (the position,
    in micrometres with the loop closed; in open loop it reads volts, and the position shown
    stays the last one measured) and ERROR (the channel's fault word: a problem).
--]]

InTerminator = "\17"    -- XON ends every answer
OutTerminator = "\r"

IdlePollPeriod = 1.0
MovingPollPeriod = 0.05
ForcedFastPolls = 2

local TRAVEL_UM = 100.0

local function channel()
  return math.floor(AXIS)
end

local function um_per_step()
  return RESOLUTION or 0.001
end

-- The answer to a command, without XOFF and line ends; an error when the device refused it.
local function send(command)
  local reply = asyn.writeread(command, PORT)
  if reply == nil then error(string.format("no answer to %s", command)) end
  local text = string.gsub(reply, "[\19\r\n]+", " ")
  local code = string.match(text, "ErrorCode,(%d+)")
  if code then
    error(string.format("the NV40 refused %s: error %s", command, code))
  end
  return text
end

local target = nil
local unchanged = 0
local last_position = nil

local function go_to(um)
  if um < 0 or um > TRAVEL_UM then
    error(string.format("%.4f um is outside the stage's 0 to %g um", um, TRAVEL_UM))
  end
  send(string.format("setk,%d,1", channel()))
  send(string.format("cloop,%d,1", channel()))
  send(string.format("set,%d,%.3f", channel(), um))
  target = um / um_per_step()
  unchanged = 0
end

local function position_um()
  local value = string.match(send(string.format("rk,%d", channel())), "rk,%d+,([-%d.]+)")
  if value == nil then error("rk was not answered with a position") end
  return tonumber(value)
end

function move(position, relative, minVel, maxVel, accel)
  local steps = position
  if relative then
    steps = position_um() / um_per_step() + position
  end
  go_to(steps * um_per_step())
end

-- The record's soft limits, in steps, as it last gave them.
local high_limit, low_limit = nil, nil

function setHighLimit(position) high_limit = position end
function setLowLimit(position) low_limit = position end

function moveVelocity(minVel, maxVel, accel)
  if maxVel >= 0 then
    go_to(math.min(TRAVEL_UM, (high_limit or math.huge) * um_per_step()))
  else
    go_to(math.max(0, (low_limit or -math.huge) * um_per_step()))
  end
end

function home(minVel, maxVel, accel, forwards)
  error("a piezo stage has no home: move it to a position instead")
end

function stop(accel)
  go_to(position_um())
end

function poll()
  local status = tonumber(string.match(send(string.format("stat,%d", channel())), "STATUS,%d+,(%d+)"))
  if status == nil then error("stat was not answered with a status") end
  -- In open loop rk reads volts: the position is the last one read with the loop closed.
  local closed = status & 0x0008 ~= 0
  local position = last_position or 0
  if closed then
    position = math.floor(position_um() / um_per_step() * 1000 + 0.5) / 1000
  end
  local faults = {}
  for word in string.gmatch(send("ERROR"), "%x%x%x%x") do faults[#faults + 1] = tonumber(word, 16) end
  local fault = faults[channel() + 1]
  if fault == nil then error("ERROR was not answered with the channel's fault word") end
  local done, problem = true, fault ~= 0
  if target ~= nil then
    if math.abs(position - target) <= (TOLERANCE or 2) then
      target = nil
    elseif position == last_position then
      unchanged = unchanged + 1
      if unchanged >= 3 then
        target, problem = nil, true
      else
        done = false
      end
    else
      unchanged = 0
      done = false
    end
  end
  if last_position ~= nil and position ~= last_position then
    asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DIRECTION", position > last_position and 1 or 0)
  end
  last_position = position
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_POSITION", position)
  asyn.setDoubleParam(DRIVER, AXIS, "MOTOR_ENCODER_POSITION", position)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_DONE", done and 1 or 0)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_MOVING", done and 0 or 1)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_POWERED", closed and 1 or 0)
  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_PROBLEM", problem and 1 or 0)
  asyn.callParamCallbacks(DRIVER, AXIS)
  return not done
end
