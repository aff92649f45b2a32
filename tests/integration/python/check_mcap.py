"""Reads a flexloop sample file with the official MCAP Python reader and its
ROS1 decoder (genpy), independently of flexloop's Rust reader, and prints
what it found as one JSON object for the Rust test to check.

usage: check_mcap.py FILE
"""
import io
import json
import sys

from mcap.reader import make_reader
from mcap_ros1.decoder import DecoderFactory


def main(path):
    ros1 = DecoderFactory()
    out = {"channels": {}, "metadata": {}, "events": [], "statistics": None}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None:
            raise SystemExit(f"{path}: no summary section")
        stats = summary.statistics
        out["statistics"] = {
            "message_count": stats.message_count,
            "channel_message_counts": {
                summary.channels[cid].topic: n
                for cid, n in stats.channel_message_counts.items()
            },
            "chunk_count": stats.chunk_count,
        }
        for record in reader.iter_metadata():
            out["metadata"][record.name] = dict(record.metadata)
        offset = int(out["metadata"].get("flexloop", {}).get("log_time_offset_ns", "0"))
        for schema, channel, message in reader.iter_messages():
            c = out["channels"].setdefault(
                channel.topic,
                {
                    "schema": schema.name,
                    "schema_encoding": schema.encoding,
                    "message_encoding": channel.message_encoding,
                    "count": 0,
                    "seqs": [],
                    "header_sequence_matches": True,
                    "reserialises_identically": True,
                    "log_time_is_published_ns": True,
                },
            )
            c["count"] += 1
            if channel.message_encoding == "json":
                out["events"].append(json.loads(message.data))
                continue
            decoder = ros1.decoder_for(channel.message_encoding, schema)
            msg = decoder(message.data)
            c["seqs"].append(msg.seq)
            if message.sequence != msg.seq % (1 << 32):
                c["header_sequence_matches"] = False
            # genpy writes the decoded message back: the same bytes, or the
            # file's bytes are not ROS1 serialisation of its schema.
            buf = io.BytesIO()
            msg.serialize(buf)
            if buf.getvalue() != message.data:
                c["reserialises_identically"] = False
            if message.log_time != msg.published_ns + offset:
                c["log_time_is_published_ns"] = False
            if channel.topic == "/measurement" and "first_measurement" not in out:
                out["first_measurement"] = {
                    "seq": msg.seq,
                    "y": list(msg.y),
                    "u_applied": list(msg.u_applied),
                    "n_outputs": msg.n_outputs,
                }
    for c in out["channels"].values():
        seqs = c.pop("seqs")
        if seqs:
            distinct = sorted(set(seqs))
            c["first_seq"] = distinct[0]
            c["last_seq"] = distinct[-1]
            c["distinct"] = len(distinct)
            c["missing"] = distinct[-1] - distinct[0] + 1 - len(distinct)
            c["in_order"] = all(a < b for a, b in zip(seqs, seqs[1:]))
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
