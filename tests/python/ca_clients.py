"""Stock EPICS Channel Access clients against `zmotor ca`, with no zmotor code: pyepics (caget,
caput with wait, monitors), ophyd's EpicsMotor in a bluesky RunEngine scan, and caproto (its
command-line tools and its client) as a second CA implementation. Each check asserts; a line
`ok <check>` is printed for each that passed.

Usage: python3 ca_clients.py clients | ophyd | bridge | jog | gone
The environment names the server (EPICS_CA_ADDR_LIST=127.0.0.1:PORT, EPICS_CA_AUTO_ADDR_LIST=NO).
The axis m1 is launch/sim-axis.toml's: mm, PREC 3, dial limits ±100, 10 mm/s.
"""
import math
import os
import subprocess
import sys
import time
import warnings

warnings.simplefilter("ignore")
if sys.argv[1] == "ophyd":
    import ophyd  # noqa: F401  (before pyepics, whose PV class it extends)
import epics  # noqa: E402


def ok(check):
    print("ok", check, flush=True)


def near(a, b, tolerance=1e-9):
    return a is not None and abs(a - b) <= tolerance


def reads():
    assert near(epics.caget("m1.RBV", timeout=10), 0.0), epics.caget("m1.RBV")
    assert epics.caget("m1.EGU") == "mm"
    assert epics.caget("m1.RTYP") == "motor"
    assert epics.caget("m1.DESC") == "simulated linear stage"
    assert epics.caget("m1.SPMG", as_string=True) == "Go"
    assert epics.caget("m1.SPMG") == 3
    ctrl = epics.PV("m1", form="ctrl")
    ctrl.wait_for_connection(timeout=10)
    meta = ctrl.get_ctrlvars()
    assert meta["precision"] == 3 and meta["units"] == "mm", meta
    assert (meta["upper_ctrl_limit"], meta["lower_ctrl_limit"]) == (100.0, -100.0), meta
    # VAL's alarm limits are HIHI, HIGH, LOW, LOLO (0 here); RBV has none (NaN), as the record gives.
    assert (meta["upper_alarm_limit"], meta["lower_alarm_limit"]) == (0.0, 0.0), meta
    assert math.isnan(epics.PV("m1.RBV").get_ctrlvars()["upper_alarm_limit"])
    # Time stamps are the node's (when the axis read the status), as an IOC's record time: at
    # rest, fields read together share the axis's last one, in the past.
    stamps = set()
    for name in ("m1.DESC", "m1.EGU", "m1.PREC", "m1.VELO", "m1.HLM"):
        pv = epics.PV(name, form="time")
        assert pv.wait_for_connection(timeout=10) and pv.get(timeout=10) is not None, name
        stamps.add(pv.timestamp)
    assert len(stamps) == 1 and 0 < time.time() - stamps.pop() < 600, stamps
    dial = epics.PV("m1.DVAL").get_ctrlvars()
    assert (dial["upper_ctrl_limit"], dial["lower_ctrl_limit"]) == (100.0, -100.0), dial
    assert epics.PV("m1.SPMG").get_ctrlvars()["enum_strs"][:4] == ("Stop", "Pause", "Move", "Go")
    # The record's get_units and get_control_double: speeds in EGU/sec, raw values in steps.
    assert epics.PV("m1.VELO").get_ctrlvars()["units"] == "mm/sec"
    raw = epics.PV("m1.RRBV").get_ctrlvars()
    assert (raw["upper_ctrl_limit"], raw["lower_ctrl_limit"]) == (100000, -100000), raw
    rbv = epics.PV("m1.RBV", form="time")
    assert rbv.get(timeout=10) == 0.0 and rbv.timestamp > time.time() - 3600, rbv.timestamp
    assert epics.PV("m1.RBV").write_access is False and epics.PV("m1.VELO").write_access is True
    ok("reads")


