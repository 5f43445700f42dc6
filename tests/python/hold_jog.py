"""A stock eclipse-zenoh Python client jogs an axis under a hold (the jog deadman), then waits to
be killed: the node must end the jog when this client's liveliness token goes.

Usage: python3 hold_jog.py ENDPOINT AXIS
The session's lease is half a second (transport/link/tx/lease), so that a cut-off client is
seen gone within a second; the hold is a CBOR map {kind: "hold", token: KEY} as the write's
attachment, naming a liveliness token this client declares first.
"""
import json
import sys
import time

import cbor2
import zenoh

endpoint, axis = sys.argv[1], sys.argv[2]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("transport/link/tx/lease", "500")

with zenoh.open(conf) as session:
    token_key = f"motor/{axis}/@hold/{session.info.zid()}"
    token = session.liveliness().declare_token(token_key)
    hold = cbor2.dumps({"kind": "hold", "token": token_key})
    replies = list(session.get(f"motor/{axis}/JOGF", payload="1", attachment=hold, timeout=5.0))
    if len(replies) != 1 or replies[0].ok is None:
        sys.exit(f"hold_jog: the jog was not taken: {replies}")
    print("holding", flush=True)
    while True:
        time.sleep(1)
