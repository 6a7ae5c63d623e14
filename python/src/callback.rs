//! Residuals written in Python: a callable of the variables' values that returns the residual and,
//! unless numeric differentiation was chosen, its Jacobian blocks.
//!
//! A problem with such residuals is solved on the calling thread with the interpreter held
//! ([`on_this_thread`]), so each call finds it taken already. An exception, or a result of the
//! wrong shape, is kept (the first one of a solve), the block reads as non-finite so that no step
//! is taken on it, and the solve stops at the end of the iteration and raises it, naming the
//! block.

use crate::arrays::{self, Vector};
use dynamap_solver::{Jacobians, NumericDiff, Residual, Var};
use numpy::{AllowTypeChange, PyArrayLike2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// The first error a Python residual raised during a solve.
#[derive(Default)]
pub struct ErrorSlot {
    set: AtomicBool,
    error: Mutex<Option<PyErr>>,
}

impl ErrorSlot {
    /// True once an error is kept.
    pub fn is_set(&self) -> bool {
        self.set.load(Ordering::Acquire)
    }
    /// Keeps `e` unless an earlier error is kept.
    pub fn keep_first(&self, e: PyErr) {
        let mut slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Some(e);
            self.set.store(true, Ordering::Release);
        }
    }
    /// The kept error, if any; the slot is empty afterwards.
    pub fn take(&self) -> Option<PyErr> {
        let e = self.error.lock().unwrap_or_else(|p| p.into_inner()).take();
        self.set.store(false, Ordering::Release);
        e
    }
}

/// A Python callable as the function of one residual block.
pub struct Callable {
    f: Py<PyAny>,
    dim: usize,
    block: usize,
    errors: Arc<ErrorSlot>,
}

impl Callable {
    /// Block `block`'s callable with `dim` residual rows, keeping its errors in `errors`.
    pub fn new(f: Py<PyAny>, dim: usize, block: usize, errors: Arc<ErrorSlot>) -> Self {
        Self {
            f,
            dim,
            block,
            errors,
        }
    }

    /// `f(*values)`.
    fn call<'py>(&self, py: Python<'py>, values: &[&[f64]]) -> PyResult<Bound<'py, PyAny>> {
        let args: Vec<_> = values.iter().map(|v| arrays::vector(py, v)).collect();
        self.f.bind(py).call1(PyTuple::new(py, args)?)
    }

    /// Copies a returned residual into `out`, checking its length.
    fn residual_into(&self, r: &Bound<'_, PyAny>, out: &mut [f64]) -> PyResult<()> {
        let r: Vector<'_> = r.extract().map_err(|e| self.shape(format!("{e}")))?;
        let v = r.as_array();
        if v.len() != self.dim {
            return Err(self.shape(format!(
                "returned {} residual rows, {} were declared",
                v.len(),
                self.dim
            )));
        }
        for (o, x) in out.iter_mut().zip(v.iter()) {
            *o = *x;
        }
        Ok(())
    }

    fn shape(&self, what: String) -> PyErr {
        PyValueError::new_err(format!("residual block {}: {what}", self.block))
    }

    /// The residual alone, for numeric differentiation: `f` returns r.
    fn plain(&self, values: &[&[f64]], out: &mut [f64]) {
        self.guarded(out, |py, out| {
            let r = self.call(py, values)?;
            self.residual_into(&r, out)
        });
    }

    /// The residual and its Jacobians: `f` returns `(r, [J_1, …, J_k])`, J_k of shape
    /// `dim × tangent_dim(x_k)`.
    fn analytic(&self, vars: &[Var<'_>], out: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        let values: Vec<&[f64]> = vars.iter().map(|v| v.value).collect();
        self.guarded(out, |py, out| {
            let result = self.call(py, &values)?;
            let (r, js): (Bound<'_, PyAny>, Bound<'_, PyAny>) = result.extract().map_err(|_| {
                self.shape("expected (residual, [jacobian, ...]) from the callable".into())
            })?;
            self.residual_into(&r, out)?;
            if let Some(j) = jac {
                self.jacobians_into(&js, vars.len(), j)?;
            }
            Ok(())
        });
    }

    /// Copies the returned Jacobian blocks (row-major arrays) into the column-major blocks.
    fn jacobians_into(
        &self,
        js: &Bound<'_, PyAny>,
        k: usize,
        out: &mut Jacobians<'_>,
    ) -> PyResult<()> {
        let js: Vec<PyArrayLike2<'_, f64, AllowTypeChange>> = js
            .extract()
            .map_err(|e| self.shape(format!("the Jacobians: {e}")))?;
        if js.len() != k {
            return Err(self.shape(format!(
                "returned {} Jacobian blocks for {k} variables",
                js.len()
            )));
        }
        for (b, jb) in js.iter().enumerate() {
            let a = jb.as_array();
            let cols = out.cols(b);
            if a.shape() != [self.dim, cols] {
                return Err(self.shape(format!(
                    "Jacobian block {b} has shape {:?}, expected ({}, {cols})",
                    a.shape(),
                    self.dim
                )));
            }
            let block = out.block(b);
            for c in 0..cols {
                for i in 0..self.dim {
                    block[c * self.dim + i] = a[[i, c]];
                }
            }
        }
        Ok(())
    }

    /// Runs `body` with the interpreter; on an error (or after one kept earlier) the residual
    /// reads NaN and the error is kept.
    fn guarded(&self, out: &mut [f64], body: impl FnOnce(Python<'_>, &mut [f64]) -> PyResult<()>) {
        if self.errors.is_set() {
            out.fill(f64::NAN);
            return;
        }
        Python::attach(|py| {
            if let Err(e) = body(py, out) {
                out.fill(f64::NAN);
                self.errors.keep_first(e);
            }
        });
    }
}

/// A Python residual with Jacobians from the callable itself.
pub struct Analytic(pub Callable);

impl Residual for Analytic {
    fn dim(&self) -> usize {
        self.0.dim
    }
    fn evaluate(&self, vars: &[Var<'_>], residual: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        self.0.analytic(vars, residual, jac);
    }
}

/// A Python residual differentiated by central differences on each variable's manifold.
pub fn numeric(c: Callable) -> impl Residual {
    let dim = c.dim;
    NumericDiff::new(dim, move |values: &[&[f64]], r: &mut [f64]| {
        c.plain(values, r)
    })
}

thread_local! {
    /// A rayon pool whose one worker is this thread (built on first use, kept for the thread).
    static HERE: std::cell::OnceCell<rayon::ThreadPool> = const { std::cell::OnceCell::new() };
}

/// Runs `f` with the solver's parallel loops on the calling thread alone, the interpreter held.
///
/// A problem with residuals written in Python gains nothing from more threads (each call needs
/// the interpreter), and every call from another thread would take the interpreter and switch
/// threads; here each call finds it held already.
pub fn on_this_thread<R: Send>(f: impl FnOnce() -> R + Send) -> PyResult<R> {
    HERE.with(|cell| {
        if cell.get().is_none() {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .use_current_thread()
                .build()
                .map_err(|e| PyValueError::new_err(format!("a one-thread pool: {e}")))?;
            let _ = cell.set(pool);
        }
        Ok(cell.get().expect("set above").install(f))
    })
}
