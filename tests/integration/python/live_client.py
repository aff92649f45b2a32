"""Clients of flexloop's live view (`flexloop up --live`), speaking the
Foxglove WebSocket protocol with the `websockets` package, independently of
the server's crate. Each scene drives one or several clients at once and
prints what they saw as one JSON object for the Rust test to check.

Messages are decoded with the schema the server advertised, through the
MCAP Python package's ROS1 decoder (genpy), as a recording is.

usage: live_client.py SCENE URL SECONDS [TOKEN]
  observe: one client subscribed to everything at the loop's rate, one at
           live.rate_hz = rate/10 on /measurement and /command, one that
           never reads, one that drops its connection, one that sends garbage
  tune:    parameters: get, set with and without the token, a refused set,
           a refused rate
  readonly: a set on a read-only server
"""
import asyncio
import json
import struct
import sys
import time

from mcap.records import Schema
from mcap_ros1.decoder import DecoderFactory
from websockets.asyncio.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
SAMPLE_TOPICS = ["/measurement", "/estimate", "/command"]
ALL_TOPICS = SAMPLE_TOPICS + ["/events", "/latency", "/scenario"]
KEPT_PER_TOPIC = 200


class Client:
    def __init__(self, ws):
        self.ws = ws
        self.channels = {}
        self.server_info = None
        self.statuses = []
        self.parameter_values = {}
        self.subscriptions = {}
        self.received = {}
        self.decoders = {}
        self.ros1 = DecoderFactory()
        self.closed = None
        # Every N-th sample (live.rate_hz); the samples' own gaps are
        # counted at full rate only.
        self.every = 1

    @classmethod
    async def open(cls, url, **kwargs):
        ws = await connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=20, **kwargs)
        return cls(ws)

    def handle_text(self, text):
        msg = json.loads(text)
        op = msg.get("op")
        if op == "serverInfo":
            self.server_info = msg
        elif op == "advertise":
            for c in msg["channels"]:
                self.channels[c["id"]] = c
        elif op == "status":
            self.statuses.append({"level": msg.get("level"), "message": msg.get("message")})
        elif op == "parameterValues":
            self.parameter_values[msg.get("id")] = msg["parameters"]

    def handle_binary(self, data):
        if data[0] != 1:
            return
        sub_id, log_time = struct.unpack_from("<IQ", data, 1)
        payload = bytes(data[13:])
        channel = self.subscriptions.get(sub_id)
        if channel is None:
            return
        topic = channel["topic"]
        received_before = self.total()
        r = self.received.setdefault(topic, {"count": 0, "seqs": [], "kept": [], "json": []})
        r["count"] += 1
        if channel["encoding"] == "json":
            message = json.loads(payload)
            if topic == "/latency":
                # What this client can say of its own losses at this point:
                # the messages it received before this one, and the sample
                # sequence numbers missing so far from the streams it gets
                # at full rate.
                message["received_before"] = received_before
                message["missing_by_seq"] = self.missing_by_seq()
            r["json"].append(message)
            return
        decoder = self.decoders.get(sub_id)
        if decoder is None:
            schema = Schema(
                id=channel["id"],
                name=channel["schemaName"],
                encoding=channel["schemaEncoding"],
                data=channel["schema"].encode(),
            )
            decoder = self.ros1.decoder_for(channel["encoding"], schema)
            self.decoders[sub_id] = decoder
        msg = decoder(payload)
        r["seqs"].append(msg.seq)
        if len(r["kept"]) < KEPT_PER_TOPIC:
            r["kept"].append({"seq": msg.seq, "hex": payload.hex(), "log_time": log_time})

    async def pump(self, seconds):
        """Reads (and handles) everything for `seconds`."""
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            try:
                data = await asyncio.wait_for(self.ws.recv(), timeout=left)
            except asyncio.TimeoutError:
                return
            except Exception as e:  # the server closed this client
                self.closed = repr(e)
                return
            if isinstance(data, str):
                self.handle_text(data)
            else:
                self.handle_binary(data)

    def missing_by_seq(self):
        missing = 0
        for topic in SAMPLE_TOPICS:
            seqs = self.received.get(topic, {}).get("seqs", [])
            if seqs and self.every == 1:
                missing += seqs[-1] - seqs[0] + 1 - len(seqs)
        return missing

    def total(self):
        return sum(r["count"] for r in self.received.values())

    async def until(self, predicate, seconds):
        end = time.monotonic() + seconds
        while not predicate() and time.monotonic() < end and self.closed is None:
            await self.pump(min(0.1, max(0.0, end - time.monotonic())))
        return predicate()

    async def advertised(self, topics, seconds=20):
        ok = await self.until(
            lambda: set(topics) <= {c["topic"] for c in self.channels.values()}, seconds
        )
        if not ok:
            raise SystemExit(f"not advertised within {seconds} s: {topics}; got {self.channels}")

    async def subscribe(self, topics):
        by_topic = {c["topic"]: c for c in self.channels.values()}
        subs = []
        for topic in topics:
            sub_id = len(self.subscriptions) + 1
            self.subscriptions[sub_id] = by_topic[topic]
            subs.append({"id": sub_id, "channelId": by_topic[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def unsubscribe(self, topics):
        ids = [i for i, c in self.subscriptions.items() if c["topic"] in topics]
        await self.ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": ids}))

    async def get_parameters(self, request_id, names=()):
        await self.ws.send(
            json.dumps({"op": "getParameters", "parameterNames": list(names), "id": request_id})
        )
        await self.until(lambda: request_id in self.parameter_values, 30)
        return self.parameter_values.get(request_id)

    async def set_parameters(self, request_id, parameters, seconds=120):
        """Sets; returns the values answered and the statuses that came with them."""
        before = len(self.statuses)
        await self.ws.send(
            json.dumps({"op": "setParameters", "parameters": parameters, "id": request_id})
        )
        await self.until(lambda: request_id in self.parameter_values, seconds)
        # Statuses are sent before the answer, on the same connection.
        await self.pump(0.2)
        return {
            "values": self.parameter_values.get(request_id),
            "statuses": self.statuses[before:],
        }

    def report(self):
        out = {}
        for topic, r in self.received.items():
            seqs = r.pop("seqs")
            r["first_seq"] = seqs[0] if seqs else None
            r["last_seq"] = seqs[-1] if seqs else None
            r["all_seqs_multiple_of"] = None
            for n in (100, 10, 1):
                if seqs and all(s % n == 0 for s in seqs):
                    r["all_seqs_multiple_of"] = n
                    break
            r["in_order"] = all(a < b for a, b in zip(seqs, seqs[1:]))
            out[topic] = r
        return {"received": out, "statuses": self.statuses, "closed": self.closed}


async def observe(url, seconds):
    full = await Client.open(url)
    await full.advertised(ALL_TOPICS)
    decimated = await Client.open(url)
    await decimated.advertised(ALL_TOPICS)
    rate = await decimated.get_parameters("rate", ["live.rate_hz"])
    loop_rate = rate[0]["value"]
    named = await decimated.set_parameters(
        "named", [{"name": "live.rate_hz", "value": loop_rate / 10}]
    )
    decimated.every = 10
    await full.subscribe(ALL_TOPICS)
    # The JSON channels on the decimated client: a full-rate client that
    # cannot keep up loses the oldest of its queue, these among them.
    await decimated.subscribe(["/measurement", "/command", "/latency", "/scenario"])

    # One that never reads: the library stops reading its socket once one
    # message waits.
    silent = await Client.open(url, max_queue=1)
    await silent.advertised(ALL_TOPICS)
    await silent.subscribe(ALL_TOPICS)

    abrupt = await Client.open(url)
    await abrupt.advertised(ALL_TOPICS)
    await abrupt.subscribe(ALL_TOPICS)

    garbage = await Client.open(url)
    await garbage.advertised(ALL_TOPICS)
    for junk in [
        "not json at all",
        json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 987654}]}),
        json.dumps({"op": "nonsense"}),
        json.dumps({"op": "setParameters", "parameters": [{"name": 5}]}),
    ]:
        await garbage.ws.send(junk)
    await garbage.ws.send(b"\xff\x00\x01garbage")

    async def drop_abruptly():
        await abrupt.pump(0.5)
        abrupt.ws.transport.abort()

    await asyncio.gather(
        full.pump(seconds),
        decimated.pump(seconds),
        drop_abruptly(),
        garbage.pump(seconds),
    )
    # Unsubscribed from all but /latency, whose copies say what the server
    # handed this client: past the unsubscribe, only themselves (one each).
    # (By the server's count, not by a quiet spell: a client behind still
    # drains its queue for a while.)
    await full.unsubscribe([t for t in ALL_TOPICS if t != "/latency"])
    latencies = lambda: full.received.get("/latency", {}).get("json", [])
    seen_at_unsubscribe = len(latencies())
    await full.until(lambda: len(latencies()) >= seen_at_unsubscribe + 3, 60)
    after = latencies()[seen_at_unsubscribe:]
    handed_after_unsubscribing = (
        after[2]["live"]["you"]["handed"] - after[1]["live"]["you"]["handed"] - 1
        if len(after) >= 3
        else None
    )
    channels = list(full.channels.values())
    result = {
        "server_info": full.server_info,
        "channels": channels,
        "loop_rate_hz": loop_rate,
        "named_rate": named,
        "full": full.report(),
        "decimated": decimated.report(),
        "garbage": garbage.report(),
        "handed_after_unsubscribing": handed_after_unsubscribing,
    }
    for c in (full, decimated, silent, garbage):
        try:
            await asyncio.wait_for(c.ws.close(), timeout=2)
        except Exception:
            pass
    return result


