//! The `Sampler` class: a DP-GP Gibbs sampler owned by Python, run on a rayon pool (one per
//! thread count, shared by every sampler of the process) with
//! the GIL released, and stoppable with Ctrl-C between frames.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::Duration;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{pairs, to_numpy};
use crate::errors::{CoreError, CoreResult};
use crate::settings::SamplerSettings;
use dpgp_core::Error;
use dpgp_core::gibbs::{Data, Sampler};
use dpgp_core::kernel::LengthScales;
use dpgp_core::pattern::FrameRef;

#[pyclass(module = "dpgp._core", name = "Sampler")]
pub struct PySampler {
    inner: Mutex<Sampler>,
    pool: Arc<rayon::ThreadPool>,
}

pub(crate) fn offsets_vec(name: &str, o: &PyReadonlyArray1<'_, i64>) -> CoreResult<Vec<usize>> {
    o.as_array()
        .iter()
        .map(|&x| {
            usize::try_from(x)
                .map_err(|_| CoreError(Error::Shape(format!("{name} must be non-negative"))))
        })
        .collect()
}

/// Frames as views into flat arrays.
pub(crate) fn frame_refs<'a>(
    xy: &'a [[f64; 2]],
    v: &'a [[f64; 2]],
    offsets: &[usize],
) -> CoreResult<Vec<FrameRef<'a>>> {
    if xy.len() != v.len() || offsets.first() != Some(&0) || offsets.last() != Some(&xy.len()) {
        return Err(CoreError(Error::Shape(
            "offsets must run from 0 to the number of rows of xy and v".into(),
        )));
    }
    if offsets.windows(2).any(|w| w[1] <= w[0]) {
        return Err(CoreError(Error::Shape(
            "every frame must hold at least one vehicle".into(),
        )));
    }
    Ok(offsets
        .windows(2)
        .map(|w| FrameRef {
            xy: &xy[w[0]..w[1]],
            v: &v[w[0]..w[1]],
        })
        .collect())
}

/// The process's rayon pool of `n` threads (0: one per core), created on first use: samplers
/// share pools, so that many live models do not each hold their own threads. `n` is checked
/// against the core's limit (`gibbs::check_threads`) with the other settings.
fn shared_pool(n: usize) -> PyResult<Arc<rayon::ThreadPool>> {
    static POOLS: Mutex<Vec<(usize, Arc<rayon::ThreadPool>)>> = Mutex::new(Vec::new());
    let mut pools = POOLS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, p)) = pools.iter().find(|(k, _)| *k == n) {
        return Ok(Arc::clone(p));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| {
            pyo3::exceptions::PyRuntimeError::new_err(format!("could not start threads: {e}"))
        })?;
    let pool = Arc::new(pool);
    pools.push((n, Arc::clone(&pool)));
    Ok(pool)
}

impl PySampler {
    fn lock(&self) -> std::sync::MutexGuard<'_, Sampler> {
        // A panic inside a sweep cannot leave the state half-written in a way we could repair,
        // but the data stays memory-safe; keep serving it.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Run `work` on the pool with the GIL released, polling Ctrl-C on this (the main) thread.
    pub(crate) fn run<T: Send>(
        &self,
        py: Python<'_>,
        work: impl FnOnce(&mut Sampler, &dyn Fn() -> bool) -> dpgp_core::Result<T> + Send,
    ) -> PyResult<T> {
        let stop = AtomicBool::new(false);
        let mut interrupt: Option<PyErr> = None;
        let result = py.detach(|| {
            std::thread::scope(|s| {
                let (tx, rx) = mpsc::channel();
                let stop_ref = &stop;
                let handle = s.spawn(move || {
                    let mut guard = self.lock();
                    let sampler: &mut Sampler = &mut guard;
                    let r = self
                        .pool
                        .install(|| work(sampler, &|| stop_ref.load(Ordering::Relaxed)));
                    let _ = tx.send(());
                    r
                });
                while rx.recv_timeout(Duration::from_millis(50)).is_err() {
                    if handle.is_finished() {
                        break;
                    }
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        stop.store(true, Ordering::Relaxed);
                        interrupt.get_or_insert(e);
                    }
                }
                handle.join()
            })
        });
        match result {
            Ok(Ok(v)) => {
                if interrupt.is_some() {
                    // Ctrl-C came after the last check point (e.g. during the length-scale step):
                    // the work is done and kept; re-arm the interrupt so Python raises it next.
                    // SAFETY: PyErr_SetInterrupt only sets CPython's pending-signal flag.
                    unsafe { pyo3::ffi::PyErr_SetInterrupt() };
                }
                Ok(v)
            }
            Ok(Err(Error::Interrupted)) => {
                Err(interrupt.unwrap_or_else(|| CoreError(Error::Interrupted).into()))
            }
            Ok(Err(e)) => Err(CoreError(e).into()),
            Err(_) => Err(pyo3::exceptions::PyRuntimeError::new_err(
                "internal error: the sampler thread panicked",
            )),
        }
    }
}

