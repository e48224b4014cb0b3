//! The `Sampler` class: a DP-GP chain owned by Python — the collapsed Gibbs sampler or the
//! sub-cluster sampler (settings key `sampler`) — run on a rayon pool (one per thread count,
//! shared by every sampler of the process) with the GIL released, and stoppable with Ctrl-C.
//! What the sub-cluster chain does not compute itself (scores of frames, fields, rollouts) it
//! answers through a collapsed sampler built at its state on first use.

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
use dpgp_core::gibbs::{Data, Sampler, SamplerKind, Settings, SweepStats};
use dpgp_core::kernel::LengthScales;
use dpgp_core::pattern::FrameRef;
use dpgp_core::subcluster::shard::{Link, Shard};
use dpgp_core::subcluster::{Start, Store, SubclusterSampler};

use crate::shard::{PyLink, PyShard};

#[pyclass(module = "dpgp._core", name = "Sampler")]
pub struct PySampler {
    inner: Mutex<Engine>,
    pool: Arc<rayon::ThreadPool>,
    /// A sharded chain's link to shards served by Python, whose exceptions are raised again.
    link: Option<Arc<PyLink>>,
}

/// The chain, by sampler.
pub(crate) enum Engine {
    Collapsed(Sampler),
    /// The sub-cluster chain and, once asked for, a collapsed sampler at its state.
    Subcluster(SubclusterSampler, Option<Box<Sampler>>),
}

impl Engine {
    /// The collapsed sampler at the chain's state (built for a sub-cluster chain on first use).
    fn collapsed(&mut self) -> dpgp_core::Result<&mut Sampler> {
        match self {
            Self::Collapsed(s) => Ok(s),
            Self::Subcluster(chain, view) => {
                if view.is_none() {
                    *view = Some(Box::new(collapsed_at(chain)?));
                }
                Ok(view.as_mut().expect("built above"))
            }
        }
    }

    /// The sub-cluster chain, its collapsed view dropped (the chain is about to change).
    fn chain_mut(&mut self) -> Option<&mut SubclusterSampler> {
        match self {
            Self::Collapsed(_) => None,
            Self::Subcluster(chain, view) => {
                *view = None;
                Some(chain)
            }
        }
    }

    fn kind(&self) -> &'static str {
        match self {
            Self::Collapsed(_) => "collapsed",
            Self::Subcluster(..) => "subcluster",
        }
    }
}

