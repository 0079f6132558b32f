"""A minimal reproducer, plain zenoh-python and nothing of ours, of what a visiting session
leaves in a long-running receiver: zenoh's receiver keeps every same-host sender's
shared-memory pool mapped (and locked) after the sender has gone.

    python -m bench.shm_visits [--visits 4] [--messages 100] [--bytes 5000]

A subscriber (``ubf/**``) listens on loopback; each visit is a new process that connects,
puts ``--messages`` payloads of ``--bytes`` at 1000/s and exits. Printed: the subscriber's
``VmRSS`` and ``VmLck`` after each visit, with zenoh's default configuration and with
``transport/shared_memory/enabled: false`` on the subscriber — measured in the same run.
Payloads under 3072 bytes (``message_size_threshold``) do not go through shared memory and
leave nothing. Upstream: eclipse-zenoh/zenoh#2787 (receiver-side mappings kept after the
remote process ends) and #1700 (segments are never detached at the receiver).
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import time

SUBSCRIBER = r'''
import json, sys, zenoh
conf = zenoh.Config()
conf.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
if sys.argv[2] == "off":
    conf.insert_json5("transport/shared_memory/enabled", "false")
session = zenoh.open(conf)
received = [0]
sub = session.declare_subscriber("ubf/**", lambda sample: received.__setitem__(0, received[0] + 1))
print("ready", flush=True)
for _ in sys.stdin:
    status = dict(line.split(":", 1) for line in open("/proc/self/status"))
    print(json.dumps({"rss_kib": int(status["VmRSS"].split()[0]),
                      "lck_kib": int(status["VmLck"].split()[0]), "received": received[0]}),
          flush=True)
'''

VISITOR = r'''
import json, os, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
pub = session.declare_publisher("ubf/visit")
while not pub.matching_status.matching:
    time.sleep(0.01)
payload = os.urandom(int(sys.argv[3]))
for _ in range(int(sys.argv[2])):
    pub.put(payload)
    time.sleep(0.001)
session.close()
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run(shm: str, args: argparse.Namespace) -> list[dict[str, int]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, endpoint, shm],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert sub.stdin is not None and sub.stdout is not None
    sub.stdout.readline()

    def status() -> dict[str, int]:
        sub.stdin.write("\n")  # type: ignore[union-attr]
        sub.stdin.flush()  # type: ignore[union-attr]
        return dict(json.loads(sub.stdout.readline()))  # type: ignore[union-attr]

    rows = [status()]
    try:
        for i in range(args.visits):
            subprocess.run([sys.executable, "-c", VISITOR, endpoint, str(args.messages),
                            str(args.bytes)], check=True)
            expected = (i + 1) * args.messages
            deadline = time.monotonic() + 10
            while (row := status())["received"] < expected and time.monotonic() < deadline:
                time.sleep(0.05)
            rows.append(row)
    finally:
        sub.kill()
        sub.wait()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.shm_visits", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--visits", type=int, default=4)
    parser.add_argument("--messages", type=int, default=100)
    parser.add_argument("--bytes", type=int, default=5000)
    args = parser.parse_args(argv)
    runs = {shm: run(shm, args) for shm in ("default", "off")}
    print(f"{args.visits} visits of {args.messages} × {args.bytes} B; subscriber's growth since "
          f"before the first (MiB):")
    print(f"  {'visit':>5}  {'RSS, SHM on':>11}  {'locked':>7}  {'RSS, SHM off':>12}  "
          f"{'locked':>7}")
    for i in range(1, args.visits + 1):
        on, off = (runs[s][i] for s in ("default", "off"))
        on0, off0 = (runs[s][0] for s in ("default", "off"))
        print(f"  {i:>5}  {(on['rss_kib'] - on0['rss_kib']) / 1024:+11.1f}  "
              f"{(on['lck_kib'] - on0['lck_kib']) / 1024:+7.1f}  "
              f"{(off['rss_kib'] - off0['rss_kib']) / 1024:+12.1f}  "
              f"{(off['lck_kib'] - off0['lck_kib']) / 1024:+7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
