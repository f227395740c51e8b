//! A linear MIMO state-space model in modal form: subspace identification from the BLA,
//! then output-error refinement.
//!
//! ## The model ([`ModalSs`])
//! ```text
//! x[k+1] = A x[k] + B u[k],   y[k] = C x[k] + D u[k],   G(z) = C (zI − A)⁻¹ B + D
//! ```
//! with `A` block diagonal (real modal form): a pair of poles `σ ± iω` is the block
//! `[[σ, ω], [−ω, σ]]`, a real pole `λ` the block `[λ]`. Its resolvent is
//! `(zI − A_b)⁻¹ = [[z−σ, ω], [−ω, z−σ]] / ((z−σ)² + ω²)`. The model is stable when every
//! pole is inside the unit circle (`σ² + ω² < 1`, `|λ| < 1`).
//!
//! ## Subspace identification ([`fsid`]; McKelvey, Akçay and Ljung, IEEE TAC 41(7), 1996)
//! From `G(z_k)` on `K` lines, with `q` block rows:
//! ```text
//! Y = [z_k^i G(z_k)]_{i<q, k}  (qp × Km),   U = [z_k^i I_m]_{i<q, k}  (qm × Km)
//! ```
//! realified (`[Re, Im]`), the column space of `Y Π⊥_U` (the part of `Y` orthogonal to `U`)
//! is that of the extended observability matrix. It is taken from the Gram matrix:
//! `Y Π⊥ Yᵀ = H_yy − H_yu H_uu⁻¹ H_uy`, whose leading `n` eigenvectors give `O`; then
//! `C = O[0:p]`, `A = O[0:(q−1)p]⁺ O[p:qp]`. Unstable poles are reflected into the unit
//! circle (`λ → 1/λ̄`), `A` is brought to modal form, and `B`, `D` are the least-squares
//! solution of `Σ_k ‖G(z_k) − D − C(z_kI − A)⁻¹B‖²_F` ([`ModalSs::fit_bd`]).
//!
//! ## Output-error refinement ([`refine_oe`])
//! The simulation error over steady-state periods, summed over the realisations `r` of every
//! kept level, is on each line (see the module docs of [`super`])
//! ```text
//! Σ_r |Y_r − G U_r|² = ‖(G − Ĝ) L‖²_F + const,   S = Σ_r U_r U_rᴴ = L Lᴴ,   Ĝ = (Σ_r Y_r U_rᴴ) S⁻¹
//! ```
//! so the cost is that of `p × m` residuals per line, whatever the number of realisations
//! ([`OeData`]). Levenberg–Marquardt minimises it over the poles (`σ, ω` or `λ`), `B`, `C`
//! and `D` with the exact Jacobian: with `R = (zI − A)⁻¹`,
//! `∂G/∂σ_b = C_b R_b² B_b`, `∂G/∂ω_b = C_b R_b J R_b B_b` (`J = [[0,1],[−1,0]]`),
//! `∂G/∂B_{ij} = (CR)_{:,i} e_jᵀ`, `∂G/∂C_{oi} = e_o (RB)_{i,:}`, `∂G/∂D_{oj} = e_o e_jᵀ`.
//! A step that makes a pole leave the unit circle is refused.

use super::MimoError;
use super::spectra::{C64, Spectra};
use nalgebra::{Complex, DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One block of the modal `A` (discrete time).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Mode {
    /// A real pole `λ`.
    Real(f64),
    /// A pair `σ ± iω` (`ω > 0`), block `[[σ, ω], [−ω, σ]]`.
    Pair {
        /// Real part.
        sigma: f64,
        /// Imaginary part.
        omega: f64,
    },
}

impl Mode {
    /// States of the block (1 or 2).
    pub fn size(&self) -> usize {
        match self {
            Mode::Real(_) => 1,
            Mode::Pair { .. } => 2,
        }
    }
    /// The largest pole magnitude.
    pub fn radius(&self) -> f64 {
        match *self {
            Mode::Real(l) => l.abs(),
            Mode::Pair { sigma, omega } => sigma.hypot(omega),
        }
    }
    /// Frequency (Hz) and damping ratio of the equivalent continuous pole at `fs`.
    pub fn frequency_damping(&self, fs: f64) -> (f64, f64) {
        let l = match *self {
            Mode::Real(l) => Complex::new(l, 0.0),
            Mode::Pair { sigma, omega } => Complex::new(sigma, omega),
        };
        let s = l.ln() * fs;
        (s.norm() / std::f64::consts::TAU, if s.norm() > 0.0 { -s.re / s.norm() } else { 1.0 })
    }
}

/// A linear state-space model in real modal form (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct ModalSs {
    /// The blocks of `A`, in state order.
    pub modes: Vec<Mode>,
    /// `B`, `n × m`.
    pub b: DMatrix<f64>,
    /// `C`, `p × n`.
    pub c: DMatrix<f64>,
    /// `D`, `p × m`.
    pub d: DMatrix<f64>,
}

