"""A stock, third-party SMC100 client against whatever answers on a serial device.

The client is yaqd-newport's `yaqd-newport-smc100` daemon (PyPI: yaqd-newport), driven through
yaqc as its users drive it. On start it resets the controller (RS), waits for NOT REFERENCED,
homes (OR), then polls TS / TP / TE; a position set is PA, a stop ST. This script runs that
daemon on the serial device given (a pseudo-terminal served by `zmotor sim-controller
newport_smc100 --pty`), waits for the home search to end, moves the stage to two targets and
checks where it ended each time. The daemon's first PA after its home search goes to its last
destination, which on a first run is NaN: `1PAnan`, which the controller must refuse with C
("Parameter missing or out of range"); that is the one command error expected.

Usage: smc100_workflow.py <serial device>; prints "smc100 workflow ok" when all went well.
"""

import os
import random
import socket
import subprocess
import sys
import tempfile
import time

import yaqc

try:
    import tomllib
except ImportError:  # Python < 3.11
    import tomli as tomllib


def free_port():
    """A free port below the kernel's ephemeral range: a port 0 probe may be handed to an
    outgoing connection before the daemon binds it."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            ephemeral = int(f.read().split()[0])
    except OSError:
        ephemeral = 0
    candidates = list(range(10000, ephemeral)) if ephemeral > 11000 else [0]
    random.shuffle(candidates)
    for port in candidates[:1000]:
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return s.getsockname()[1]
    raise SystemExit("no free port on 127.0.0.1")


def wait_for(what, check, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if check():
                return
        except ConnectionError:
            pass
        time.sleep(0.1)
    raise SystemExit(f"timed out waiting for {what}")


def state_of(client):
    """The daemon's state (a TOML text): what TS last said, among others."""
    return tomllib.loads(client.get_state())


def main(device):
    port = free_port()
    workdir = tempfile.mkdtemp(prefix="smc100-")
    config = os.path.join(workdir, "config.toml")
    with open(config, "w") as f:
        f.write(f'[smc1]\nserial_port = "{device}"\nport = {port}\naxis = 1\n')
    log_path = os.path.join(workdir, "daemon.log")
    log = open(log_path, "w")
    env = dict(os.environ, XDG_DATA_HOME=workdir, XDG_STATE_HOME=workdir, XDG_CACHE_HOME=workdir)
    # The daemon's script is beside this Python (a virtual environment's bin), or on the PATH.
    beside = os.path.join(os.path.dirname(sys.executable), "yaqd-newport-smc100")
    executable = beside if os.path.exists(beside) else "yaqd-newport-smc100"
    daemon = subprocess.Popen(
        [executable, "--config", config], stdout=log, stderr=subprocess.STDOUT, env=env
    )
    try:
        client = None

        def connected():
            nonlocal client
            client = yaqc.Client(port, host="127.0.0.1")
            return True

        wait_for("the daemon", connected, 20)
        # The daemon resets the controller, waits 5 s, then homes.
        wait_for("the home search to end", lambda: not client.busy(), 60)
        state = state_of(client)
        if not state["status"].startswith("READY") or abs(client.get_position()) > 1e-6:
            raise SystemExit(f"not homed at 0: {state}")
        lower, upper = client.get_limits()
        if (lower, upper) != (-12.5, 12.5):
            raise SystemExit(f"software limits SL?/SR? read as {(lower, upper)}")
        for target in (5.0, -3.25):
            client.set_position(target)
            time.sleep(0.5)
            wait_for(f"the move to {target}", lambda: not client.busy(), 30)
            position = client.get_position()
            if abs(position - target) > 1e-6:
                raise SystemExit(f"asked {target}, ended at {position}: {state_of(client)}")
        state = state_of(client)
        if state["error_code"] != "0000" or not state["status"].startswith("READY"):
            raise SystemExit(f"ended in {state}")
    finally:
        daemon.terminate()
        try:
            daemon.wait(10)
        except subprocess.TimeoutExpired:
            daemon.kill()
        log.close()
    with open(log_path) as f:
        said = f.read()
    errors = [line.split("ERROR CODE", 1)[1].strip() for line in said.splitlines() if "ERROR CODE" in line]
    if errors != ["Parameter missing or out of range [C]"]:
        raise SystemExit(f"expected one C (for PAnan), the controller reported {errors}:\n{said}")
    print("smc100 workflow ok")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    main(sys.argv[1])
