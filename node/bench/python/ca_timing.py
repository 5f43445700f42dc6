"""The Channel Access figures as a stock client sees them: pyepics (libca) reading m1.RBV and
moving m1 one step at a time with a put-callback, against a gateway on 127.0.0.1:PORT.
Prints one JSON object: percentiles in microseconds."""
import json
import os
import sys
import time

port, reads, moves = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
os.environ.update(EPICS_CA_AUTO_ADDR_LIST="NO", EPICS_CA_ADDR_LIST="127.0.0.1", EPICS_CA_SERVER_PORT=port)
import epics  # noqa: E402  (libca reads its environment when it starts)


def percentiles(samples):
    samples = sorted(samples)
    at = lambda q: samples[round((len(samples) - 1) * q)] * 1e6
    return {"p50": at(0.5), "p90": at(0.9), "p99": at(0.99)}


rbv, val = epics.PV("m1.RBV"), epics.PV("m1")
if not (rbv.wait_for_connection(30) and val.wait_for_connection(30)):
    sys.exit("pyepics could not connect to m1")
read = []
for _ in range(reads):
    start = time.perf_counter()
    if rbv.get(use_monitor=False) is None:
        sys.exit("a caget of m1.RBV got nothing")
    read.append(time.perf_counter() - start)
move = []
for i in range(moves):
    start = time.perf_counter()
    if val.put(round(0.5 + (i + 1) * 0.001, 3), wait=True, timeout=30) != 1:
        sys.exit("a put-callback of m1 did not complete")
    move.append(time.perf_counter() - start)
print(json.dumps({"read": percentiles(read), "move": percentiles(move)}))