/// A collapsed sampler holding the sub-cluster chain's state: its patterns (with their own
/// hyperparameters), α and sweep count.
fn collapsed_at(chain: &SubclusterSampler) -> dpgp_core::Result<Sampler> {
    let settings = Settings {
        sampler: SamplerKind::Collapsed,
        ..chain.settings().clone()
    };
    // A sharded chain's frames are gathered from its shards: what is asked of the view (scores,
    // fields, rollouts over the training frames) needs them all in one place.
    let data = match chain.data() {
        Some(d) => Arc::clone(d),
        None => {
            let store = chain.store();
            Arc::new(store.frames(&(0..store.len()).collect::<Vec<_>>())?)
        }
    };
    let mut s = Sampler::new_with_data(data, settings)?;
    let infos = chain.patterns();
    let group: std::collections::HashMap<usize, usize> =
        infos.iter().enumerate().map(|(g, p)| (p.slot, g)).collect();
    let labels: Vec<usize> = chain.gather_labels()?.iter().map(|l| group[l]).collect();
    let ls: Vec<LengthScales> = infos.iter().map(|p| p.length_scales).collect();
    let noise: Vec<[f64; 2]> = infos.iter().map(|p| p.noise_var).collect();
    s.set_state_with_noise(&labels, &ls, Some(&noise), chain.alpha())?;
    s.set_sweeps_done(chain.sweeps_done());
    Ok(s)
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

/// The core's frames from flat arrays: positions, velocities, frame offsets and, when given
/// (not empty), each point's previous heading (fields over heading).
pub(crate) fn frames_data(
    xy: &PyReadonlyArray2<'_, f64>,
    v: &PyReadonlyArray2<'_, f64>,
    offsets: &PyReadonlyArray1<'_, i64>,
    h: &Option<PyReadonlyArray1<'_, f64>>,
) -> CoreResult<Data> {
    let (xy, v) = (pairs("xy", xy)?, pairs("v", v)?);
    let h = crate::convert::headings("h", h)?;
    let data = Data::new(xy.to_vec(), v.to_vec(), offsets_vec("offsets", offsets)?)?;
    Ok(if h.is_empty() {
        data
    } else {
        data.with_headings(h.to_vec())?
    })
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
            h: &[],
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
    fn lock(&self) -> std::sync::MutexGuard<'_, Engine> {
        // A panic inside a sweep cannot leave the state half-written in a way we could repair,
        // but the data stays memory-safe; keep serving it.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Run `work` on the collapsed sampler at the chain's state (see [`Engine::collapsed`]).
    pub(crate) fn run<T: Send>(
        &self,
        py: Python<'_>,
        work: impl FnOnce(&mut Sampler, &dyn Fn() -> bool) -> dpgp_core::Result<T> + Send,
    ) -> PyResult<T> {
        self.run_engine(py, |e, stop| work(e.collapsed()?, stop))
    }

    /// Run `work` on the pool with the GIL released, polling Ctrl-C on this (the main) thread.
    pub(crate) fn run_engine<T: Send>(
        &self,
        py: Python<'_>,
        work: impl FnOnce(&mut Engine, &dyn Fn() -> bool) -> dpgp_core::Result<T> + Send,
    ) -> PyResult<T> {
        let stop = AtomicBool::new(false);
        let mut interrupt: Option<PyErr> = None;
        let result = py.detach(|| {
            // The work is spawned onto the pool from this thread (no thread of its own), which
            // meanwhile polls Ctrl-C; a panic in it is caught there and reported, not unwound.
            let (tx, rx) = mpsc::channel();
            let stop_ref = &stop;
            let interrupt_ref = &mut interrupt;
            self.pool.in_place_scope(|s| {
                s.spawn(move |_| {
                    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        let mut guard = self.lock();
                        work(&mut guard, &|| stop_ref.load(Ordering::Relaxed))
                    }));
                    let _ = tx.send(r);
                });
                loop {
                    match rx.recv_timeout(Duration::from_millis(50)) {
                        Ok(r) => return r,
                        Err(mpsc::RecvTimeoutError::Disconnected) => {
                            return Err(Box::new("the sampler's job ended without a result")
                                as Box<dyn std::any::Any + Send>);
                        }
                        Err(mpsc::RecvTimeoutError::Timeout) => {
                            if let Err(e) = Python::attach(|py| py.check_signals()) {
                                stop.store(true, Ordering::Relaxed);
                                interrupt_ref.get_or_insert(e);
                            }
                        }
                    }
                }
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
            Ok(Err(e)) => Err(self
                .link
                .as_ref()
                .and_then(|l| l.take_error())
                .unwrap_or_else(|| CoreError(e).into())),
            Err(_) => Err(pyo3::exceptions::PyRuntimeError::new_err(
                "internal error: the sampler thread panicked",
            )),
        }
    }
}

impl PySampler {
    fn sharded(
        py: Python<'_>,
        store: Store,
        settings: &Bound<'_, PyAny>,
        link: Option<Arc<PyLink>>,
    ) -> PyResult<Self> {
        let (settings, n_threads) = SamplerSettings::extract(settings)?.into_core(false)?;
        if settings.sampler != SamplerKind::Subcluster {
            return Err(CoreError(Error::InvalidInput(
                "sharded frames need sampler=\"subcluster\" (the collapsed sampler needs every frame in one process)".into(),
            ))
            .into());
        }
        // The shards keep the frames' labels: the leader holds the patterns' sums alone.
        let chain = py
            .detach(|| {
                let mut chain = SubclusterSampler::with_store(store, settings)?;
                chain.hold_labels_on_shards()?;
                Ok(chain)
            })
            .map_err(CoreError)?;
        Ok(Self {
            inner: Mutex::new(Engine::Subcluster(chain, None)),
            pool: shared_pool(n_threads)?,
            link,
        })
    }
}

#[pymethods]
impl PySampler {
    /// A sampler over frames `xy`, `v` (rows of all frames, `offsets` where each starts) with
    /// `settings`, a dict (settings.rs: `SamplerSettings`) that the core validates.
    /// `h`: each point's previous heading (radians, `NaN` where unknown), for fields over heading.
    #[new]
    #[pyo3(signature = (xy, v, offsets, settings, h=None))]
    fn new(
        py: Python<'_>,
        xy: PyReadonlyArray2<'_, f64>,
        v: PyReadonlyArray2<'_, f64>,
        offsets: PyReadonlyArray1<'_, i64>,
        settings: &Bound<'_, PyAny>,
        h: Option<PyReadonlyArray1<'_, f64>>,
    ) -> PyResult<Self> {
        let (settings, n_threads) = SamplerSettings::extract(settings)?.into_core(false)?;
        let data = Arc::new(frames_data(&xy, &v, &offsets, &h)?);
        let sampler = py
            .detach(|| match settings.sampler {
                SamplerKind::Collapsed => {
                    Sampler::new_with_data(data, settings).map(Engine::Collapsed)
                }
                SamplerKind::Subcluster => {
                    SubclusterSampler::new(data, settings).map(|c| Engine::Subcluster(c, None))
                }
            })
            .map_err(CoreError)?;
        let pool = shared_pool(n_threads)?;
        Ok(Self {
            inner: Mutex::new(sampler),
            pool,
            link: None,
        })
    }

    /// A sub-cluster chain over shards of frames served in this process, in shard order.
    #[staticmethod]
    fn over_shards(
        py: Python<'_>,
        shards: Vec<PyRef<'_, PyShard>>,
        settings: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let datas: Vec<Shard> = shards.iter().map(|s| s.inner.clone()).collect();
        let store = Store::in_process_shards(datas).map_err(CoreError)?;
        Self::sharded(py, store, settings, None)
    }

    /// A sub-cluster chain over shards of `sizes[s]` frames served through `serve(jobs)`, a
    /// callable taking `[(shard, request bytes)]` and returning the reply bytes in order.
    #[staticmethod]
    fn over_link(
        py: Python<'_>,
        sizes: Vec<usize>,
        serve: Py<PyAny>,
        settings: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let link = Arc::new(PyLink::new(serve));
        let store =
            Store::sharded(&sizes, Arc::clone(&link) as Arc<dyn Link>).map_err(CoreError)?;
        Self::sharded(py, store, settings, Some(link))
    }

    /// How many shards hold the chain's frames (1: all in this process).
    fn n_shards(&self) -> usize {
        match &*self.lock() {
            Engine::Collapsed(_) => 1,
            Engine::Subcluster(c, _) => c.store().n_shards(),
        }
    }

    /// Which sampler runs the chain: "collapsed" or "subcluster".
    fn kind(&self) -> &'static str {
        self.lock().kind()
    }

    /// ρ of the sticky prior (`None` without it).
    fn stickiness(&self) -> Option<f64> {
        match &*self.lock() {
            Engine::Collapsed(s) => s.stickiness(),
            Engine::Subcluster(..) => None,
        }
    }

    /// Each frame's link under the sticky prior (`True`: it stays in its predecessor's
    /// pattern), or `None` without it.
    fn links<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<bool>>> {
        match &*self.lock() {
            Engine::Collapsed(s) => s.links().map(|l| l.to_vec().into_pyarray(py)),
            Engine::Subcluster(..) => None,
        }
    }

    /// Set the links and ρ (a resumed chain); links the labels do not allow are dropped.
    fn set_links(&self, links: PyReadonlyArray1<'_, bool>, rho: f64) -> PyResult<()> {
        let links: Vec<bool> = links.as_array().to_vec();
        match &mut *self.lock() {
            Engine::Collapsed(s) => s.set_links(&links, rho).map_err(|e| CoreError(e).into()),
            Engine::Subcluster(..) => Err(CoreError(Error::InvalidInput(
                "the sub-cluster sampler has no sticky links".into(),
            ))
            .into()),
        }
    }

    /// Place every unassigned frame: `init` "sequential" (the sequential CRP conditional; the
    /// default), "one" (one pattern) or "many" (many patterns).
    #[pyo3(signature = (init=None))]
    fn initialize(&self, py: Python<'_>, init: Option<&str>) -> PyResult<()> {
        let start: Start = init.unwrap_or("sequential").parse().map_err(CoreError)?;
        self.run_engine(py, |e, stop| match e {
            Engine::Collapsed(s) => match start {
                Start::Sequential => s.initialize(stop),
                _ => {
                    let groups = dpgp_core::subcluster::start_groups(start, s.data().len());
                    let k = groups.iter().max().map_or(0, |g| g + 1);
                    let ls = vec![s.settings().base.length_scales; k];
                    let alpha = s.alpha();
                    s.set_state(&groups, &ls, alpha)
                }
            },
            Engine::Subcluster(..) => {
                let chain = e.chain_mut().expect("a sub-cluster chain");
                chain.initialize(start, stop)
            }
        })
    }

    /// One sweep; returns (moves, K, alpha, log_joint).
    fn sweep(&self, py: Python<'_>) -> PyResult<(usize, usize, f64, f64)> {
        self.run_engine(py, |e, stop| {
            let r: SweepStats = match e.chain_mut() {
                Some(chain) => chain.sweep(stop)?,
                None => e.collapsed()?.sweep(stop)?,
            };
            Ok((r.moves, r.n_patterns, r.alpha, r.log_joint))
        })
    }

    /// The arena slot of each frame's pattern (gathered from the shards when they hold them).
    fn labels<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<usize>>> {
        let labels = self.run_engine(py, |e, _| match e {
            Engine::Collapsed(s) => Ok(s.labels().to_vec()),
            Engine::Subcluster(c, _) => c.gather_labels(),
        })?;
        Ok(labels.into_pyarray(py))
    }

    /// Whether the shards hold the frames' labels (a sharded chain): the leader then has only
    /// the patterns' sums, and `labels()` gathers them.
    fn labels_held(&self) -> bool {
        match &*self.lock() {
            Engine::Subcluster(c, _) => c.held_chain().is_some(),
            Engine::Collapsed(_) => false,
        }
    }

    /// When the shards hold the labels: the counts of (label at the last mark, label now) as
    /// rows `(a, b, count)`, and the shards mark their labels (set with the labels, and at each
    /// call); `None` otherwise. The previous sweep's ARI without a label crossing.
    fn label_table<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<u64>>>> {
        let table = self.run_engine(py, |e, _| match e {
            Engine::Subcluster(c, _) => c.label_table(),
            Engine::Collapsed(_) => Ok(None),
        })?;
        Ok(table.map(|t| {
            let n = t.len();
            let flat: Vec<u64> = t.into_iter().flatten().collect();
            numpy::ndarray::Array2::from_shape_vec((n, 3), flat)
                .expect("three columns")
                .into_pyarray(py)
        }))
    }

    /// (slot, stable id, n_frames, w_x, w_y) for each pattern, in slot order.
    fn patterns(&self) -> Vec<(usize, u64, usize, f64, f64)> {
        self.infos()
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
        match &*self.lock() {
            Engine::Collapsed(s) => s.alpha(),
            Engine::Subcluster(c, _) => c.alpha(),
        }
    }

    /// Sweeps done so far: with the seed, the position of the random stream.
    fn sweeps_done(&self) -> u64 {
        match &*self.lock() {
            Engine::Collapsed(s) => s.sweeps_done(),
            Engine::Subcluster(c, _) => c.sweeps_done(),
        }
    }

    /// Continue as if `sweeps` sweeps had been done (a resumed chain).
    fn set_sweeps_done(&self, sweeps: u64) {
        let mut e = self.lock();
        match e.chain_mut() {
            Some(c) => c.set_sweeps_done(sweeps),
            None => {
                if let Engine::Collapsed(s) = &mut *e {
                    s.set_sweeps_done(sweeps)
                }
            }
        }
    }

    fn log_joint(&self) -> f64 {
        match &*self.lock() {
            Engine::Collapsed(s) => s.log_joint(),
            Engine::Subcluster(c, _) => c.log_joint(),
        }
    }

    /// Bytes held by the patterns (and the collapsed sampler's score cache).
    fn memory_bytes(&self) -> usize {
        match &*self.lock() {
            Engine::Collapsed(s) => s.memory_bytes(),
            Engine::Subcluster(c, v) => {
                c.memory_bytes() + v.as_ref().map_or(0, |v| v.memory_bytes())
            }
        }
    }

    /// (proposed, accepted) counts of informed proposals so far (the collapsed sampler's).
    fn proposal_counts(&self) -> (u64, u64) {
        match &*self.lock() {
            Engine::Collapsed(s) => (s.proposals.proposed, s.proposals.accepted),
            Engine::Subcluster(..) => (0, 0),
        }
    }

    /// (split proposed, split accepted, merge proposed, merge accepted) so far.
    fn split_merge_counts(&self) -> (u64, u64, u64, u64) {
        let s = match &*self.lock() {
            Engine::Collapsed(s) => s.split_merge,
            Engine::Subcluster(c, _) => c.split_merge,
        };
        (
            s.split_proposed,
            s.split_accepted,
            s.merge_proposed,
            s.merge_accepted,
        )
    }

    /// The noise pair the chain is at.
    fn noise_var(&self) -> (f64, f64) {
        let n = match &*self.lock() {
            Engine::Collapsed(s) => s.noise_var(),
            Engine::Subcluster(c, _) => c.noise_var(),
        };
        (n[0], n[1])
    }

    /// Each pattern's noise pair, in slot order (the chain's pair unless the noise is per
    /// pattern).
    fn pattern_noise(&self) -> Vec<(f64, f64)> {
        self.infos()
            .into_iter()
            .map(|p| (p.noise_var[0], p.noise_var[1]))
            .collect()
    }

    /// Put the chain at a noise pair (a resumed chain).
    fn set_noise_var(&self, py: Python<'_>, noise_var: (f64, f64)) -> PyResult<()> {
        let noise = [noise_var.0, noise_var.1];
        self.run_engine(py, |e, _| match e.chain_mut() {
            Some(c) => c.set_noise_var(noise),
            None => e.collapsed()?.set_noise_var(noise),
        })
    }

    /// Seconds spent per part of the sweep so far (the parts depend on the sampler).
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let parts: Vec<(&str, f64)> = match &*self.lock() {
            Engine::Collapsed(s) => s.timings.parts().to_vec(),
            Engine::Subcluster(c, _) => c.timings.parts().to_vec(),
        };
        for (name, seconds) in parts {
            d.set_item(name, seconds)?;
        }
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
    /// `h`: each point's previous heading (`NaN`: unknown), for a chain over heading.
    #[allow(clippy::type_complexity)]
    #[pyo3(signature = (xy, v, offsets, h=None))]
    fn score_frames<'py>(
        &self,
        py: Python<'py>,
        xy: PyReadonlyArray2<'py, f64>,
        v: PyReadonlyArray2<'py, f64>,
        offsets: PyReadonlyArray1<'py, i64>,
        h: Option<PyReadonlyArray1<'py, f64>>,
    ) -> PyResult<(Vec<Vec<f64>>, Vec<f64>)> {
        let (xy, v) = (pairs("xy", &xy)?, pairs("v", &v)?);
        let h = crate::convert::headings("h", &h)?;
        dpgp_core::pattern::check_headings("h", h, xy.len()).map_err(CoreError)?;
        let offsets = offsets_vec("offsets", &offsets)?;
        let mut frames = frame_refs(xy, v, &offsets)?;
        if !h.is_empty() {
            for (f, w) in frames.iter_mut().zip(offsets.windows(2)) {
                f.h = &h[w[0]..w[1]];
            }
        }
        self.run(py, |s, _| s.score_frames(&frames))
    }

    /// Each pattern's heading length scale (slot order as `patterns`; `inf`: position only).
    fn heading_scales(&self) -> Vec<f64> {
        self.infos()
            .into_iter()
            .map(|p| p.length_scales.wh)
            .collect()
    }

    /// Posterior mean and variance of pattern `slot`'s velocity field at `query_xy`.
    #[allow(clippy::type_complexity)]
    #[pyo3(signature = (slot, query_xy, h=None))]
    fn posterior<'py>(
        &self,
        py: Python<'py>,
        slot: usize,
        query_xy: PyReadonlyArray2<'py, f64>,
        h: Option<PyReadonlyArray1<'py, f64>>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>)> {
        let q = pairs("query_xy", &query_xy)?;
        let h: &[f64] = match &h {
            Some(h) => h.as_slice().map_err(|_| {
                CoreError(Error::Shape("h must be a contiguous float64 array".into()))
            })?,
            None => &[],
        };
        if !h.is_empty() && h.len() != q.len() {
            return Err(CoreError(Error::Shape(format!(
                "{} headings for {} points",
                h.len(),
                q.len()
            )))
            .into());
        }
        let (mean, var) = self.run(py, |s, _| {
            let p = pattern_at(s, slot)?;
            dpgp_core::error::check_finite("query_xy", q.as_flattened())?;
            if h.iter().any(|x| x.is_infinite()) {
                return Err(Error::InvalidInput(
                    "headings must be finite radians or NaN (unknown)".into(),
                ));
            }
            Ok(p.posterior_at(dpgp_core::frame::Inputs { xy: q, h }))
        })?;
        Ok((to_numpy(py, mean), to_numpy(py, var)))
    }

    /// Set the state: a group number per frame, the length scales of each group, and alpha;
    /// `noise_var`: each group's noise pair (per-pattern noise), `None` for the chain's pair.
    /// `heading_scales`: each group's heading length scale, for a chain over heading.
    #[pyo3(signature = (labels, length_scales, alpha, noise_var=None, heading_scales=None))]
    fn set_state(
        &self,
        py: Python<'_>,
        labels: PyReadonlyArray1<'_, i64>,
        length_scales: PyReadonlyArray2<'_, f64>,
        alpha: f64,
        noise_var: Option<PyReadonlyArray2<'_, f64>>,
        heading_scales: Option<Vec<f64>>,
    ) -> PyResult<()> {
        let labels = offsets_vec("labels", &labels)?;
        let (ls, noise) = group_settings(&length_scales, &noise_var, &heading_scales)?;
        self.run_engine(py, |e, _| match e.chain_mut() {
            Some(c) => c.set_state(&labels, &ls, noise.as_deref(), alpha),
            None => e
                .collapsed()?
                .set_state_with_noise(&labels, &ls, noise.as_deref(), alpha),
        })
    }

    /// `set_state` with each frame in group `group[slot]` of its pattern's slot (a canonical
    /// rebuild): over shards that hold the labels, no label crosses. Sub-cluster chains only.
    #[pyo3(signature = (group, length_scales, alpha, noise_var=None, heading_scales=None))]
    fn regroup(
        &self,
        py: Python<'_>,
        group: PyReadonlyArray1<'_, i64>,
        length_scales: PyReadonlyArray2<'_, f64>,
        alpha: f64,
        noise_var: Option<PyReadonlyArray2<'_, f64>>,
        heading_scales: Option<Vec<f64>>,
    ) -> PyResult<()> {
        // Slots that hold no pattern may map anywhere (negative: nowhere).
        let group: Vec<usize> = group
            .as_array()
            .iter()
            .map(|&g| usize::try_from(g).unwrap_or(usize::MAX))
            .collect();
        let (ls, noise) = group_settings(&length_scales, &noise_var, &heading_scales)?;
        self.run_engine(py, |e, _| match e.chain_mut() {
            Some(c) => c.regroup(&group, &ls, noise.as_deref(), alpha),
            None => Err(Error::InvalidInput(
                "regroup is the sub-cluster chain's; the collapsed sampler takes set_state".into(),
            )),
        })
    }
}