/// The resolvent `(zI − A)⁻¹` of a modal `A`, one block per mode.
pub(crate) struct Resolvent {
    /// Per mode: its first state and its 2 × 2 (or 1 × 1 in `[0][0]`) block.
    pub blocks: Vec<(usize, [[C64; 2]; 2])>,
}

impl Resolvent {
    pub(crate) fn new(modes: &[Mode], z: C64) -> Self {
        let mut at = 0;
        let blocks = modes
            .iter()
            .map(|md| {
                let b = match *md {
                    Mode::Real(l) => {
                        let r = (z - l).inv();
                        [[r, Complex::new(0.0, 0.0)], [Complex::new(0.0, 0.0), Complex::new(0.0, 0.0)]]
                    }
                    Mode::Pair { sigma, omega } => {
                        let a = z - sigma;
                        let den = (a * a + omega * omega).inv();
                        [[a * den, den * omega], [-den * omega, a * den]]
                    }
                };
                let out = (at, b);
                at += md.size();
                out
            })
            .collect();
        Self { blocks }
    }

    /// `M R` for `M` with `n` columns (`rows × n`).
    pub(crate) fn right_of(&self, m: &DMatrix<f64>, modes: &[Mode]) -> DMatrix<C64> {
        let mut out = DMatrix::<C64>::zeros(m.nrows(), m.ncols());
        for ((i0, r), md) in self.blocks.iter().zip(modes) {
            let s = md.size();
            for row in 0..m.nrows() {
                for j in 0..s {
                    out[(row, i0 + j)] = (0..s).map(|a| r[a][j] * m[(row, i0 + a)]).sum();
                }
            }
        }
        out
    }

    /// `R M` for `M` with `n` rows (`n × cols`).
    pub(crate) fn left_of(&self, m: &DMatrix<f64>, modes: &[Mode]) -> DMatrix<C64> {
        let mut out = DMatrix::<C64>::zeros(m.nrows(), m.ncols());
        for ((i0, r), md) in self.blocks.iter().zip(modes) {
            let s = md.size();
            for col in 0..m.ncols() {
                for i in 0..s {
                    out[(i0 + i, col)] = (0..s).map(|a| r[i][a] * m[(i0 + a, col)]).sum();
                }
            }
        }
        out
    }
}

fn c64(x: f64) -> C64 {
    Complex::new(x, 0.0)
}

impl ModalSs {
    /// States `n`.
    pub fn order(&self) -> usize {
        self.modes.iter().map(Mode::size).sum()
    }

    /// Largest pole magnitude (stable below 1).
    pub fn radius(&self) -> f64 {
        self.modes.iter().map(Mode::radius).fold(0.0, f64::max)
    }

    /// Checks the sizes and that every value is finite.
    pub fn validate(&self) -> Result<(), MimoError> {
        let n = self.order();
        if self.b.nrows() != n
            || self.c.ncols() != n
            || self.d.nrows() != self.c.nrows()
            || self.d.ncols() != self.b.ncols()
        {
            return Err(MimoError::Shape(format!(
                "A of order {n}, B {}×{}, C {}×{}, D {}×{}",
                self.b.nrows(),
                self.b.ncols(),
                self.c.nrows(),
                self.c.ncols(),
                self.d.nrows(),
                self.d.ncols()
            )));
        }
        let modes_ok = self.modes.iter().all(|m| match *m {
            Mode::Real(l) => l.is_finite(),
            Mode::Pair { sigma, omega } => sigma.is_finite() && omega.is_finite(),
        });
        if !modes_ok {
            return Err(MimoError::Parameter("A"));
        }
        for (m, name) in [(&self.b, "B"), (&self.c, "C"), (&self.d, "D")] {
            if m.iter().any(|v| !v.is_finite()) {
                return Err(MimoError::Parameter(name));
            }
        }
        Ok(())
    }

