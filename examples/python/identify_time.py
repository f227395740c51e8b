"""The Python side of the module's overhead measurement (docs/book/src/python.md): the median
wall time of `boucwen.identify` on a record, from a Record and from NumPy arrays. The Rust
side is `cargo run --release -p boucwen-py --example identify_time -- RECORD.csv [MODEL] [RUNS]`.

    python examples/python/identify_time.py RECORD.csv [MODEL] [RUNS]
"""

import statistics
import sys
import time

import boucwen

path = sys.argv[1]
model = sys.argv[2] if len(sys.argv) > 2 else "extended"
runs = int(sys.argv[3]) if len(sys.argv) > 3 else 7
rec = boucwen.read_record(path)
u, y = rec.u, rec.y

for label, call in [
    ("Record", lambda: boucwen.identify(rec, model=model)),
    ("arrays", lambda: boucwen.identify(u, y, rec.ts, model=model)),
]:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        m = call()
        times.append(time.perf_counter() - t)
    print(
        f"python identify(model={model!r}) from {label}: {len(rec)} samples, median {statistics.median(times):.4f} s "
        f"of {runs} runs (min {min(times):.4f}, max {max(times):.4f}), held out {m.held_out_rms_um:.6f} µm; "
        f"each: {' '.join(f'{t:.4f}' for t in times)}"
    )
