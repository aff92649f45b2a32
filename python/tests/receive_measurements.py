"""Receives ``count`` measurements of a running loop in order and reports
whether they were contiguous, as one JSON line on stdout.

Usage: python receive_measurements.py PREFIX COUNT TIMEOUT_S

Run by tests/integration/python_component.rs against a loop it started:
the iceoryx2 prefix and root path come from flexloop.transport, as a
controller's do.
"""

import json
import sys
import time

from flexloop import messages, transport


def main():
    prefix, count, timeout_s = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    domain = transport.Domain(prefix)
    node = domain.node("python-probe")
    channel = transport.channel("flexloop/measurement")
    inlet = transport.Inlet(
        node, channel, messages.Measurement, channel["subscriber_max_buffer_size"]
    )
    m = messages.Measurement()
    received = 0
    gaps = 0
    first = last = None
    deadline = time.monotonic() + timeout_s
    while received < count and time.monotonic() < deadline:
        inlet.wait(0.1)
        while received < count and inlet.receive_into(m):
            if last is not None and m.seq != last + 1:
                gaps += 1
            if first is None:
                first = m.seq
            last = m.seq
            received += 1
    inlet.close()
    print(json.dumps({
        "received": received,
        "first": first,
        "last": last,
        "gaps": gaps,
        "type_name": messages.Measurement.TYPE_NAME,
    }))
    return 0 if received == count else 1


if __name__ == "__main__":
    sys.exit(main())