    /// `G(z) = C (zI − A)⁻¹ B + D`.
    pub fn frf(&self, z: C64) -> DMatrix<C64> {
        let r = Resolvent::new(&self.modes, z);
        let rb = r.left_of(&self.b, &self.modes);
        self.c.map(c64) * rb + self.d.map(c64)
    }

    /// `B`, `D` by least squares against `g` on `z` for the present modes and `C`.
    pub fn fit_bd(&mut self, z: &[C64], g: &[DMatrix<C64>]) -> Result<(), MimoError> {
        let (n, p) = (self.order(), self.c.nrows());
        let m = g.first().map_or(0, |x| x.ncols());
        let np = n + p;
        let parts: (DMatrix<f64>, DMatrix<f64>) = z
            .par_iter()
            .zip(g)
            .fold(
                || (DMatrix::zeros(np, np), DMatrix::zeros(np, m)),
                |(mut nn, mut rhs), (&zk, gk)| {
                    let r = Resolvent::new(&self.modes, zk);
                    let cr = r.right_of(&self.c, &self.modes);
                    let mut phi = DMatrix::<C64>::zeros(p, np);
                    phi.columns_mut(0, n).copy_from(&cr);
                    for o in 0..p {
                        phi[(o, n + o)] = c64(1.0);
                    }
                    let ph = phi.adjoint();
                    nn += (&ph * &phi).map(|v| v.re);
                    rhs += (&ph * gk).map(|v| v.re);
                    (nn, rhs)
                },
            )
            .reduce(|| (DMatrix::zeros(np, np), DMatrix::zeros(np, m)), |a, b| (a.0 + b.0, a.1 + b.1));
        let (nn, rhs) = parts;
        let sol = solve_spd(nn, &rhs).ok_or(MimoError::Numerical("B, D least squares"))?;
        self.b = sol.rows(0, n).into_owned();
        self.d = sol.rows(n, p).into_owned();
        Ok(())
    }
}

/// Solves `N X = R` for symmetric positive semidefinite `N`, with a small ridge when needed.
pub(crate) fn solve_spd(mut nn: DMatrix<f64>, rhs: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let scale = (0..nn.nrows()).map(|i| nn[(i, i)]).fold(0.0, f64::max).max(1e-300);
    for ridge in [1e-12, 1e-9, 1e-6] {
        let mut a = nn.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += ridge * scale;
        }
        if let Some(ch) = a.cholesky() {
            let x = ch.solve(rhs);
            if x.iter().all(|v| v.is_finite()) {
                return Some(x);
            }
        }
    }
    for i in 0..nn.nrows() {
        nn[(i, i)] += 1e-6 * scale;
    }
    nn.lu().solve(rhs)
}

/// Subspace identification of a model of order `n` from `g` on the lines `z` (module docs),
/// with `q` block rows (`q·p > n`; `None`: `max(n + 4, 40)`).
pub fn fsid(z: &[C64], g: &[DMatrix<C64>], n: usize, q: Option<usize>) -> Result<ModalSs, MimoError> {
    let first = g.first().ok_or_else(|| MimoError::Data("no lines for subspace identification".into()))?;
    let (p, m) = (first.nrows(), first.ncols());
    let q = q.unwrap_or((n + 4).max(40));
    if n == 0 || q * p <= n || z.len() != g.len() || z.len() * m * 2 < q * (m + p) {
        return Err(MimoError::Data(format!("order {n} with {q} block rows from {} lines", z.len())));
    }
    // Realified [U; Y], rows (qm + qp), columns 2·K·m.
    let (rows, cols) = (q * (m + p), 2 * z.len() * m);
    let mut mat = DMatrix::<f64>::zeros(rows, cols);
    for (k, (&zk, gk)) in z.iter().zip(g).enumerate() {
        let mut zi = c64(1.0);
        for i in 0..q {
            for j in 0..m {
                let (cr, ci) = (k * m + j, z.len() * m + k * m + j);
                mat[(i * m + j, cr)] = zi.re;
                mat[(i * m + j, ci)] = zi.im;
                for o in 0..p {
                    let v = zi * gk[(o, j)];
                    mat[(q * m + i * p + o, cr)] = v.re;
                    mat[(q * m + i * p + o, ci)] = v.im;
                }
            }
            zi *= zk;
        }
    }
    let h = &mat * mat.transpose();
    let (qm, qp) = (q * m, q * p);
    let huu = h.view((0, 0), (qm, qm)).into_owned();
    let huy = h.view((0, qm), (qm, qp)).into_owned();
    let hyy = h.view((qm, qm), (qp, qp)).into_owned();
    let x = solve_spd(huu, &huy).ok_or(MimoError::Numerical("subspace identification (H_uu)"))?;
    let mut proj = hyy - huy.transpose() * x;
    proj = (&proj + proj.transpose()) * 0.5;
    let eig = proj.symmetric_eigen();
    let mut order: Vec<usize> = (0..qp).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let o = DMatrix::from_fn(qp, n, |r, c| eig.eigenvectors[(r, order[c])]);
    let c = o.rows(0, p).into_owned();
    let o1 = o.rows(0, qp - p).into_owned();
    let o2 = o.rows(p, qp - p).into_owned();
    let a = o1
        .svd(true, true)
        .solve(&o2, 1e-12)
        .map_err(|_| MimoError::Numerical("subspace identification (A)"))?;
    let (modes, t) = modal_form(&a)?;
    let c = c * t;
    let mut ss = ModalSs { modes, b: DMatrix::zeros(n, m), c, d: DMatrix::zeros(p, m) };
    ss.fit_bd(z, g)?;
    balance(&mut ss);
    ss.validate()?;
    Ok(ss)
}