def put_wait_and_monitors():
    seen = []
    rbv = epics.PV("m1.RBV", callback=lambda value=None, **kw: seen.append(value))
    rbv.wait_for_connection(timeout=10)
    ctrl_limits = []
    val = epics.PV("m1", form="ctrl", callback=lambda **kw: ctrl_limits.append(kw.get("upper_ctrl_limit")))
    val.wait_for_connection(timeout=10)
    time.sleep(0.5)
    start = time.monotonic()
    assert epics.caput("m1", 5.0, wait=True, timeout=30) == 1
    took = time.monotonic() - start
    # 5 mm at 10 mm/s with 0.2 s ramps: the put-callback waits for the end of the motion.
    assert took > 0.5, took
    assert epics.caget("m1.DMOV") == 1 and near(epics.caget("m1.RBV"), 5.0)
    time.sleep(0.5)
    assert near(seen[-1], 5.0) and len(seen) >= 3, seen
    assert any(0.0 < v < 5.0 for v in seen), seen
    ok("put-callback waits for the motion; monitors follow it")
    assert epics.caput("m1.HLM", 50.0, wait=True) == 1
    deadline = time.monotonic() + 5
    while 50.0 not in ctrl_limits and time.monotonic() < deadline:
        time.sleep(0.05)
    assert 50.0 in ctrl_limits, ctrl_limits
    assert epics.caput("m1.HLM", 100.0, wait=True) == 1
    ok("control limits are re-posted when HLM changes")


def refused():
    from caproto.sync.client import write

    before = epics.caget("m1.RBV")
    # Beyond the soft limits: the record takes the put and does not move, as an IOC answers it
    # (ECA_NORMAL); LVIO says why.
    reply = write("m1", 500.0, notify=True, repeater=False, timeout=10)
    assert reply.status.name == "ECA_NORMAL", reply
    assert epics.caget("m1.LVIO") == 1
    # A value the record refuses (NTMF below 2: set to 2, not processed) fails the put.
    reply = write("m1.NTMF", 1, notify=True, repeater=False, timeout=10)
    assert reply.status.name == "ECA_PUTFAIL", reply
    assert epics.caget("m1.NTMF") == 2
    reply = write("m1.RBV", 1.0, notify=True, repeater=False, timeout=10)
    assert reply.status.name == "ECA_NOWTACCESS", reply
    # A double to an integer field is cut toward zero, as an IOC's dbPut converts it.
    from caproto import ChannelType

    retries = epics.caget("m1.RTRY")
    reply = write("m1.RTRY", 2.7, notify=True, repeater=False, timeout=10, data_type=ChannelType.DOUBLE)
    assert reply.status.name == "ECA_NORMAL", reply
    cut = epics.caget("m1.RTRY", use_monitor=False)
    assert cut == 2, (cut, retries)
    assert write("m1.RTRY", retries, notify=True, repeater=False, timeout=10).status.name == "ECA_NORMAL"
    # Text longer than a string field holds is cut to fit, as an IOC's dbPut copies it (EGU: 15).
    assert write("m1.EGU", "millimetres, roughly", notify=True, repeater=False, timeout=10).status.name == "ECA_NORMAL"
    assert epics.caget("m1.EGU", use_monitor=False) == "millimetres, ro"
    assert write("m1.EGU", "mm", notify=True, repeater=False, timeout=10).status.name == "ECA_NORMAL"
    time.sleep(0.3)
    assert epics.caget("m1.RBV") == before and epics.caget("m1.DMOV") == 1
    assert epics.caget("m1") == before
    ok("refused writes answer as an IOC would (a limit violation taken, a refused value failed) and move nothing")
    # The refusal's words, as the axis's ERR key has them: in full as a character array (ERR$,
    # as EPICS serves long strings), cut to a DBR_STRING's 39 characters as ERR.
    deadline = time.time() + 10
    message = ""
    while "NTMF" not in message and time.time() < deadline:
        message = epics.caget("m1.ERR$", as_string=True) or ""
        time.sleep(0.05)
    assert "NTMF" in message, message
    assert epics.caget("m1.ERR") == message[:39], (epics.caget("m1.ERR"), message)
    assert epics.PV("m1.ERR$").write_access is False
    ok("the axis's ERR reads in full as ERR$ and cut as ERR")


