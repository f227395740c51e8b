#!/usr/bin/env python3
"""A reference output-error fit of the extended model, to compare with `boucwen identify`.

The same model and simulation as the project's `fit::fit_oe` (extended model, AR order 2,
Bouc-Wen loop with the amplitude factored out, no input delay, no offset), the same
variable projection (A1 and A solved by least squares for every outer point, A >= 0), the
same grid of starts (16 resonances x 6 dampings at a middle loop shape, then 8 loop shapes
on the best 6 structures, Levenberg-Marquardt from the best 5), and the same criterion
samples as `boucwen identify` (the fitted part after its start-up: a fifth of it, at most
1 s, at least 200 samples). Unlike the project it fits sample by sample, every sample of the
criterion. The simulation and the exact Jacobian (forward sensitivities, Kaufman's form of
the projected Jacobian) are compiled with numba; the refinement is
scipy.optimize.least_squares(method='lm') (MINPACK) with tolerances 1e-10.

    python oe_peer.py RECORD.csv [--fit-fraction 0.5] [--json] [--start-from IDENTIFY.json]

`--start-from` takes the JSON of `boucwen identify --json` and runs the same careful LM from
that result on this criterion, reporting the cost before and after (the project's result
is converged when LM cannot lower it).

Not run in CI. See benches/peers/README.md for the setup and the comparison script.
"""
import argparse
import json
import sys
import time

import numpy as np
from numba import njit
from scipy.optimize import least_squares


@njit(cache=True)
def columns(u, phi, skip, end):
    """Filtered columns z = G u, z = -G h1 over [skip, end) and their sensitivities."""
    a1, a2, r0, g, b = phi[0], phi[1], phi[2], phi[3], phi[4]
    m = end - skip
    Z = np.zeros((m, 2))
    S1 = np.zeros((m, 2))  # dz/da1 per column
    S2 = np.zeros((m, 2))  # dz/da2 per column
    GH = np.zeros((m, 3))  # G dh1/d(r0, g, b)
    z1 = np.zeros(2)
    z2 = np.zeros(2)
    s1 = np.zeros(2)
    s2 = np.zeros(2)
    gs1 = np.zeros(3)
    gs2 = np.zeros(3)
    dh = np.zeros(3)
    x = np.zeros(2)
    h = 0.0
    up = 0.0
    for k in range(end):
        uk = u[k]
        du = uk - up
        sh = 1.0 if h > 0 else (-1.0 if h < 0 else 0.0)
        adu = abs(du)
        dhdh = 1.0 - g * sh * du - b * adu
        dh[0] = dhdh * dh[0] + adu
        dh[1] = dhdh * dh[1] - abs(h) * du
        dh[2] = dhdh * dh[2] - h * adu
        h = h + (1.0 - g * abs(h)) * du + (r0 - b * h) * adu
        if not np.isfinite(h) or abs(h) > 1e12:
            return Z, S1, S2, GH, False
        x[0] = uk
        x[1] = -h
        for i in range(2):
            s = a1 * s1[i] + a2 * s2[i] + z1[i]
            s2[i] = s1[i]
            s1[i] = s
            v = a1 * z1[i] + a2 * z2[i] + x[i]
            z2[i] = z1[i]
            z1[i] = v
        for q in range(3):
            v = a1 * gs1[q] + a2 * gs2[q] + dh[q]
            gs2[q] = gs1[q]
            gs1[q] = v
        up = uk
        if k >= skip:
            j = k - skip
            for i in range(2):
                Z[j, i] = z1[i]
                S1[j, i] = s1[i]
                S2[j, i] = s2[i]
            for q in range(3):
                GH[j, q] = gs1[q]
    return Z, S1, S2, GH, True


def stable(a1, a2):
    # Roots of z^2 - a1 z - a2 inside the unit circle (Jury's conditions).
    return abs(a2) < 1.0 and abs(a1) < 1.0 - a2


class Problem:
    def __init__(self, u, y, skip, end):
        self.u, self.y, self.skip, self.end = u, y[skip:end], skip, end
        self.last = (None, None)

    def solve(self, phi):
        """theta, residual and the pieces of the Jacobian, or None when unstable (the last
        one is kept: least_squares asks for the residual and the Jacobian at the same point)."""
        key = np.asarray(phi, dtype=np.float64).tobytes()
        if self.last[0] == key:
            return self.last[1]
        out = self._solve(phi)
        self.last = (key, out)
        return out

    def _solve(self, phi):
        if not (np.all(np.isfinite(phi)) and stable(phi[0], phi[1])):
            return None
        Z, S1, S2, GH, ok = columns(self.u, np.asarray(phi, dtype=np.float64), self.skip, self.end)
        if not ok:
            return None
        G = Z.T @ Z
        G[np.diag_indices(2)] += 1e-12 * G.diagonal().max() + 1e-300
        rhs = Z.T @ self.y
        theta = np.linalg.solve(G, rhs)
        active = [0, 1]
        if theta[1] < 0.0:  # A >= 0: the bound is active
            theta = np.array([rhs[0] / G[0, 0], 0.0])
            active = [0]
        r = self.y - Z @ theta
        return theta, r, Z, S1, S2, GH, active, G

    def cost(self, phi):
        s = self.solve(phi)
        return np.inf if s is None else float(s[1] @ s[1])

    def residual(self, phi):
        s = self.solve(phi)
        return 1e3 * self.y if s is None else s[1]

    def jacobian(self, phi):
        s = self.solve(phi)
        if s is None:
            return np.zeros((len(self.y), 5))
        theta, r, Z, S1, S2, GH, active, G = s
        V = np.column_stack([S1 @ theta, S2 @ theta, -theta[1] * GH])
        Za = Z[:, active]
        coef = np.linalg.solve(G[np.ix_(active, active)], Za.T @ V)
        return -(V - Za @ coef)

    def model(self, phi):
        theta = self.solve(phi)[0]
        return dict(ar=[phi[0], phi[1]], a1=theta[0], a=theta[1], a0=phi[2] * theta[1],
                    gamma=(1.0 if theta[1] >= 0 else -1.0) * phi[3], beta=phi[4])