/// Scales each mode's states so that its rows of `B` and columns of `C` have equal norms
/// (the transfer function is unchanged; it conditions the refinement).
pub fn balance(ss: &mut ModalSs) {
    let mut at = 0;
    for md in &ss.modes {
        let s = md.size();
        let nb: f64 = (0..s).map(|i| ss.b.row(at + i).norm_squared()).sum::<f64>().sqrt();
        let nc: f64 = (0..s).map(|i| ss.c.column(at + i).norm_squared()).sum::<f64>().sqrt();
        if nb > 0.0 && nc > 0.0 && nb.is_finite() && nc.is_finite() {
            let f = (nc / nb).sqrt();
            for i in 0..s {
                ss.b.row_mut(at + i).scale_mut(f);
                ss.c.column_mut(at + i).scale_mut(1.0 / f);
            }
        }
        at += s;
    }
}

/// The real modal form of `a`: its modes (unstable poles reflected into the unit circle,
/// `λ → 0.999/λ̄` when `|λ| ≥ 1`) and `T` with `A T = T A_modal` for the original poles.
fn modal_form(a: &DMatrix<f64>) -> Result<(Vec<Mode>, DMatrix<f64>), MimoError> {
    let n = a.nrows();
    let schur =
        nalgebra::Schur::try_new(a.clone(), 1e-14, 10_000).ok_or(MimoError::Numerical("eigenvalues of A"))?;
    let mut eig: Vec<C64> = schur.complex_eigenvalues().iter().copied().collect();
    eig.sort_by(|x, y| x.im.abs().total_cmp(&y.im.abs()).then(x.re.total_cmp(&y.re)));
    let ac = a.map(c64);
    let mut modes = Vec::new();
    let mut t = DMatrix::<f64>::zeros(n, n);
    let mut col = 0;
    let mut used = vec![false; eig.len()];
    for i in 0..eig.len() {
        if used[i] || col >= n {
            continue;
        }
        let l = eig[i];
        used[i] = true;
        let is_pair = l.im.abs() > 1e-9 * l.norm().max(1e-300);
        if is_pair {
            // Mark its conjugate.
            if let Some(j) =
                (0..eig.len()).find(|&j| !used[j] && (eig[j] - l.conj()).norm() < 1e-6 * l.norm().max(1e-12))
            {
                used[j] = true;
            }
            if col + 2 > n {
                continue;
            }
        }
        let lp = if is_pair { Complex::new(l.re, l.im.abs()) } else { c64(l.re) };
        let v = eigenvector(&ac, lp)?;
        if is_pair {
            for r in 0..n {
                t[(r, col)] = v[r].re;
                t[(r, col + 1)] = v[r].im;
            }
            let l2 = reflect(lp);
            modes.push(Mode::Pair { sigma: l2.re, omega: l2.im });
            col += 2;
        } else {
            for r in 0..n {
                t[(r, col)] = v[r].re;
            }
            modes.push(Mode::Real(reflect(lp).re));
            col += 1;
        }
    }
    if col != n {
        return Err(MimoError::Numerical("modal form (eigenvalue pairing)"));
    }
    Ok((modes, t))
}

