"""A stock eclipse-zenoh Python client, over mutual TLS, sends a confirmed write (a `get` with a
payload) to one key and prints how it ended: `ok VALUE`, `err MESSAGE`, or `none` when nothing
answered (what Zenoh gives a query its access rules deny).

Usage: python3 guarded_write.py ENDPOINT CA CERT KEY KEY_EXPR VALUE
"""
import json
import sys

import zenoh

endpoint, ca, cert, key, key_expr, value = sys.argv[1:7]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5(
    "transport/link/tls",
    json.dumps(
        {
            "root_ca_certificate": ca,
            "connect_certificate": cert,
            "connect_private_key": key,
            "enable_mtls": True,
        }
    ),
)

with zenoh.open(conf) as session:
    replies = list(session.get(key_expr, payload=value, encoding=zenoh.Encoding.TEXT_PLAIN, timeout=5.0))
    if not replies:
        print("none")
    elif replies[0].ok is not None:
        print("ok", replies[0].ok.payload.to_bytes().hex())
    else:
        print("err", replies[0].err.payload.to_string())
