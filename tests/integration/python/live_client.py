"""Clients of flexloop's live view (`flexloop up --live`), speaking the
Foxglove WebSocket protocol with the `websockets` package, independently of
the server's crate. Each scene drives one or several clients at once and
prints what they saw as one JSON object for the Rust test to check.

Messages are decoded with the schema the server advertised, through the
MCAP Python package's ROS1 decoder (genpy), as a recording is.

usage: live_client.py SCENE URL SECONDS [TOKEN | PID]
  observe: one client subscribed to everything at the loop's rate, one at
           live.rate_hz = rate/10 on /measurement and /command, one that
           never reads, one that drops its connection, one that sends garbage
  tune:    parameters: get, set with and without the token, a refused set,
           a refused rate
  readonly: a set on a read-only server
  flood PID: 1000 connections at once; those admitted subscribe to
           everything and never read; the server's memory (PID: the live
           server's) meanwhile and after
  bigset PID: a set just under the size a client may send and one of 15 MB,
           without the token; the server's memory before and after
  bypass PID: a client straight to the crate's own port (on loopback),
           not through the server's address: it is served nothing
  brute TOKEN: wrong tokens from four connections as fast as the server
           answers, for SECONDS; then the right one, during and after the
           lockout
"""
import asyncio
import json
import re
import resource
import struct
import sys
import time

from websockets.exceptions import InvalidStatus

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


def memory(pid):
    """The process's resident memory now and at its peak, in kB (from /proc)."""
    out = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM", "RssAnon", "RssShmem"):
                out[key] = int(value.split()[0])
    return out


async def attempt(url, **kwargs):
    """One connection: the client, or how it was refused."""
    try:
        return await Client.open(url, **kwargs), None
    except InvalidStatus as e:
        return None, {"status": e.response.status_code, "body": e.response.body.decode(errors="replace")}
    except Exception as e:  # reset, closed before the answer, timed out
        return None, {"error": type(e).__name__}


async def flood(url, seconds, pid, count=1000):
    # Room for the sockets (the hard limit is the machine's).
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, count + 200)), hard))
    before = memory(pid)
    attempts = await asyncio.gather(*[attempt(url, max_queue=1) for _ in range(count)])
    admitted = [c for c, _ in attempts if c is not None]
    refusals = [r for _, r in attempts if r is not None]
    # Those admitted subscribe to everything and never read again.
    for c in admitted:
        await c.advertised(ALL_TOPICS)
        await c.subscribe(ALL_TOPICS)
    samples = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        await asyncio.sleep(0.5)
        samples.append(memory(pid)["VmRSS"])
    during = memory(pid)
    # One more while they hold every place.
    extra, extra_refusal = await attempt(url)
    if extra is not None:
        await extra.ws.close()
    for c in admitted:
        c.ws.transport.abort()
    await asyncio.sleep(2)
    after = memory(pid)
    # The places are given back.
    again, again_refusal = await attempt(url)
    if again is not None:
        await again.advertised(["/measurement"])
        await again.ws.close()
    return {
        "memory_before_kb": before,
        "memory_during_kb": during,
        "rss_samples_kb": samples,
        "memory_after_kb": after,
        "admitted": len(admitted),
        "refused_503": sum(1 for r in refusals if r.get("status") == 503),
        "refused_otherwise": [r for r in refusals if r.get("status") != 503][:20],
        "refusal_body": next((r["body"] for r in refusals if "body" in r), None),
        "extra_refusal": extra_refusal,
        "again_admitted": again is not None,
        "again_refusal": again_refusal,
    }


async def bigset(url, seconds, pid):
    c = await Client.open(url)
    await c.advertised(["/measurement"])
    await c.get_parameters("all")
    before = memory(pid)
    # Just under the 64 KiB a client may send: parsed by the crate, then
    # refused by the token before its value is looked at.
    under = await c.set_parameters(
        "under", [{"name": "controller.bandwidth_hz", "value": "9" * 60_000}], seconds=30
    )
    after_under = memory(pid)
    big = await Client.open(url)
    await big.advertised(["/measurement"])
    message = json.dumps(
        {"op": "setParameters", "id": "big",
         "parameters": [{"name": "controller.bandwidth_hz", "value": "9" * 15_000_000}]}
    )
    sent = None
    try:
        await asyncio.wait_for(big.ws.send(message), timeout=30)
        sent = "sent"
    except Exception as e:
        sent = type(e).__name__
    await big.until(lambda: False, seconds)
    await asyncio.sleep(1)
    after = memory(pid)
    # The first client is still served.
    still = await c.get_parameters("still", ["live.rate_hz"])
    await c.ws.close()
    return {
        "memory_before_kb": before,
        "memory_after_under_kb": after_under,
        "memory_after_kb": after,
        "under": under,
        "big_sent": sent,
        "big_closed": big.closed,
        "big_answered": "big" in big.parameter_values,
        "still_served": still,
    }


