"""The Bouc-Wen benchmark from Python, notebook style: read the training record, diagnose it,
identify a model (fitted on its first periods), and score the model on the fifth period,
which the fit never saw. Plots the held-out period if matplotlib is installed.

    pip install ./crates/py            # once, in a virtual environment
    python examples/python/benchmark.py [TRAIN.csv] [--plot FILE.png]

The record defaults to ../shared/data/bouc-wen-benchmark/train.csv beside the repository
(40,960 samples at 750 Hz: five periods of one multisine; force u in N, displacement y in m).
"""

import argparse
import pathlib
import time

import numpy as np

import boucwen

ROOT = pathlib.Path(__file__).resolve().parents[2]
PERIOD = 8192  # samples per period of the benchmark's multisine

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("record", nargs="?", default=ROOT.parent / "shared/data/bouc-wen-benchmark/train.csv")
parser.add_argument("--plot", default="benchmark.png", help="where to draw the held-out period (PNG)")
args = parser.parse_args()

# 1. Read: the importer of the commands; y is written in metres, the library works in µm.
rec = boucwen.read_record(args.record, units={"y": "m"})
print(f"{rec.source}: {len(rec)} samples every {rec.ts:.6g} s, read as {rec.notes}")

# 2. Diagnose: what the paper's actuator model gets wrong, and the cause.
t = time.perf_counter()
d = boucwen.diagnose(rec)
print(f"\ndiagnose ({d.analysis} drive, {time.perf_counter() - t:.1f} s):")
for f in d.findings:
    print(f"  - {f['kind']}: {f['cause']}")

# 3. Identify: every family fitted on the first part of the record's steady window (whole
#    periods: here the first three), scored on the rest; one kept by the stated rule.
t = time.perf_counter()
model = boucwen.identify(rec, model="auto")
fitted = model.report["fit_samples"]
print(f"\nidentify ({time.perf_counter() - t:.1f} s): kept {model}, fitted on the first {fitted // PERIOD} periods")
for name, value in model.params.items():
    print(f"  {name:>12} = {value:.6g}")
assert fitted <= 4 * PERIOD, "the fit saw the fifth period"

# 4. Compare on the fifth period, in steady state (the period run once before the scored
#    one), as the benchmark scores its test multisine.
held = slice(4 * PERIOD, 5 * PERIOD)
c = model.compare(rec.u[held], rec.y[held], periodic=True)
print(f"\nheld-out period 5: RMS error {c['rms_um']:.3f} µm, FIT {c['fit_pct']:.2f} %"
      f" (output RMS {c['output_rms_um']:.1f} µm; the record's noise is about 7.4 µm)")
assert np.isfinite(c["rms_um"]) and c["fit_pct"] > 90.0, "the held-out fit is worse than expected"

# 5. Plot, if matplotlib is there.
try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("\nmatplotlib is not installed: no plot (pip install matplotlib)")
else:
    time_s = np.arange(PERIOD) * rec.ts
    first = time_s < 0.5  # the outputs over the period's first half second, the error over all of it
    fig, (a, b) = plt.subplots(2, 1, figsize=(8, 5))
    a.plot(time_s[first], rec.y[held][first], label="measured", lw=1.5)
    a.plot(time_s[first], c["simulated"][first], "--", label=f"{model.name}, free run", lw=1)
    a.set_ylabel("y (µm)")
    a.legend()
    b.plot(time_s, rec.y[held] - c["simulated"], lw=0.4, color="C3")
    b.set_ylabel("error (µm)")
    b.set_xlabel("time in period 5 (s)")
    fig.suptitle(f"Bouc-Wen benchmark, held-out period: RMS {c['rms_um']:.2f} µm, FIT {c['fit_pct']:.1f} %")
    fig.tight_layout()
    fig.savefig(args.plot, dpi=120)
    print(f"\nwrote {args.plot}")
