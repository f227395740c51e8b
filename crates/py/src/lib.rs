//! boucwen from Python: the host library ([`boucwen_lab`]) as the module `boucwen`, NumPy
//! arrays in and out.
//!
//! | Python | what | the command it matches |
//! |---|---|---|
//! | `read_record(path, columns=None, units=None, …)` | a [`Record`]: `t`, `u`, `y` arrays and how the file was read | the importer of every command |
//! | `identify(u, y, ts, model="auto", …)` | a [`Model`] | `boucwen identify --save` |
//! | `Model.simulate`, `.compare`, `.save`, `Model.load` | free run, scores, the model file | `simulate --model`, `compare` |
//! | `diagnose(u, y, ts, rules=None)` | a [`Diagnosis`]: findings with their evidence, `.to_json()` | `boucwen diagnose --json` |
//! | `design(records, …)` | a [`Design`]: the board's design file | `boucwen board design` |
//! | `sweep(…)` | the sweep's table as a dict of arrays | `boucwen sweep` (`sweep.csv`) |
//!
//! Each function calls the same library functions as the command, so the numbers are the
//! same bit for bit (crates/py/tests checks them against the binary). Every error the library
//! returns becomes `boucwen.Error` with the library's message; a panic is caught at the
//! entry point and becomes `boucwen.Error` too, never a Python `PanicException`. The long
//! calls release the GIL.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

mod convert;
mod design;
mod diagnose;
mod model;
mod record;
mod sweep;

pub use design::Design;
pub use diagnose::Diagnosis;
pub use model::Model;
pub use record::Record;

create_exception!(
    boucwen,
    Error,
    PyException,
    "An error of boucwen: the library's one-line message (the file, the line or the option at fault)."
);

/// The module `boucwen`.
#[pymodule]
#[pyo3(name = "boucwen")]
fn boucwen_py(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("Error", m.py().get_type::<Error>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Record>()?;
    m.add_class::<Model>()?;
    m.add_class::<Diagnosis>()?;
    m.add_class::<Design>()?;
    m.add_function(wrap_pyfunction!(record::read_record, m)?)?;
    m.add_function(wrap_pyfunction!(model::identify, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose::diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(design::design, m)?)?;
    m.add_function(wrap_pyfunction!(sweep::sweep, m)?)?;
    Ok(())
}