def resonance_ar(f_hz, zeta, ts):
    w = 2 * np.pi * f_hz * ts
    if zeta < 1.0:
        r = np.exp(-zeta * w)
        return [2 * r * np.cos(w * np.sqrt(1 - zeta * zeta)), -r * r]
    s = np.sqrt(zeta * zeta - 1)
    r1, r2 = np.exp(-(zeta - s) * w), np.exp(-(zeta + s) * w)
    return [r1 + r2, -r1 * r2]


def lm(prob, start):
    res = least_squares(prob.residual, start, jac=prob.jacobian, method="lm",
                        ftol=1e-10, xtol=1e-10, gtol=1e-10, x_scale="jac")
    return res.x, prob.cost(res.x), res.nfev, res.status


def fit(u, y, ts, split, lm_starts=5):
    skip = max(min(split // 5, int(1.0 / ts)), 200)
    prob = Problem(u, y, skip, split)
    u_amp = max(np.abs(u[:split]).max(), 1e-9)
    nyq = 0.5 / ts
    mid = [0.0, 0.75 / u_amp, 2.25 / u_amp]
    ranked = []
    for i in range(16):
        f_r = 5.0 * (nyq * 0.9 / 5.0) ** (i / 15.0)
        for zeta in [0.01, 0.03, 0.1, 0.3, 1.0, 3.0]:
            phi = np.array(resonance_ar(f_r, zeta, ts) + mid)
            c = prob.cost(phi)
            if np.isfinite(c):
                ranked.append((c, phi))
    ranked.sort(key=lambda t: t[0])
    cands = []
    for _, s in ranked[:6]:
        for kappa in [0.3, 1.0, 3.0, 10.0]:
            for q in [-0.5, 0.5]:
                total = kappa / u_amp
                phi = np.array([s[0], s[1], 0.0, total * q / 2, total * (1 - q / 2)])
                c = prob.cost(phi)
                if np.isfinite(c):
                    cands.append((c, phi))
    cands.sort(key=lambda t: t[0])
    best = None
    for _, start in cands[:lm_starts]:
        x, c, nfev, status = lm(prob, start)
        if best is None or c < best[1]:
            best = (x, c, nfev, status)
    return prob, best


def simulate(model, u):
    a1, a2 = model["ar"]
    A1, A, A0, g, b = model["a1"], model["a"], model["a0"], model["gamma"], model["beta"]
    return _simulate(u, a1, a2, A1, A, A0, g, b)


@njit(cache=True)
def _simulate(u, a1, a2, A1, A, A0, g, b):
    y = np.zeros(len(u))
    h = 0.0
    up = 0.0
    y1 = 0.0
    y2 = 0.0
    for k in range(len(u)):
        du = u[k] - up
        h = h + (A - g * abs(h)) * du + (A0 - b * h) * abs(du)
        v = a1 * y1 + a2 * y2 + A1 * u[k] - h
        y2 = y1
        y1 = v
        y[k] = v
        up = u[k]
    return y


def main():
    p = argparse.ArgumentParser()
    p.add_argument("record")
    p.add_argument("--fit-fraction", type=float, default=0.5)
    p.add_argument("--json", action="store_true")
    p.add_argument("--start-from")
    a = p.parse_args()
    d = np.genfromtxt(a.record, delimiter=",", names=True)
    t, u, y = d["t"], np.ascontiguousarray(d["u"]), np.ascontiguousarray(d["y"])
    ts = float(np.median(np.diff(t)))
    split = int(round(a.fit_fraction * len(u)))
    # Compile (or load the cache) before timing the fit.
    columns(u[:300], np.array([0.5, -0.1, 0.0, 0.1, 0.1]), 0, 300)
    _simulate(u[:10], 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    out = {"record": a.record}
    if a.start_from:
        with open(a.start_from) as f:
            r = json.load(f)["params"]
        amp = r["a"]
        start = np.array([r["ar"][0], r["ar"][1], r["a0"] / amp, np.sign(amp) * r["gamma"], r["beta"]])
        skip = max(min(split // 5, int(1.0 / ts)), 200)
        prob = Problem(u, y, skip, split)
        c0 = prob.cost(start)
        x, c1, nfev, status = lm(prob, start)
        out.update(cost_start=c0, cost_lm=c1, lowered_pct=100 * (1 - c1 / c0), nfev=nfev)
        print(json.dumps(out) if a.json else out)
        return
    t0 = time.perf_counter()
    prob, (x, c, nfev, status) = fit(u, y, ts, split)
    elapsed = time.perf_counter() - t0
    model = prob.model(x)
    sim = simulate(model, u)
    held = float(np.sqrt(np.mean((sim[split:] - y[split:]) ** 2)))
    out.update(fit_seconds=elapsed, rms_um=held, fit_rms_um=float(np.sqrt(c / len(prob.y))), nfev=nfev,
               status=int(status), params=model)
    print(json.dumps(out) if a.json else out)


if __name__ == "__main__":
    sys.exit(main())