async def brute(url, seconds, token, clients=4):
    cs = [await Client.open(url) for _ in range(clients)]
    for c in cs:
        await c.advertised(["/measurement"])
    sent = [0] * clients

    async def guess(i, c):
        end = time.monotonic() + seconds
        n = 0
        while time.monotonic() < end:
            # Eight requests in flight, then their answers.
            ids = []
            for _ in range(8):
                rid = f"g{i}-{n}"
                n += 1
                ids.append(rid)
                await c.ws.send(json.dumps({
                    "op": "setParameters", "id": rid,
                    "parameters": [{"name": "live.token", "value": f"guess-{i}-{n:012d}"}],
                }))
            sent[i] += len(ids)
            await c.until(lambda: all(r in c.parameter_values for r in ids), 30)

    started = time.monotonic()
    await asyncio.gather(*[guess(i, c) for i, c in enumerate(cs)])
    elapsed = time.monotonic() - started
    statuses = [s["message"] for c in cs for s in c.statuses]
    # One more wrong guess (compared, it starts a lockout; or refused in
    # one), then the right token at once: refused unexamined while the
    # lockout holds.
    during = await cs[0].set_parameters(
        "right-during",
        [{"name": "live.token", "value": "one-more-guess"}, {"name": "live.token", "value": token}],
    )
    # After the lockout it says: taken (no error).
    text = json.dumps(during["statuses"])
    left = [float(m) for m in re.findall(r"(?:another|for) ([0-9.]+) s", text)]
    waited = min(max(left, default=0.0) + 0.5, 70.0)
    await cs[0].pump(waited)
    after = await cs[0].set_parameters("right-after", [{"name": "live.token", "value": token}])
    for c in cs:
        await c.ws.close()
    return {
        "elapsed_s": elapsed,
        "sent": sum(sent),
        "answered": sum(len(c.parameter_values) for c in cs),
        "wrong": sum(1 for m in statuses if "not the server's token" in m),
        "throttled": sum(1 for m in statuses if "too many wrong tokens" in m),
        "first_statuses": statuses[:8],
        "right_during": during,
        "waited_s": waited,
        "right_after": after,
    }


def listening_ports(pid):
    """The TCP ports process `pid` listens on (its sockets' inodes in /proc/net/tcp)."""
    import os
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = set()
    with open("/proc/net/tcp") as f:
        for line in list(f)[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:
                ports.add(int(fields[1].split(":")[1], 16))
    return ports


async def bypass(url, seconds, pid):
    public = int(url.rsplit(":", 1)[1])
    inner = sorted(listening_ports(pid) - {public})
    if len(inner) != 1:
        raise SystemExit(f"the crate's port: {inner}")
    c = await Client.open(f"ws://127.0.0.1:{inner[0]}")
    await c.advertised(ALL_TOPICS)
    await c.subscribe(ALL_TOPICS)
    await c.pump(seconds)
    got = await c.get_parameters("get", [])
    sets = await c.set_parameters(
        "set", [{"name": "live.rate_hz", "value": 100.0},
                {"name": "live.gate", "value": "00000000000000000000000000000000:1"}]
    )
    await c.ws.close()
    return {
        "inner_port": inner[0],
        "received": c.total(),
        "get": got,
        "set": sets,
        "statuses": c.statuses,
    }


def main():
    scene, url, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    token = sys.argv[4] if len(sys.argv) > 4 else ""
    if scene == "observe":
        result = asyncio.run(observe(url, seconds))
    elif scene == "tune":
        result = asyncio.run(tune(url, seconds, token))
    elif scene == "readonly":
        result = asyncio.run(readonly(url, seconds))
    elif scene == "flood":
        result = asyncio.run(flood(url, seconds, int(token)))
    elif scene == "bigset":
        result = asyncio.run(bigset(url, seconds, int(token)))
    elif scene == "bypass":
        result = asyncio.run(bypass(url, seconds, int(token)))
    elif scene == "brute":
        result = asyncio.run(brute(url, seconds, token))
    else:
        raise SystemExit(f"unknown scene {scene}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