#[pymethods]
impl PySampler {
    /// A sampler over frames `xy`, `v` (rows of all frames, `offsets` where each starts) with
    /// `settings`, a dict (settings.rs: `SamplerSettings`) that the core validates.
    #[new]
    fn new(
        py: Python<'_>,
        xy: PyReadonlyArray2<'_, f64>,
        v: PyReadonlyArray2<'_, f64>,
        offsets: PyReadonlyArray1<'_, i64>,
        settings: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let (settings, n_threads) = SamplerSettings::extract(settings)?.into_core(false)?;
        let (xy, v) = (pairs("xy", &xy)?, pairs("v", &v)?);
        let offsets = offsets_vec("offsets", &offsets)?;
        let data = Data::new(xy.to_vec(), v.to_vec(), offsets).map_err(CoreError)?;
        let sampler = py
            .detach(|| Sampler::new(data, settings))
            .map_err(CoreError)?;
        let pool = shared_pool(n_threads)?;
        Ok(Self {
            inner: Mutex::new(sampler),
            pool,
        })
    }

    /// ρ of the sticky prior (`None` without it).
    fn stickiness(&self) -> Option<f64> {
        self.lock().stickiness()
    }

    /// Each frame's link under the sticky prior (`True`: it stays in its predecessor's
    /// pattern), or `None` without it.
    fn links<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<bool>>> {
        self.lock().links().map(|l| l.to_vec().into_pyarray(py))
    }

    /// Set the links and ρ (a resumed chain); links the labels do not allow are dropped.
    fn set_links(&self, links: PyReadonlyArray1<'_, bool>, rho: f64) -> PyResult<()> {
        let links: Vec<bool> = links.as_array().to_vec();
        self.lock()
            .set_links(&links, rho)
            .map_err(|e| CoreError(e).into())
    }

    /// Place every unassigned frame by the sequential CRP conditional.
    fn initialize(&self, py: Python<'_>) -> PyResult<()> {
        self.run(py, |s, stop| s.initialize(stop))
    }

    /// One sweep; returns (moves, K, alpha, log_joint).
    fn sweep(&self, py: Python<'_>) -> PyResult<(usize, usize, f64, f64)> {
        self.run(py, |s, stop| {
            s.sweep(stop)
                .map(|r| (r.moves, r.n_patterns, r.alpha, r.log_joint))
        })
    }

    /// The arena slot of each frame's pattern.
    fn labels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<usize>> {
        self.lock().labels().to_vec().into_pyarray(py)
    }

    /// (slot, stable id, n_frames, w_x, w_y) for each pattern, in slot order.
    fn patterns(&self) -> Vec<(usize, u64, usize, f64, f64)> {
        self.lock()
            .patterns()
            .into_iter()
            .map(|p| {
                (
                    p.slot,
                    p.id,
                    p.n_frames,
                    p.length_scales.wx,
                    p.length_scales.wy,
                )
            })
            .collect()
    }

    fn alpha(&self) -> f64 {
        self.lock().alpha()
    }

    /// Sweeps done so far: with the seed, the position of the random stream.
    fn sweeps_done(&self) -> u64 {
        self.lock().sweeps_done()
    }

    /// Continue as if `sweeps` sweeps had been done (a resumed chain).
    fn set_sweeps_done(&self, sweeps: u64) {
        self.lock().set_sweeps_done(sweeps)
    }

    fn log_joint(&self) -> f64 {
        self.lock().log_joint()
    }

    /// Bytes held by the patterns and the score cache.
    fn memory_bytes(&self) -> usize {
        self.lock().memory_bytes()
    }

    /// (proposed, accepted) counts of informed proposals so far.
    fn proposal_counts(&self) -> (u64, u64) {
        let p = self.lock().proposals;
        (p.proposed, p.accepted)
    }

    /// (split proposed, split accepted, merge proposed, merge accepted) so far.
    fn split_merge_counts(&self) -> (u64, u64, u64, u64) {
        let s = self.lock().split_merge;
        (
            s.split_proposed,
            s.split_accepted,
            s.merge_proposed,
            s.merge_accepted,
        )
    }

    /// The noise pair the chain is at.
    fn noise_var(&self) -> (f64, f64) {
        let n = self.lock().noise_var();
        (n[0], n[1])
    }

