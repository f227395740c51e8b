"""Records of actuators that are not boucwen's virtual bimorph, written as benches write them.

The hysteresis is a Prandtl-Ishlinskii sum of play operators (not a Bouc-Wen loop), with
optional log-spaced creep, a 2nd-order structure (bilinear), a cubic stiffening, sensor noise,
quantisation and dropouts; drives as benches use them (unipolar 0-100 V for stacks, triangles,
squares, slow sines, chirps, amplitude steps, idle starts). Deterministic (fixed seeds).

    python3 benches/other_actuator/records.py DIR      # then: boucwen diagnose DIR/*.csv

Needs numpy and scipy (pip install numpy scipy). Not run in CI: a measurement, see the
book's "Records of another actuator" (docs/book/src/diagnosis/other-actuator.md).
"""
import os
import sys

import numpy as np
from scipy.signal import bilinear, lfilter

OUT = sys.argv[1] if len(sys.argv) > 1 else "other-actuator"
os.makedirs(OUT, exist_ok=True)
RNG = np.random.default_rng(7)


def play_hysteresis(u, umax):
    """Prandtl-Ishlinskii: ten play operators of radii 0..0.9 umax, weights falling off."""
    radii = np.linspace(0, umax, 11)[:-1]
    w = np.exp(-np.arange(10) / 3.0)
    w /= w.sum()
    z = np.zeros(10)
    h = np.empty(len(u))
    for k, x in enumerate(u):
        z = np.minimum(np.maximum(z, x - radii), x + radii)
        h[k] = w @ z
    return h


def structure(x, fs, fn, zeta):
    wn = 2 * np.pi * fn
    b, a = bilinear([wn * wn], [1, 2 * zeta * wn, wn * wn], fs)
    return lfilter(b, a, x)


def creep(u, fs):
    y = np.zeros(len(u))
    for tau, g in [(0.5, 0.3), (5.0, 0.3), (50.0, 0.4)]:
        al = np.exp(-1 / (fs * tau))
        y += g * lfilter([1 - al], [1, -al], u)
    return y


def actuator(u, fs, umax, stroke_um, fn=2000.0, zeta=0.05, creep_share=0.0, cubic=0.0,
             noise_um=0.002, lsb_um=None):
    x = (0.88 * u + 0.12 * play_hysteresis(u, umax)) * stroke_um / umax
    if creep_share:
        x = x + creep_share * stroke_um / umax * creep(u, fs)
    y = structure(x, fs, fn, zeta)
    if cubic:
        y = y + cubic * (y - y.mean()) ** 3 / stroke_um ** 2
    y = y + noise_um * RNG.standard_normal(len(y))
    if lsb_um:
        y = np.round(y / lsb_um) * lsb_um
    return y


def write(name, cols, data, sep=","):
    np.savetxt(f"{OUT}/{name}.csv", np.column_stack(data), delimiter=sep, header=sep.join(cols),
               comments="", fmt="%.7g")


def t_axis(fs, seconds):
    return np.arange(int(round(fs * seconds))) / fs


def triangle(t, f):
    p = (t * f) % 1.0
    return np.where(p < 0.5, 2 * p, 2 - 2 * p)


STACK = ["Time [s]", "Voltage [V]", "Displacement [um]"]