async def tune(url, seconds, token):
    c = await Client.open(url)
    await c.advertised(["/events"])
    await c.subscribe(["/events"])
    values = await c.get_parameters("all")
    out = {"parameters": values}
    set_bw = [{"name": "controller.bandwidth_hz", "value": 35.5}]
    out["without_token"] = await c.set_parameters("no-token", set_bw)
    out["wrong_token"] = await c.set_parameters(
        "wrong-token", [{"name": "live.token", "value": token + "-not"}]
    )
    out["with_token"] = await c.set_parameters(
        "with-token", [{"name": "live.token", "value": token}] + set_bw
    )
    out["breaks_rule"] = await c.set_parameters(
        "breaks-rule", [{"name": "controller.bandwidth_hz", "value": 83.0}]
    )
    out["not_swappable"] = await c.set_parameters(
        "not-swappable", [{"name": "loop.rate_hz", "value": 5000.0}]
    )
    out["odd_rate"] = await c.set_parameters("odd-rate", [{"name": "live.rate_hz", "value": 333.0}])
    out["after"] = await c.get_parameters("after", ["controller.bandwidth_hz", "live.rate_hz"])
    await c.until(
        lambda: any(
            e.get("kind") == "set" for e in c.received.get("/events", {}).get("json", [])
        ),
        seconds,
    )
    out["events"] = c.received.get("/events", {}).get("json", [])
    await c.ws.close()
    return out


async def readonly(url, seconds):
    c = await Client.open(url)
    await c.advertised(["/measurement"])
    out = {
        "set": await c.set_parameters(
            "ro", [{"name": "controller.bandwidth_hz", "value": 35.5}]
        ),
        "rate": await c.set_parameters("rate", [{"name": "live.rate_hz", "value": 100.0}]),
    }
    await c.ws.close()
    return out


def main():
    scene, url, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    token = sys.argv[4] if len(sys.argv) > 4 else ""
    if scene == "observe":
        result = asyncio.run(observe(url, seconds))
    elif scene == "tune":
        result = asyncio.run(tune(url, seconds, token))
    elif scene == "readonly":
        result = asyncio.run(readonly(url, seconds))
    else:
        raise SystemExit(f"unknown scene {scene}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
