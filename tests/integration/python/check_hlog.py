"""Decodes a flexloop latency log (HdrHistogram interval log, one tag per
histogram) with the HdrHistogram Python package, merges the intervals of
every tag and prints count, max and percentiles per tag as JSON.

Percentiles are taken at rank ceil(q * count), the rank the Rust crate and
so flexloop's summary use (the Python package rounds instead).

usage: check_hlog.py FILE
"""
import json
import math
import sys

from hdrh.histogram import HdrHistogram
from hdrh.log import HistogramLogReader

QUANTILES = {"p50": 0.5, "p90": 0.9, "p99": 0.99, "p99.9": 0.999, "p99.99": 0.9999}


def main(path):
    reader = HistogramLogReader(path, HdrHistogram(1, 10_000_000_000, 3))
    merged = {}
    intervals = {}
    while True:
        h = reader.get_next_interval_histogram()
        if h is None:
            break
        tag = h.get_tag()
        if tag not in merged:
            merged[tag] = HdrHistogram(1, 10_000_000_000, 3)
        merged[tag].add(h)
        intervals[tag] = intervals.get(tag, 0) + 1
    out = {}
    for tag, h in merged.items():
        total = h.get_total_count()
        buckets = [
            (v.value_iterated_to, v.count_at_value_iterated_to)
            for v in h.get_recorded_iterator()
        ]
        entry = {"count": total, "max_ns": h.get_max_value(), "intervals": intervals[tag]}
        for label, q in QUANTILES.items():
            rank = max(1, math.ceil(q * total))
            seen = 0
            for value, count in buckets:
                seen += count
                if seen >= rank:
                    entry[label + "_ns"] = value
                    break
        out[tag] = entry
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