def puts_disabled():
    """DISP disables puts, as on an IOC (the Enable/Disable of a motor screen, m1_able): every
    put but DISP's fails and changes nothing; STOP is taken (README departure Z23)."""
    from caproto.sync.client import write

    def put(name, value):
        return write(name, value, notify=True, repeater=False, timeout=10).status.name

    before = epics.caget("m1.RBV", use_monitor=False)
    velo = epics.caget("m1.VELO", use_monitor=False)
    # The motor's Enable/Disable record of motor's databases, m1_able, is DISP by its choices.
    ables = []
    able = epics.PV("m1_able", callback=lambda value=None, **kw: ables.append(value))
    assert able.wait_for_connection(timeout=10) and able.get(as_string=True) == "Enable"
    assert epics.PV("m1_able").get_ctrlvars()["enum_strs"][:2] == ("Enable", "Disable")
    assert put("m1_able", "Disable") == "ECA_NORMAL"
    assert epics.caget("m1.DISP", use_monitor=False) == 1
    disp = epics.PV("m1.DISP")
    assert disp.wait_for_connection(timeout=10) and disp.type == "time_char", disp.type  # DBF_UCHAR, as dbCommon's
    assert epics.Motor("m1").disabled == 1
    assert put("m1", before + 1.0) == "ECA_PUTFAIL"
    assert put("m1.VELO", 2.0) == "ECA_PUTFAIL"
    assert put("m1.STOP", 1) == "ECA_NORMAL"
    time.sleep(0.3)
    assert epics.caget("m1.VELO", use_monitor=False) == velo
    assert epics.caget("m1.RBV", use_monitor=False) == before and epics.caget("m1.DMOV") == 1
    assert "puts are disabled" in epics.caget("m1.ERR$", as_string=True, use_monitor=False)
    assert put("m1.DISP", [0]) == "ECA_NORMAL"  # a char channel: caproto writes a sequence
    deadline = time.monotonic() + 10
    while ables[-1:] != [0] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ables == [0, 1, 0], ables
    assert epics.caput("m1", before + 1.0, wait=True, timeout=30) == 1
    assert near(epics.caget("m1.RBV", use_monitor=False), before + 1.0)
    assert epics.caput("m1", before, wait=True, timeout=30) == 1
    ok("DISP (a char channel) disables every put but DISP and STOP; DISP 0 enables them; m1_able shows and sets it")


def common_fields():
    """The dbCommon fields zmotor does not model read as an IOC's motor record holds them."""
    assert epics.caget("m1.SCAN", as_string=True, use_monitor=False) == "Passive"
    assert epics.caget("m1.UDFS", as_string=True, use_monitor=False) == "INVALID"
    assert epics.caget("m1.TPRO", use_monitor=False) == 0
    assert epics.caget("m1.ASG", use_monitor=False) == ""
    scan = epics.PV("m1.SCAN")
    assert scan.wait_for_connection(timeout=10) and not scan.write_access
    ok("dbCommon's SCAN, UDFS, TPRO and ASG read as an IOC's defaults, read-only")


def long_strings():
    """A string field's `$` channel is its text as characters, read and written (caget -S)."""
    desc = epics.caget("m1.DESC", use_monitor=False)
    chars = epics.PV("m1.DESC$")
    assert chars.wait_for_connection(timeout=10) and chars.type.endswith("char") and chars.count == 41, chars.info
    assert epics.caget("m1.DESC$", as_string=True, use_monitor=False) == desc
    assert epics.caput("m1.DESC$", "the slit's top blade, by its long name", wait=True, timeout=10) == 1
    assert epics.caget("m1.DESC", use_monitor=False) == "the slit's top blade, by its long name"
    assert epics.caput("m1.DESC", desc, wait=True, timeout=10) == 1
    ok("a string field's long-string channel (DESC$) reads and writes its text as characters")


