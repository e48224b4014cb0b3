//! Core errors -> typed Python exceptions. The classes live in `dpgp/exceptions.py` so that
//! bad-input errors can subclass both `dpgp.DpgpError` and `ValueError`.

use pyo3::exceptions::PyKeyboardInterrupt;
use pyo3::prelude::*;

pyo3::import_exception!(dpgp.exceptions, InvalidInputError);
pyo3::import_exception!(dpgp.exceptions, ShapeError);
pyo3::import_exception!(dpgp.exceptions, NotPositiveDefiniteError);
pyo3::import_exception!(dpgp.exceptions, MemoryBudgetError);
pyo3::import_exception!(dpgp.model.sharded, LabelsLost);

/// Newtype for the orphan rule: `From<dpgp_core::Error> for PyErr` cannot live here.
pub struct CoreError(pub dpgp_core::Error);

impl From<dpgp_core::Error> for CoreError {
    fn from(e: dpgp_core::Error) -> Self {
        Self(e)
    }
}

impl From<CoreError> for PyErr {
    fn from(e: CoreError) -> PyErr {
        use dpgp_core::Error as E;
        let msg = e.0.to_string();
        match e.0 {
            E::InvalidInput(_) => InvalidInputError::new_err(msg),
            E::Shape(_) => ShapeError::new_err(msg),
            E::NotPositiveDefinite { .. } => NotPositiveDefiniteError::new_err(msg),
            E::MemoryBudget { .. } => MemoryBudgetError::new_err(msg),
            E::Interrupted => PyKeyboardInterrupt::new_err(msg),
            E::Link(_) => pyo3::exceptions::PyRuntimeError::new_err(msg),
            E::LabelsLost(_) => LabelsLost::new_err(msg),
        }
    }
}

pub type CoreResult<T> = Result<T, CoreError>;