fn reflect(l: C64) -> C64 {
    let r = l.norm();
    if r >= 0.999 { l / (r * r) * 0.999f64.min(r * r) } else { l }
}

/// An eigenvector of `a` for the eigenvalue `l`, by inverse iteration.
fn eigenvector(a: &DMatrix<C64>, l: C64) -> Result<DVector<C64>, MimoError> {
    let n = a.nrows();
    let shift = l + Complex::new(1e-10 * l.norm().max(1e-3), 1e-10 * l.norm().max(1e-3));
    let lu = (a - DMatrix::<C64>::identity(n, n) * shift).lu();
    let mut v = DVector::from_fn(n, |i, _| Complex::new(1.0 + 0.1 * i as f64, 0.3 - 0.05 * i as f64));
    for _ in 0..3 {
        let w = lu.solve(&v).ok_or(MimoError::Numerical("eigenvector of A"))?;
        let norm = w.norm();
        if !(norm.is_finite() && norm > 0.0) {
            return Err(MimoError::Numerical("eigenvector of A"));
        }
        v = w / c64(norm);
    }
    // Rotate so that the largest component is real (a tidy real basis for a pair).
    let big = v.iter().copied().max_by(|x, y| x.norm().total_cmp(&y.norm())).unwrap_or(c64(1.0));
    let rot = big.conj() / c64(big.norm().max(1e-300));
    Ok(v * rot)
}

/// The output-error data: per excited line `z`, `Ĝ` and the Cholesky factor `L` of `S`.
#[derive(Clone, Debug)]
pub struct OeData {
    /// Line points `z_k`.
    pub z: Vec<C64>,
    /// `Ĝ(k)`, `p × m`.
    pub g: Vec<DMatrix<C64>>,
    /// `L(k)`, `m × m` lower triangular, `L Lᴴ = Σ_r U_r U_rᴴ`.
    pub l: Vec<DMatrix<C64>>,
    /// `Σ_r |Y_r|²` minus `‖Ĝ L‖²` summed over lines: the cost no linear model removes.
    pub floor: f64,
    /// Realisations summed (over levels).
    pub realisations: usize,
    /// Samples per period `N`.
    pub samples: usize,
}

impl OeData {
    /// From the excited lines of the levels `levels` of `s`.
    pub fn new(s: &Spectra, levels: &[usize]) -> Result<Self, MimoError> {
        Self::weighted(s, levels, &vec![1.0; levels.len()])
    }

    /// As [`Self::new`], with level `levels[i]`'s squared errors weighted by `weights[i]`
    /// (`Σ_r` becomes `Σ_levels w Σ_r`).
    pub fn weighted(s: &Spectra, levels: &[usize], weights: &[f64]) -> Result<Self, MimoError> {
        if weights.len() != levels.len() || weights.iter().any(|w| !(w.is_finite() && *w > 0.0)) {
            return Err(MimoError::Parameter("level weights"));
        }
        let (m, p) = (s.inputs, s.outputs);
        let mut out =
            OeData { z: vec![], g: vec![], l: vec![], floor: 0.0, realisations: 0, samples: s.samples };
        for &li in levels {
            out.realisations += s.levels.get(li).map_or(0, |l| l.u.len());
        }
        for k in (0..s.lines()).filter(|&k| s.excited[k]) {
            let mut ss = DMatrix::<C64>::zeros(m, m);
            let mut ty = DMatrix::<C64>::zeros(p, m);
            let mut yy = 0.0;
            for (&li, &w) in levels.iter().zip(weights) {
                let l = s.levels.get(li).ok_or_else(|| MimoError::Data(format!("no level {li}")))?;
                for r in 0..l.u.len() {
                    let u = DVector::from_fn(m, |c, _| l.u[r][k * m + c]);
                    let y = DVector::from_fn(p, |o, _| l.y[r][k * p + o]);
                    ss += &u * u.adjoint() * c64(w);
                    ty += &y * u.adjoint() * c64(w);
                    yy += w * y.norm_squared();
                }
            }
            let Some(ch) = ss.clone().cholesky() else { continue };
            let Some(si) = ss.try_inverse() else { continue };
            let g = ty * si;
            let lo = ch.l();
            out.floor += yy - (&g * &lo).norm_squared();
            out.z.push(s.z(k));
            out.g.push(g);
            out.l.push(lo);
        }
        if out.z.is_empty() {
            return Err(MimoError::Data("no line where the inputs span every direction".into()));
        }
        Ok(out)
    }