def alarm_acknowledgement():
    """What ALH does: the record's alarm and acknowledgement read as DBR_STSACK_STRING, and
    DBR_PUT_ACKT / DBR_PUT_ACKS written to it; a plain put of ACKS is refused (SPC_NOMOD)."""
    from caproto import ChannelType
    from caproto.sync.client import read, write

    def stsack():
        meta = read("m1", data_type=ChannelType.STSACK_STRING, repeater=False, timeout=10).metadata
        return (meta.status, meta.severity, meta.ackt, meta.acks, float(meta.value))

    rbv = epics.caget("m1.RBV", use_monitor=False)
    assert stsack() == (0, 0, 1, 0, rbv), stsack()
    write("m1", [0], data_type=ChannelType.PUT_ACKT, notify=True, repeater=False, timeout=10)
    assert epics.caget("m1.ACKT", use_monitor=False) == 0
    assert stsack()[2] == 0
    write("m1.VELO", [3], data_type=ChannelType.PUT_ACKS, notify=True, repeater=False, timeout=10)
    assert epics.caget("m1.ACKS", use_monitor=False) == 0
    acks = epics.PV("m1.ACKS")
    assert acks.wait_for_connection(timeout=10) and not acks.write_access
    write("m1", [1], data_type=ChannelType.PUT_ACKT, notify=True, repeater=False, timeout=10)
    assert stsack()[2:4] == (1, 0)
    ok("ALH's alarm acknowledgement: DBR_STSACK_STRING reads ACKT and ACKS, DBR_PUT_ACKT and DBR_PUT_ACKS write them")

    # An alarm raised by one processing reaches a DBE_ALARM monitor as one event, whole.
    events, ctrl_events = [], []
    alarm = epics.PV("m1", form="time", auto_monitor=epics.dbr.DBE_ALARM,
                     callback=lambda severity=None, status=None, **kw: events.append((status, severity)))
    # A DBR_CTRL monitor, whose metadata holds the alarm too (a display's).
    alarm_ctrl = epics.PV("m1", form="ctrl", auto_monitor=epics.dbr.DBE_ALARM,
                          callback=lambda severity=None, status=None, **kw: ctrl_events.append((status, severity)))
    assert alarm.wait_for_connection(timeout=10) and alarm_ctrl.wait_for_connection(timeout=10)
    deadline = time.monotonic() + 10
    while not (events and ctrl_events) and time.monotonic() < deadline:
        time.sleep(0.01)
    dhlm = epics.caget("m1.DHLM", use_monitor=False)
    assert epics.caput("m1.HLSV", "MAJOR", wait=True, timeout=10) == 1
    assert epics.caput("m1.DHLM", epics.caget("m1.DRBV", use_monitor=False) - 1.0, wait=True, timeout=10) == 1
    deadline = time.monotonic() + 10
    while (len(events) < 2 or len(ctrl_events) < 2) and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.3)  # bounded: a second, split event would come within it
    assert events[1:] == [(4, 2)], events  # HIGH, MAJOR
    assert ctrl_events[1:] == [(4, 2)], ctrl_events
    assert stsack()[1] == 2 and stsack()[3] == 2, stsack()
    write("m1", [2], data_type=ChannelType.PUT_ACKS, notify=True, repeater=False, timeout=10)
    assert epics.caput("m1.DHLM", dhlm, wait=True, timeout=10) == 1
    assert epics.caput("m1.HLSV", "NO_ALARM", wait=True, timeout=10) == 1
    alarm.clear_callbacks()
    alarm_ctrl.clear_callbacks()
    assert stsack()[:4] == (0, 0, 1, 0), stsack()
    ok("an alarm raised by one processing reaches a DBE_ALARM monitor as one event, and is acknowledged")


def dmov_monitor():
    """A monitor of m1.DMOV once its first value came, and the list its later values go to."""
    pulses = []
    dmov = epics.PV("m1.DMOV", callback=lambda value=None, **kw: pulses.append(value))
    dmov.wait_for_connection(timeout=10)
    deadline = time.monotonic() + 10
    while not pulses and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pulses, "no first DMOV"
    pulses.clear()
    return dmov, pulses


def moves_of_nothing():
    # A put that moves nothing (a null move, a limit violation) pulses DMOV 0 then 1 at once; a
    # monitor sees both, in that order, however the gateway's circuit is behind the network.
    from epics import ca

    dmov, pulses = dmov_monitor()
    here = epics.caget("m1")
    seen = []
    for attempt in range(16):
        pulses.clear()
        target = here if attempt % 4 < 2 else 500.0
        assert epics.caput("m1", target, wait=attempt % 2 == 0, timeout=10) == 1
        deadline = time.monotonic() + 5
        while len(pulses) < 2 and time.monotonic() < deadline:
            ca.poll(0.01)
        seen.append("".join(str(v) for v in pulses))
    assert seen == ["01"] * 16, seen
    dmov.clear_callbacks()
    ok("a put that moves nothing posts DMOV 0 then 1 to a monitor")


def read_after_write():
    # A plain caput, then cagets on the same circuit: they see what the put did (the motion
    # under way, the new target), as an IOC processes a put before the circuit's next request.
    here = epics.caget("m1", use_monitor=False)
    for step in (2.0, -2.0, 2.0, -2.0):
        target = here + step
        assert epics.caput("m1", target) == 1
        assert epics.caget("m1.DMOV", use_monitor=False) == 0, "DMOV read right after the put"
        assert near(epics.caget("m1.VAL", use_monitor=False), target, 1e-6)
        deadline = time.monotonic() + 10
        while epics.caget("m1.DMOV", use_monitor=False) != 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        here = target
    ok("a read right after a plain put sees what the put did")