/// Each group's length scales (with its heading scale) and noise pair, as `set_state` takes them.
#[allow(clippy::type_complexity)]
fn group_settings(
    length_scales: &PyReadonlyArray2<'_, f64>,
    noise_var: &Option<PyReadonlyArray2<'_, f64>>,
    heading_scales: &Option<Vec<f64>>,
) -> PyResult<(Vec<LengthScales>, Option<Vec<[f64; 2]>>)> {
    let pos = pairs("length_scales", length_scales)?;
    if let Some(wh) = &heading_scales
        && wh.len() != pos.len()
    {
        return Err(CoreError(Error::Shape(format!(
            "{} heading length scales for {} groups",
            wh.len(),
            pos.len()
        )))
        .into());
    }
    let ls: Vec<LengthScales> = pos
        .iter()
        .enumerate()
        .map(|(g, w)| {
            let ls = LengthScales::new(w[0], w[1])?;
            match &heading_scales {
                Some(wh) => ls.with_heading(wh[g]),
                None => Ok(ls),
            }
        })
        .collect::<dpgp_core::Result<_>>()
        .map_err(CoreError)?;
    let noise: Option<Vec<[f64; 2]>> = match &noise_var {
        Some(n) => Some(pairs("noise_var", n)?.to_vec()),
        None => None,
    };
    Ok((ls, noise))
}

impl PySampler {
    fn infos(&self) -> Vec<dpgp_core::gibbs::PatternInfo> {
        match &*self.lock() {
            Engine::Collapsed(s) => s.patterns(),
            Engine::Subcluster(c, _) => c.patterns(),
        }
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
