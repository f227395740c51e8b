//! The paper's section 3 identification by recursive least squares.

use super::FitError;
use crate::model::{HostModel, ModelError, ModelSpec};
use boucwen_core::ident::{IdentConfig, Identifier};
use boucwen_core::signal::Oscillator;

/// The paper's section 3 identification: one pass of RLS with the running-sum regressors
/// over `u[..fit_end]`, `y[..fit_end]`. At most one branch (the paper's models (6)/(7),
/// branch AR order 2 on `y_n[k-1], y_n[k-2]`).
pub fn fit_paper_rls(
    u: &[f64],
    y: &[f64],
    ts: f64,
    fit_end: usize,
    spec: &ModelSpec,
) -> Result<HostModel, FitError> {
    spec.check(ts)?;
    let need = 100;
    if fit_end < need || u.len() < fit_end || y.len() < fit_end {
        return Err(FitError::TooFewSamples { have: fit_end.min(u.len()).min(y.len()), need });
    }
    let drive = Oscillator::new(spec.drive_hz, ts)?;
    let (ext, branches) = match spec.harmonics.as_slice() {
        [] => {
            let mut id = Identifier::<f64, 2, 0, 0, 7>::new(IdentConfig::paper::<2>(), drive, [])?;
            for k in 0..fit_end {
                id.update(u[k], y[k])?;
            }
            (id.extended(), vec![])
        }
        [n] => {
            let mut id = Identifier::<f64, 2, 2, 1, 11>::new(IdentConfig::paper::<2>(), drive, [*n])?;
            for k in 0..fit_end {
                id.update(u[k], y[k])?;
            }
            let e = id.enhanced();
            (e.base, e.branches.to_vec())
        }
        more => return Err(ModelError::TooManyBranches(more.len()).into()),
    };
    Ok(HostModel { ext, drive_hz: spec.drive_hz, branches, drift: vec![], delay: 0.0 })
}
