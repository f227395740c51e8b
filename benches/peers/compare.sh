#!/usr/bin/env bash
# The output-error fit against the Python peer (oe_peer.py) on the records of
# examples/peer_records.rs: time in-process and whole-process, held-out RMS, and a careful
# LM run started from the project's result. Prints a Markdown table. Not run in CI.
#
#   python3 -m venv benches/peers/.venv
#   benches/peers/.venv/bin/pip install -r benches/peers/requirements.txt
#   bash benches/peers/compare.sh [RUNS]     # RUNS timings per record (default 5), medians
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${1:-5}
PY=${PEER_PYTHON:-benches/peers/.venv/bin/python}
DIR=target/peer-records
cargo build --release -q -p boucwen-cli --bin boucwen
cargo run --release -q --example peer_records -- "$DIR"
# One peer run compiles numba's cache; the timed runs load it.
"$PY" benches/peers/oe_peer.py "$DIR/clean-1.csv" --json > /dev/null
now() { date +%s.%N; }
for f in "$DIR"/*.csv; do
    b=${f%.csv}
    : > "$b.times"
    for _ in $(seq "$RUNS"); do
        t0=$(now); target/release/boucwen identify "$f" --json > "$b.rust.json"; t1=$(now)
        "$PY" benches/peers/oe_peer.py "$f" --json > "$b.peer.json"; t2=$(now)
        python3 - "$b" "$t0" "$t1" "$t2" >> "$b.times" <<'PYEOF'
import json, sys
b, t0, t1, t2 = sys.argv[1], *map(float, sys.argv[2:])
r, p = json.load(open(b + ".rust.json")), json.load(open(b + ".peer.json"))
print(json.dumps([r["fit"]["seconds"], t1 - t0, p["fit_seconds"], t2 - t1]))
PYEOF
    done
    "$PY" benches/peers/oe_peer.py "$f" --json --start-from "$b.rust.json" > "$b.check.json"
done
python3 - "$DIR" <<'PYEOF'
import glob, json, statistics as st, sys
d = sys.argv[1]
print("| record | drive (Hz) | fit, project (ms) | fit, peer (ms) | ratio | whole process, project (s) | whole process, peer (s) | held-out RMS, project (µm) | held-out RMS, peer (µm) | difference | stop | LM from the project's result |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for f in sorted(glob.glob(d + "/*.csv")):
    b = f[:-4]
    times = [json.loads(l) for l in open(b + ".times")]
    rf, rw, pf, pw = (st.median(t[i] for t in times) for i in range(4))
    r, p, c = (json.load(open(b + e)) for e in (".rust.json", ".peer.json", ".check.json"))
    diff = 100 * (r["rms_um"] / p["rms_um"] - 1)
    print(f"| {b.split('/')[-1]} | {r['drive_hz']:.2f} | {1e3*rf:.1f} | {1e3*pf:.1f} | {pf/rf:.1f}× | {rw:.3f} | {pw:.2f} "
          f"| {r['rms_um']:.4f} | {p['rms_um']:.4f} | {diff:+.2f} % | {r['fit']['stop']} | {c['lowered_pct']:.3f} % lower |")
PYEOF
