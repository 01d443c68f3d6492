"""Time encoding and decoding the trial record (msgspec against the standard library).

Usage::

    python benchmarks/bench_record.py [--records 2000] [--repeats 7]

Plays a few paper-sized trials once, then encodes and decodes their records ``--records``
times in all, ``--repeats`` times, and prints the median microseconds per record of:

* ``msgspec encode``: :func:`cirl_study.record.encode` (canonical JSON, keys sorted);
* ``json.dumps``: the standard library's canonical JSON of the same record as plain data;
* ``msgspec decode``: :func:`cirl_study.record.decode`, which also validates every type and
  range (the reader's path);
* ``json.loads``: the standard library's parse alone, with no validation at all;

and the ratios. The typed decode doing strictly more work than ``json.loads`` and still being
faster is why the record is a msgspec Struct.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable

from cirl_study.core.trial import play_trials
from cirl_study.features import RBFFeatures
from cirl_study.record import Grid, TrialSpec, decode, encode


def paper_records(count: int) -> list:
    """``count`` records of the paper's game (10 x 10, 9 steps, 10 features)."""
    specs = [
        TrialSpec(
            trial_id=f"main:bench-{i}:best_response:lambda=1.0:eta=0.316",
            run_id="bench",
            block="main",
            subject=f"bench-{i}",
            human="best_response",
            num_features=10,
            rationality=1.0,
            eta=0.316,
            seed=i,
            grid=Grid(width=10, height=10),
            start=(5, 5),
            learning_steps=9,
            deployment_steps=9,
            features=RBFFeatures(
                centers=tuple(
                    ((i * 7 + 3 * k) % 10 * 0.97, (k * 3) % 10 * 0.93) for k in range(10)
                ),
                sigma=1.5,
            ),
            theta=tuple(((i + k) % 7) / 3.5 - 1.0 for k in range(10)),
        )
        for i in range(count)
    ]
    return play_trials(specs)


def median_us(action: Callable[[], object], per: int, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        action()
        times.append((time.perf_counter() - began) / per * 1e6)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=2000, help="records per repeat")
    parser.add_argument("--repeats", type=int, default=7, help="repeats (default 7)")
    args = parser.parse_args()
    distinct = paper_records(20)
    records = [distinct[i % len(distinct)] for i in range(args.records)]
    plain = [json.loads(encode(record)) for record in records]
    payloads = [encode(record) for record in records]
    canonical = json.JSONEncoder(sort_keys=True, separators=(",", ":"), allow_nan=False)
    n, r = args.records, args.repeats
    timings = {
        "msgspec encode": median_us(lambda: [encode(x) for x in records], n, r),
        "json.dumps": median_us(lambda: [canonical.encode(x) for x in plain], n, r),
        "msgspec decode": median_us(lambda: [decode(x) for x in payloads], n, r),
        "json.loads": median_us(lambda: [json.loads(x) for x in payloads], n, r),
    }
    print(f"{n} records of {len(payloads[0])} bytes, median of {r} repeats, us per record")
    for name, value in timings.items():
        print(f"  {name:15s} {value:8.1f}")
    encode_ratio = timings["json.dumps"] / timings["msgspec encode"]
    decode_ratio = timings["json.loads"] / timings["msgspec decode"]
    print(f"encode: msgspec is {encode_ratio:.1f}x faster than json.dumps")
    print(f"decode: msgspec, validating, is {decode_ratio:.1f}x faster than json.loads alone")


if __name__ == "__main__":
    main()