def caproto_tools():
    def run(tool, *args):
        # caproto's tools beside this Python (a virtual environment's bin is not on PATH).
        tool = os.path.join(os.path.dirname(sys.executable), tool)
        out = subprocess.run([tool, *args], capture_output=True, text=True, timeout=30)
        assert out.returncode == 0, out.stderr
        return out.stdout

    def value(text):
        return text.split("[", 1)[1].split("]", 1)[0]

    assert float(value(run("caproto-get", "--no-repeater", "m1.RBV"))) == 5.0
    run("caproto-put", "--no-repeater", "-c", "m1", "2.5")
    assert near(epics.caget("m1.RBV"), 2.5)
    assert value(run("caproto-get", "--no-repeater", "m1.RTYP")) == "motor"
    # DBR_CLASS_NAME (38), the record type of a channel: m1_able is a bo record on an IOC.
    from caproto.sync.client import read

    assert [
        read(name, data_type=38, repeater=False, timeout=10).metadata.value for name in ("m1", "m1_able")
    ] == [b"motor", b"bo"]
    ok("caproto's command-line tools read and put-callback; its client reads the record types")


def put_callbacks_in_turn():
    # As an IOC's dbNotify: a put-callback to a motor that another put-callback moves waits for
    # that one to complete, then moves; two motions, each to its own target.
    import threading
    from caproto.sync.client import write

    dmov, pulses = dmov_monitor()
    # Two clients: caproto's (on a thread) moves the motor; pyepics puts while it moves.
    first = threading.Thread(target=write, args=("m1", 1.0), kwargs={"notify": True, "repeater": False, "timeout": 30})
    first.start()
    deadline = time.monotonic() + 10
    while 0 not in pulses and time.monotonic() < deadline:
        time.sleep(0.01)
    assert epics.caput("m1", 2.0, wait=True, timeout=30) == 1
    first.join(30)
    deadline = time.monotonic() + 5
    while len(pulses) < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pulses == [0, 1, 0, 1], pulses
    assert near(epics.caget("m1.RBV", use_monitor=False), 2.0), epics.caget("m1.RBV")
    dmov.clear_callbacks()
    ok("a put-callback to a motor another one moves waits for it to complete, as an IOC's does")


def archive_deadband():
    # An archiver's monitor (DBE_LOG) of RBV sees the readbacks past ADEL from the last it got;
    # a display's (DBE_VALUE) every one. m1 reads back at 10 Hz, 10 mm/s: about 1 mm apart.
    start = epics.caget("m1.RBV", use_monitor=False)
    assert epics.caput("m1.ADEL", 2.5, wait=True) == 1
    archived, displayed = [], []
    archive = epics.PV("m1.RBV", auto_monitor=epics.dbr.DBE_LOG, callback=lambda value=None, **kw: archived.append(value))
    display = epics.PV("m1.RBV", auto_monitor=epics.dbr.DBE_VALUE, callback=lambda value=None, **kw: displayed.append(value))
    for pv in (archive, display):
        pv.wait_for_connection(timeout=10)
    deadline = time.monotonic() + 10
    while not (archived and displayed) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert epics.caput("m1", start + 5.0, wait=True, timeout=30) == 1
    # The display's monitor has the end of the move once its last readback came.
    deadline = time.monotonic() + 10
    while not near(displayed[-1], start + 5.0, 1e-6) and time.monotonic() < deadline:
        time.sleep(0.01)
    archive.clear_callbacks()
    display.clear_callbacks()
    assert epics.caput("m1.ADEL", 0, wait=True) == 1
    assert epics.caput("m1", start, wait=True, timeout=30) == 1
    assert len(displayed) >= 5 and len(archived) >= 2, (archived, displayed)
    assert len(archived) < len(displayed), (archived, displayed)
    steps = [b - a for a, b in zip(archived, archived[1:])]
    assert all(step > 2.5 for step in steps), archived
    ok("an archiver's monitor (DBE_LOG) of RBV gets the moves past ADEL; a display's every readback")


