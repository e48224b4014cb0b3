//! Shards of frames for a sub-cluster chain: `Shard`, the frames a worker serves (it answers the
//! leader's request bytes), and the link through which a leader's chain reaches shards served by
//! Python (`dpgp.distributed`: Dask workers). The protocol is the core's
//! (`dpgp_core::subcluster::shard`); here only the crossing into Python.

use std::sync::{Arc, Mutex};

use numpy::{PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyList};

use crate::errors::CoreError;
use crate::sampler::frames_data;
use dpgp_core::Error;
use dpgp_core::subcluster::shard::{Link, Reply, Request, Shard};

/// Consecutive frames of a data set (`first`: the number of the first among all frames), which
/// answer a sharded chain's requests.
#[pyclass(module = "dpgp._core", name = "Shard", frozen)]
pub struct PyShard {
    pub(crate) inner: Shard,
}

#[pymethods]
impl PyShard {
    /// `h`: each point's previous heading (radians, NaN where unknown), for fields over heading.
    #[new]
    #[pyo3(signature = (xy, v, offsets, first, h=None))]
    fn new(
        xy: PyReadonlyArray2<'_, f64>,
        v: PyReadonlyArray2<'_, f64>,
        offsets: PyReadonlyArray1<'_, i64>,
        first: usize,
        h: Option<PyReadonlyArray1<'_, f64>>,
    ) -> PyResult<Self> {
        Ok(Self {
            inner: Shard::new(Arc::new(frames_data(&xy, &v, &offsets, &h)?), first),
        })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// The reply (bytes) to a request (bytes) of a sharded chain, computed with the GIL released.
    fn handle<'py>(&self, py: Python<'py>, request: &[u8]) -> PyResult<Bound<'py, PyBytes>> {
        let reply = py
            .detach(|| {
                let req = Request::decode(request)?;
                self.inner.handle(&req).map(|r| r.encode())
            })
            .map_err(CoreError)?;
        Ok(PyBytes::new(py, &reply))
    }
}

/// Shards served through a Python callable `serve(jobs)`: `jobs` a list of `(shard, request
/// bytes)`, returning the reply bytes in the same order. A Python exception it raises is kept,
/// to be raised again once the chain has stopped.
pub(crate) struct PyLink {
    serve: Py<PyAny>,
    pub(crate) error: Mutex<Option<PyErr>>,
}

impl std::fmt::Debug for PyLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PyLink")
    }
}

impl PyLink {
    pub(crate) fn new(serve: Py<PyAny>) -> Self {
        Self {
            serve,
            error: Mutex::new(None),
        }
    }

    /// The exception the callable raised, if it did (taken).
    pub(crate) fn take_error(&self) -> Option<PyErr> {
        self.error.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

impl Link for PyLink {
    fn run(&self, jobs: Vec<(usize, Request)>) -> dpgp_core::Result<Vec<Reply>> {
        let encoded: Vec<(usize, Vec<u8>)> = jobs.iter().map(|(s, r)| (*s, r.encode())).collect();
        let n = encoded.len();
        let replies: PyResult<Vec<Vec<u8>>> = Python::attach(|py| {
            let items: Vec<(usize, Bound<'_, PyBytes>)> = encoded
                .iter()
                .map(|(s, b)| (*s, PyBytes::new(py, b)))
                .collect();
            let out = self.serve.call1(py, (PyList::new(py, items)?,))?;
            let out = out.bind(py);
            let mut replies = Vec::with_capacity(n);
            for item in out.try_iter()? {
                replies.push(item?.cast_into::<PyBytes>()?.as_bytes().to_vec());
            }
            Ok(replies)
        });
        match replies {
            Ok(r) if r.len() == n => r.iter().map(|b| Reply::decode(b)).collect(),
            Ok(r) => Err(Error::Link(format!(
                "the shards answered {} of {n} requests",
                r.len()
            ))),
            Err(e) => {
                let msg = e.to_string();
                *self.error.lock().unwrap_or_else(|e| e.into_inner()) = Some(e);
                Err(Error::Link(msg))
            }
        }
    }
}
