"""A second process on the DDS backend, for the tests: ``python -m tests.bridge.peer``.

It opens a ``dds`` port as node ``peer`` in namespace ``/peer`` (config from
``$CYCLONEDDS_URI``), makes one publisher per message type on ``/peer/<type_name>``,
and, when ``--count N`` is above 0, waits for a subscriber on each and publishes the
seeded samples 0..N-1 of every type, round robin. Then it waits for
``std_msgs/Bool`` on ``/peer/done`` and exits 0; 2 when nothing came in time.
"""

from __future__ import annotations

import argparse
import sys
import threading

from bridge.rosport import MESSAGE_TYPES, Bool, open_port
from tests.bridge.samples import sample, topic_for

NAMESPACE = "/peer"
NODE = "peer"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--count", type=int, default=0, help="samples per type to publish")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for peers")
    args = parser.parse_args(argv)
    done = threading.Event()
    with open_port("dds", namespace=NAMESPACE, node_name=NODE) as port:
        port.subscribe("done", Bool, lambda msg: done.set())
        publishers = [port.publisher(topic_for(t), t) for t in MESSAGE_TYPES.values()]
        print("ready", flush=True)
        if args.count:
            for pub in publishers:
                if not pub.wait_for_subscribers(1, timeout_s=args.timeout):
                    print(f"peer: nobody subscribed to {pub.topic}", file=sys.stderr)
                    return 2
            for seed in range(args.count):
                for pub in publishers:
                    pub.publish(sample(pub.msg_type, seed))
        if not done.wait(args.timeout):
            print("peer: no message on /peer/done", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