def ophyd_scan():
    from bluesky import RunEngine
    from bluesky.plans import scan
    from ophyd import EpicsMotor

    motor = EpicsMotor("m1", name="m1")
    motor.wait_for_connection(timeout=10)
    # ophyd ends a move in its monitor thread by finishing the move's status, then dropping the
    # status's subscription; a plan that starts the next move in between (the monitor thread
    # starved of the CPU) has that move's subscription dropped, and waits for ever. It is
    # ophyd's: 2 of 20 scans beside two busy loops hung so with the gateway before and after
    # its change-ordering fix alike. A settle time runs the plan's callbacks after the drop.
    motor.settle_time = 0.1
    assert motor.limits == (-100.0, 100.0) and motor.precision == 3 and motor.egu == "mm"
    moving = []
    motor.motor_is_moving.subscribe(lambda value=None, **kw: moving.append(value), run=False)
    status = motor.set(3.0)
    status.wait(30)
    assert status.success and near(motor.position, 3.0) and motor.moving is False
    assert 1 in moving, moving
    # A move to where the motor is ends at once (its DMOV 0 then 1): the status finishes.
    for _ in range(3):
        status = motor.set(motor.position)
        status.wait(10)
        assert status.success and near(motor.position, 3.0), motor.position
    documents = []
    RunEngine({})(scan([], motor, 0, 1, 3), lambda name, doc: documents.append((name, doc)))
    positions = [doc["data"]["m1"] for name, doc in documents if name == "event"]
    assert positions == [0.0, 0.5, 1.0], positions
    ok("ophyd EpicsMotor moves, moves nowhere, reads limits and precision, and scans three points under bluesky")


def until(condition, what, seconds=10.0):
    """Wait for a condition, polling every 50 ms, at most `seconds`."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def bridge_records():
    """The database of channel_access.rs's bridge test: ao `length` (VAL 1000), calc `half`
    (A/2 of length, CP, no OUT), calc `waiting` (an input no one writes)."""
    assert epics.caget("length", timeout=10) == 1000.0
    until(lambda: epics.caget("half", timeout=10) == 500.0, "the calc's first result")
    assert (epics.caget("length.RTYP"), epics.caget("half.RTYP")) == ("ao", "calc")
    assert epics.PV("length").write_access is True and epics.PV("half").write_access is False
    changes = []
    half = epics.PV("half", callback=lambda value=None, **_: changes.append(value))
    assert half.wait_for_connection(timeout=10)
    until(lambda: changes[:1] == [500.0], f"the monitor's first event: {changes}")
    assert epics.caput("length", 300, wait=True, timeout=10) == 1
    assert epics.caget("length") == 300.0, "read after the write"
    until(lambda: changes[-1:] == [150.0], f"the calc's result monitored: {changes}")
    assert epics.caget("half") == 150.0
    # A calc's result is read-only; a NaN is no value; neither changes anything.
    try:
        epics.caput("half", 7, wait=True, timeout=10)
        raise AssertionError("a calc's result was written")
    except epics.ca.CASeverityException as refused:
        assert "Write access denied" in str(refused), refused
    from caproto.sync.client import write

    reply = write("length", math.nan, notify=True, repeater=False, timeout=10)
    assert reply.status.name == "ECA_PUTFAIL", reply
    time.sleep(0.3)
    assert (epics.caget("length"), epics.caget("half")) == (300.0, 150.0)
    # A calc never processed reads 0, undefined, as an IOC's.
    waiting = epics.PV("waiting", form="time")
    assert waiting.wait_for_connection(timeout=10) and waiting.get(timeout=10) == 0.0
    assert (waiting.status, waiting.severity) == (17, 3), (waiting.status, waiting.severity)
    assert not epics.PV("length.EGU").wait_for_connection(timeout=2), "only VAL and RTYP are served"
    ok("bridge records: an ao read, written and monitored through its calc, a calc read-only, one never processed undefined")


def gone():
    pv = epics.PV("m1.RBV")
    assert not pv.wait_for_connection(timeout=3), "m1 is still served"
    ok("a vanished axis is not served")


def jog():
    assert epics.caput("m1.JOGF", 1, wait=False) == 1
    print("jogging", flush=True)
    time.sleep(600)  # until killed: the jog must end when this client vanishes


# ophyd runs in a process of its own: it patches pyepics's PV class when it is imported.
STAGES = {
    "clients": [
        reads,
        put_wait_and_monitors,
        refused,
        puts_disabled,
        alarm_acknowledgement,
        common_fields,
        long_strings,
        moves_of_nothing,
        read_after_write,
        caproto_tools,
        put_callbacks_in_turn,
        archive_deadband,
    ],
    "ophyd": [ophyd_scan],
    "bridge": [bridge_records],
    "gone": [gone],
    "jog": [jog],
}
# No stage may wait for ever (a scan has no timeout of its own): after two minutes, every
# thread's stack goes to stderr, which says where it waited, and the stage fails. The jog stage
# waits to be killed.
if sys.argv[1] != "jog":
    import faulthandler

    faulthandler.dump_traceback_later(120, exit=True)
for check in STAGES[sys.argv[1]]:
    check()