    /// The cost `Σ_k ‖(G(z_k) − Ĝ_k) L_k‖²` of a model.
    pub fn cost(&self, ss: &ModalSs) -> f64 {
        self.z
            .par_iter()
            .zip(&self.g)
            .zip(&self.l)
            .map(|((&z, g), l)| ((ss.frf(z) - g) * l).norm_squared())
            .sum()
    }

    /// The RMS over a period (µm) of the simulation error the cost stands for: by Parseval,
    /// `√((2/N²)(cost + floor)/R)`.
    pub fn rms(&self, cost: f64) -> f64 {
        let n = self.samples as f64;
        (2.0 / (n * n) * (cost + self.floor).max(0.0)
            / self.realisations.max(1) as f64
            / self.g[0].nrows() as f64)
            .sqrt()
    }
}

/// How the refinement went.
#[derive(Clone, Debug, PartialEq)]
pub struct OeReport {
    /// Cost before and after.
    pub cost: (f64, f64),
    /// Iterations (Jacobians) done.
    pub iterations: usize,
}

fn pack(ss: &ModalSs) -> Vec<f64> {
    let mut th = Vec::new();
    for md in &ss.modes {
        match *md {
            Mode::Real(l) => th.push(l),
            Mode::Pair { sigma, omega } => {
                th.push(sigma);
                th.push(omega);
            }
        }
    }
    th.extend(ss.b.transpose().iter()); // B row-major
    th.extend(ss.c.transpose().iter()); // C row-major
    th.extend(ss.d.transpose().iter());
    th
}

fn unpack(template: &ModalSs, th: &[f64]) -> ModalSs {
    let (n, m, p) = (template.order(), template.b.ncols(), template.c.nrows());
    let mut i = 0;
    let modes = template
        .modes
        .iter()
        .map(|md| match md {
            Mode::Real(_) => {
                i += 1;
                Mode::Real(th[i - 1])
            }
            Mode::Pair { .. } => {
                i += 2;
                Mode::Pair { sigma: th[i - 2], omega: th[i - 1] }
            }
        })
        .collect();
    let b = DMatrix::from_row_slice(n, m, &th[i..i + n * m]);
    i += n * m;
    let c = DMatrix::from_row_slice(p, n, &th[i..i + p * n]);
    i += p * n;
    let d = DMatrix::from_row_slice(p, m, &th[i..i + p * m]);
    ModalSs { modes, b, c, d }
}

