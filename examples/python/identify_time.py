"""The module's overhead, measured (docs/book/src/python.md): the wall time of
`boucwen.identify` on a record, from a Record and from NumPy arrays, against the same call in
Rust (`crates/py/examples/identify_time.rs`), in rounds that alternate which side goes
first; the medians of all runs pooled.

    cargo build --release -p boucwen-py --example identify_time
    python examples/python/identify_time.py RECORD.csv [--model extended] [--rounds 6] [--runs 3]
"""

import argparse
import pathlib
import statistics
import subprocess
import time

import boucwen

ROOT = pathlib.Path(__file__).resolve().parents[2]
parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("record")
parser.add_argument("--model", default="extended")
parser.add_argument("--rounds", type=int, default=6)
parser.add_argument("--runs", type=int, default=3, help="runs of each side per round")
parser.add_argument("--rust", default=ROOT / "target/release/examples/identify_time", help="the Rust example")
args = parser.parse_args()

rec = boucwen.read_record(args.record)
u, y = rec.u, rec.y
times = {"Rust": [], "Python, from a Record": [], "Python, from arrays": []}
held = set()


def rust():
    out = subprocess.run(
        [str(args.rust), args.record, args.model, str(args.runs)], capture_output=True, text=True, check=True
    ).stdout
    times["Rust"] += [float(t) for t in out.split("each:")[1].split()]
    held.add(out.split("held out ")[1].split(" ")[0])


def python():
    for label, call in [
        ("Python, from a Record", lambda: boucwen.identify(rec, model=args.model)),
        ("Python, from arrays", lambda: boucwen.identify(u, y, rec.ts, model=args.model)),
    ]:
        for _ in range(args.runs):
            t = time.perf_counter()
            m = call()
            times[label].append(time.perf_counter() - t)
        held.add(f"{m.held_out_rms_um:.6f}")


for i in range(args.rounds):
    for side in (rust, python) if i % 2 == 0 else (python, rust):
        side()

base = statistics.median(times["Rust"])
print(f"identify --model {args.model} on {rec.source} ({len(rec)} samples), held out {' '.join(sorted(held))} µm")
for label, ts in times.items():
    m = statistics.median(ts)
    print(f"  {label:<22} median {m:.4f} s of {len(ts)} runs ({100 * (m / base - 1):+.1f} % against Rust)")