# Piezo stacks (15 um at 100 V, first mode 2 kHz).
fs = 10000; t = t_axis(fs, 10); u = 50 - 50 * np.cos(2 * np.pi * t)
write("stack-unipolar-sine-1hz", STACK, [t, u, actuator(u, fs, 100, 15, lsb_um=0.0003)])
fs = 10000; t = t_axis(fs, 5); u = 100 * triangle(t, 1.0)
write("stack-triangle-1hz-unit-names", ["s", "V", "um"], [t, u, actuator(u, fs, 100, 15)])
t = t_axis(fs, 10); u = 50 - 50 * np.exp(-t / 4) * np.cos(2 * np.pi * t)
write("stack-decaying-sine", STACK, [t, u, actuator(u, fs, 100, 15)])
fs = 1000; t = t_axis(fs, 30); u = 50 - 50 * np.cos(2 * np.pi * 0.1 * t)
write("stack-creep-0.1hz-3-periods", STACK, [t, u, actuator(u, fs, 100, 15, fn=200, creep_share=0.15)])
fs = 2000; t = t_axis(fs, 20); u = 50 - 50 * np.cos(2 * np.pi * 2 * t)
write("stack-creep-unipolar-2hz", STACK, [t, u, actuator(u, fs, 100, 15, fn=400, creep_share=0.1)])
fs = 2000; t = t_axis(fs, 20); f0, f1 = 0.5, 20
u = 50 - 50 * np.cos(2 * np.pi * (f0 * t + (f1 - f0) / 40 * t * t))
write("stack-chirp-0.5-20hz", STACK, [t, u, actuator(u, fs, 100, 15, fn=400)])
fs = 50000; t = t_axis(fs, 1); u = 50 * np.sin(2 * np.pi * 10 * t)
write("stack-50khz-1s-10hz", STACK, [t, u, actuator(u, fs, 50, 8)])
fs = 2000; t = t_axis(fs, 16); amp = np.select([t < 4, t < 8, t < 12], [20, 40, 60], 80)
u = amp * np.sin(2 * np.pi * 2 * t)
write("stack-amplitude-steps", STACK, [t, u, actuator(u, fs, 80, 12, fn=400)])
fs = 10000; t = t_axis(fs, 10); u = 40 * np.sin(2 * np.pi * 5 * t)
write("stack-bipolar-5hz-semicolons", ["t", "u", "y"], [t, u, actuator(u, fs, 40, 6)], sep=";")
fs = 5000; t = t_axis(fs, 10); u0 = 50 - 50 * np.cos(2 * np.pi * 2 * t)
y = actuator(u0, fs, 100, 15)
write("stack-noisy-drive-monitor", STACK, [t, u0 + 0.05 * RNG.standard_normal(len(t)), y])
fs = 20000; t = t_axis(fs, 4); u = 40 * np.sin(2 * np.pi * 5 * np.floor(t * 1000) / 1000)
write("stack-dac-steps-1khz-sampled-20khz", STACK, [t, u, actuator(u, fs, 40, 6)])
fs = 10000; t = t_axis(fs, 20); u = 50 - 50 * np.cos(2 * np.pi * t)
write("stack-sensor-offset-and-drift", STACK, [t, u, 35 + actuator(u, fs, 100, 15) + 0.02 * t])
fs = 5000; t = t_axis(fs, 8); u = np.where(np.arange(len(t)) % 5000 < 2500, 90.0, 10.0)
write("stack-square-1hz", STACK, [t, u, actuator(u, fs, 100, 15, fn=1500, zeta=0.02)])
fs = 1000; t = t_axis(fs, 8); u = 50 * np.sin(2 * np.pi * 0.5 * t)
write("stack-exactly-4-periods", STACK, [t, u, actuator(u, fs, 50, 8, fn=200)])
fs = 10000; t = t_axis(fs, 12); u = np.where(t < 3, 50.0, 50 + 50 * np.sin(2 * np.pi * 3 * (t - 3)))
write("stack-bias-then-sine", STACK, [t, u, actuator(u, fs, 100, 15)])
fs = 5000; t = t_axis(fs, 8); u = np.where(t < 2, 0.0, 60 * np.sin(2 * np.pi * 5 * (t - 2)))
write("stack-idle-start-inverted-sensor-ms", ["Time (ms)", "drive", "position"],
      [t * 1000, u, -actuator(u, fs, 60, 8, fn=800, zeta=0.03)])
fs = 2000; t = t_axis(fs, 10); u = 5 * np.sin(2 * np.pi * 2 * t)
write("stack-12-bit-sensor", STACK, [t, u, actuator(u, fs, 5, 3, fn=1000 * 0.4, lsb_um=100 / 4096)])
u = 0.05 * np.sin(2 * np.pi * 2 * t)
write("stack-drive-too-small", STACK, [t, u, actuator(u, fs, 5, 0.005, fn=400, noise_um=0.003)])
fs = 100; t = t_axis(fs, 20); u = 50 * np.sin(2 * np.pi * 10 * t)
write("stack-10-samples-per-period", STACK, [t, u, actuator(u, fs, 50, 8, fn=40, zeta=0.3)])

# Bimorphs (20 um at 1 V, first mode 70 Hz, a cubic stiffening), sampled at 1 kHz.
fs = 1000; t = t_axis(fs, 10)
for f in [5, 14, 23, 35]:
    u = np.sin(2 * np.pi * f * t)
    y = actuator(u, fs, 1, 20, fn=70, zeta=0.02, cubic=0.3, noise_um=0.01)
    write(f"bimorph-{f}hz", ["t", "u", "y"], [t, u, y])
    if f != 35:
        write(f"bimorph-{f}hz-sensor-0.5um-steps", ["t", "u", "y"], [t, u, np.round(y / 0.5) * 0.5])
        yd = y.copy()
        idx = RNG.choice(np.arange(10, len(y) - 10), 15, replace=False)
        yd[idx] += RNG.choice([-1, 1], 15) * RNG.uniform(20, 60, 15)
        write(f"bimorph-{f}hz-dropouts", ["t", "u", "y"], [t, u, yd])
print(f"wrote {len(os.listdir(OUT))} records to {OUT}")
