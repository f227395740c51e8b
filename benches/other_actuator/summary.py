"""One line per record of `boucwen diagnose --json` (stdin: one object per line): the drive
read, the window, the noise floor, the baseline's held-out error and the findings, or the
sentence of a record that gets no diagnosis.

    boucwen diagnose DIR/*.csv --json 2>/dev/null | python3 benches/other_actuator/summary.py
"""
import json
import os
import sys

print("| record | drive read | window (s) | noise floor (µm) | baseline held out (µm) | findings, or the sentence |")
print("|---|---|---|---|---|---|")
for line in sys.stdin:
    d = json.loads(line)
    name = os.path.basename(d["file"]).removesuffix(".csv")
    if d.get("step"):
        name += f" (step {d['step']['index']} of {d['step']['of']}, {d['step']['amplitude_v']:.1f} V)"
    if "error" in d:
        print(f"| {name} | | | | | {d['error'].split(': ', 1)[-1]} |")
        continue
    drive = d["drive"]
    kind = drive["kind"]
    hz = drive.get("freq_hz") or (1.0 / drive["period_s"] if drive.get("period_s") else 0.0)
    read = f"{kind} {hz:.3f} Hz"
    if drive.get("thd_pct") is not None and kind == "sine":
        read += f", {drive['thd_pct']:.2f} %"
    w = d.get("window_s") or (d.get("windows_s") or [[None, None]])[0]
    win = f"{w[0]:.3f}–{w[1]:.3f}"
    spikes = (d.get("import") or {}).get("spikes") if isinstance(d.get("import"), dict) else None
    base = d["baseline"]
    rms = "unstable" if base.get("rms_um") is None else f"{base['rms_um']:.4f}"
    found = []
    for f in d["findings"]:
        k = f["kind"] + (f" {f['order']}" if f.get("order") else "")
        if not f.get("kept", True):
            k += " (not removed)"
        found.append(k)
    text = ", ".join(found) if found else "none"
    if spikes:
        text += f"; {spikes['count']} dropouts repaired on reading"
    print(f"| {name} | {read} | {win} | {d['noise_um']:.4f} | {rms} | {text} |")