    /// Each pattern's noise pair, in slot order (the chain's pair unless the noise is per
    /// pattern).
    fn pattern_noise(&self) -> Vec<(f64, f64)> {
        self.lock()
            .patterns()
            .into_iter()
            .map(|p| (p.noise_var[0], p.noise_var[1]))
            .collect()
    }

    /// Put the chain at a noise pair (a resumed chain).
    fn set_noise_var(&self, py: Python<'_>, noise_var: (f64, f64)) -> PyResult<()> {
        self.run(py, |s, _| s.set_noise_var([noise_var.0, noise_var.1]))
    }

    /// Seconds spent per part of the sweep so far.
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.lock().timings;
        let d = PyDict::new(py);
        d.set_item("refresh", t.refresh)?;
        d.set_item("scoring", t.scoring)?;
        d.set_item("moves", t.moves)?;
        d.set_item("new_pattern", t.new_pattern)?;
        d.set_item("length_scales", t.length_scales)?;
        d.set_item("alpha", t.alpha)?;
        d.set_item("split_merge", t.split_merge)?;
        d.set_item("noise", t.noise)?;
        Ok(d)
    }

    /// Normalised conditional log-probabilities of training frame `i` (patterns in slot order, then new).
    fn conditional_log_probs(&self, py: Python<'_>, i: usize) -> PyResult<Vec<f64>> {
        self.run(py, |s, _| s.conditional_log_probs(i))
    }

    /// log p(V_i | D_k) of every training frame under every pattern (slot order), its own
    /// pattern's without it (`-inf` if alone in it): one row per frame.
    fn training_log_likelihoods(&self, py: Python<'_>) -> PyResult<Vec<Vec<f64>>> {
        self.run(py, |s, _| s.training_log_likelihoods())
    }

    /// For new frames: (log p(V_f | D_k) per frame and pattern in slot order, new-pattern term).
    #[allow(clippy::type_complexity)]
    fn score_frames<'py>(
        &self,
        py: Python<'py>,
        xy: PyReadonlyArray2<'py, f64>,
        v: PyReadonlyArray2<'py, f64>,
        offsets: PyReadonlyArray1<'py, i64>,
    ) -> PyResult<(Vec<Vec<f64>>, Vec<f64>)> {
        let (xy, v) = (pairs("xy", &xy)?, pairs("v", &v)?);
        let offsets = offsets_vec("offsets", &offsets)?;
        let frames = frame_refs(xy, v, &offsets)?;
        self.run(py, |s, _| s.score_frames(&frames))
    }

    /// Posterior mean and variance of pattern `slot`'s velocity field at `query_xy`.
    #[allow(clippy::type_complexity)]
    fn posterior<'py>(
        &self,
        py: Python<'py>,
        slot: usize,
        query_xy: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
        let q = pairs("query_xy", &query_xy)?;
        let (mean, var) = self.run(py, |s, _| {
            let p = pattern_at(s, slot)?;
            dpgp_core::error::check_finite("query_xy", q.as_flattened())?;
            Ok(p.posterior(q))
        })?;
        Ok((to_numpy(py, mean), to_numpy(py, var)))
    }

    /// Set the state: a group number per frame, the length scales of each group, and alpha;
    /// `noise_var`: each group's noise pair (per-pattern noise), `None` for the chain's pair.
    #[pyo3(signature = (labels, length_scales, alpha, noise_var=None))]
    fn set_state(
        &self,
        py: Python<'_>,
        labels: PyReadonlyArray1<'_, i64>,
        length_scales: PyReadonlyArray2<'_, f64>,
        alpha: f64,
        noise_var: Option<PyReadonlyArray2<'_, f64>>,
    ) -> PyResult<()> {
        let labels = offsets_vec("labels", &labels)?;
        let ls: Vec<LengthScales> = pairs("length_scales", &length_scales)?
            .iter()
            .map(|w| LengthScales::new(w[0], w[1]))
            .collect::<dpgp_core::Result<_>>()
            .map_err(CoreError)?;
        let noise: Option<Vec<[f64; 2]>> = match &noise_var {
            Some(n) => Some(pairs("noise_var", n)?.to_vec()),
            None => None,
        };
        self.run(py, |s, _| {
            s.set_state_with_noise(&labels, &ls, noise.as_deref(), alpha)
        })
    }
}

/// The pattern in `slot`, or an error that says so.
pub(crate) fn pattern_at(
    s: &Sampler,
    slot: usize,
) -> dpgp_core::Result<&dyn dpgp_core::pattern_model::PatternModel> {
    s.pattern(slot)
        .ok_or_else(|| Error::InvalidInput(format!("no pattern in slot {slot}")))
}