/// `JᵀJ` and `Jᵀr` of the residuals `(G − Ĝ)L` (realified) on lines `range`.
fn normal_equations(
    ss: &ModalSs,
    data: &OeData,
    range: std::ops::Range<usize>,
    np: usize,
) -> (DMatrix<f64>, DVector<f64>) {
    let (n, m, p) = (ss.order(), ss.b.ncols(), ss.c.nrows());
    let rows_per = 2 * p * m;
    let mut jac = DMatrix::<f64>::zeros(rows_per * range.len(), np);
    let mut res = DVector::<f64>::zeros(rows_per * range.len());
    for (row_line, k) in range.enumerate() {
        let (z, lk) = (data.z[k], &data.l[k]);
        let r = Resolvent::new(&ss.modes, z);
        let cr = r.right_of(&ss.c, &ss.modes);
        let rb = r.left_of(&ss.b, &ss.modes);
        let rbl = &rb * lk;
        let g = ss.c.map(c64) * &rb + ss.d.map(c64);
        let resid = (g - &data.g[k]) * lk;
        let base = row_line * rows_per;
        // Residual layout: entry (o, j) -> rows base + 2(o·m + j) (re), +1 (im).
        let put = |jac: &mut DMatrix<f64>, col: usize, o: usize, j: usize, v: C64| {
            let r0 = base + 2 * (o * m + j);
            jac[(r0, col)] = v.re;
            jac[(r0 + 1, col)] = v.im;
        };
        for o in 0..p {
            for j in 0..m {
                let r0 = base + 2 * (o * m + j);
                res[r0] = resid[(o, j)].re;
                res[r0 + 1] = resid[(o, j)].im;
            }
        }
        let mut col = 0;
        for (bi, md) in ss.modes.iter().enumerate() {
            let i0 = r.blocks[bi].0;
            match md {
                Mode::Real(_) => {
                    for o in 0..p {
                        for j in 0..m {
                            put(&mut jac, col, o, j, cr[(o, i0)] * rbl[(i0, j)]);
                        }
                    }
                    col += 1;
                }
                Mode::Pair { .. } => {
                    // dσ: CR_b · (R_b B_b L); dω: CR_b · J · (R_b B_b L).
                    for o in 0..p {
                        for j in 0..m {
                            let (a0, a1) = (cr[(o, i0)], cr[(o, i0 + 1)]);
                            let (x0, x1) = (rbl[(i0, j)], rbl[(i0 + 1, j)]);
                            put(&mut jac, col, o, j, a0 * x0 + a1 * x1);
                            // J·x = (x1, −x0)
                            put(&mut jac, col + 1, o, j, a0 * x1 - a1 * x0);
                        }
                    }
                    col += 2;
                }
            }
        }
        // B[i, j]: dr = CR[:, i] ⊗ L[j, :].
        for i in 0..n {
            for j in 0..m {
                for o in 0..p {
                    for jj in 0..m {
                        put(&mut jac, col, o, jj, cr[(o, i)] * lk[(j, jj)]);
                    }
                }
                col += 1;
            }
        }
        // C[o, i]: row o = RBL[i, :].
        for o in 0..p {
            for i in 0..n {
                for jj in 0..m {
                    put(&mut jac, col, o, jj, rbl[(i, jj)]);
                }
                col += 1;
            }
        }
        // D[o, j]: row o = L[j, :].
        for o in 0..p {
            for j in 0..m {
                for jj in 0..m {
                    put(&mut jac, col, o, jj, lk[(j, jj)]);
                }
                col += 1;
            }
        }
    }
    // `transpose() *` goes through the blocked product (matrixmultiply); `tr_mul` is a
    // product of columns, several times slower at these sizes.
    let jt = jac.transpose();
    (&jt * &jac, &jt * &res)
}

/// Refines `ss` by Levenberg–Marquardt on the output-error cost of `data` (module docs), at
/// most `iterations` Jacobians; `progress(iteration, cost)` after each.
pub fn refine_oe(
    ss: &ModalSs,
    data: &OeData,
    iterations: usize,
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<(ModalSs, OeReport), MimoError> {
    ss.validate()?;
    let mut th = pack(ss);
    let np = th.len();
    let mut best = ss.clone();
    let cost0 = data.cost(ss);
    let mut cost = cost0;
    let mut mu = 1e-3;
    let mut done = 0;
    const CHUNK: usize = 64;
    for it in 0..iterations {
        let chunks: Vec<std::ops::Range<usize>> =
            (0..data.z.len()).step_by(CHUNK).map(|a| a..(a + CHUNK).min(data.z.len())).collect();
        let (jtj, jtr) = chunks
            .into_par_iter()
            .map(|r| normal_equations(&best, data, r, np))
            .reduce(|| (DMatrix::zeros(np, np), DVector::zeros(np)), |a, b| (a.0 + b.0, a.1 + b.1));
        done = it + 1;
        let mut improved = false;
        while mu < 1e8 {
            let mut a = jtj.clone();
            for i in 0..np {
                a[(i, i)] += mu * jtj[(i, i)].max(1e-12 * (1.0 + jtj[(i, i)]));
            }
            let Some(step) = a.cholesky().map(|ch| ch.solve(&(-&jtr))) else {
                mu *= 10.0;
                continue;
            };
            let trial: Vec<f64> = th.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
            let cand = unpack(&best, &trial);
            if cand.radius() < 0.9999 && cand.validate().is_ok() {
                let c = data.cost(&cand);
                if c < cost {
                    let rel = (cost - c) / cost;
                    th = trial;
                    best = cand;
                    cost = c;
                    mu = (mu / 3.0).max(1e-9);
                    improved = rel > 1e-7;
                    break;
                }
            }
            mu *= 4.0;
        }
        progress(done, cost);
        if !improved {
            break;
        }
    }
    balance(&mut best);
    Ok((best, OeReport { cost: (cost0, cost), iterations: done }))
}
