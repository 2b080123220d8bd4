//! NLopt, built from its C sources (version 2.9.1, every algorithm but the LGPL Luksan ones, so the
//! library is under NLopt's MIT licence), with a safe interface to what skincal uses: bound-
//! constrained minimisation of a derivative-free objective by a global algorithm with a local
//! optimiser, stopped by an objective value, an evaluation budget or a relative tolerance.
//!
//! The C library is compiled by `skincal-nlopt-sys`'s `build.rs` with the `cc` crate (no cmake, no
//! system NLopt) under the flags of NLopt's own CMake build, so results are those of any other
//! NLopt 2.9.1 build.
//!
//! ```
//! use skincal_nlopt::{seed, Algorithm, Optimizer, Stop};
//!
//! // The paper's combination: MLSL with low-discrepancy starts, Nelder–Mead for the local searches.
//! seed(7);
//! let mut local = Optimizer::new(Algorithm::NelderMead, 2).unwrap();
//! local.set_ftol_rel(1e-10).unwrap();
//! let mut opt = Optimizer::new(Algorithm::MlslLds, 2).unwrap();
//! opt.set_bounds(&[-2.0, -2.0], &[2.0, 2.0]).unwrap();
//! opt.set_stopval(1e-8).unwrap();
//! opt.set_maxeval(100_000).unwrap();
//! opt.set_local_optimizer(&local).unwrap();
//! let mut x = [0.0, 0.0];
//! let rosenbrock = |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2);
//! let result = opt.minimize(&mut x, rosenbrock).unwrap();
//! assert_eq!(result.stop, Stop::StopValReached);
//! assert!((x[0] - 1.0).abs() < 1e-3 && (x[1] - 1.0).abs() < 1e-3);
//! ```

use std::any::Any;
use std::ffi::{c_double, c_int, c_uint, c_ulong, c_void, CStr};
use std::fmt;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::ptr::NonNull;

use skincal_nlopt_sys as ffi;

/// The NLopt algorithms this interface offers (their `nlopt_algorithm` codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Algorithm {
    /// `NLOPT_G_MLSL_LDS`: multi-level single-linkage with Sobol' low-discrepancy starting points,
    /// running the local optimiser set by [`Optimizer::set_local_optimizer`].
    MlslLds,
    /// `NLOPT_LN_NELDERMEAD`: the Nelder–Mead simplex, derivative free.
    NelderMead,
}

impl Algorithm {
    /// NLopt's name of the algorithm, as `nlopt_algorithm_to_string` gives it.
    pub fn nlopt_name(self) -> &'static CStr {
        match self {
            Algorithm::NelderMead => c"LN_NELDERMEAD",
            Algorithm::MlslLds => c"G_MLSL_LDS",
        }
    }

    /// The `nlopt_algorithm` code, looked up by name in the linked library.
    fn code(self) -> c_int {
        // SAFETY: a NUL-terminated name; NLopt returns -1 for names it does not know.
        unsafe { ffi::nlopt_algorithm_from_string(self.nlopt_name().as_ptr()) }
    }
}

/// Why a run stopped successfully (the positive `nlopt_result` codes, named as in NLopt).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// `NLOPT_SUCCESS`: generic success.
    Success,
    /// `NLOPT_STOPVAL_REACHED`: the objective reached the value of [`Optimizer::set_stopval`].
    StopValReached,
    /// `NLOPT_FTOL_REACHED`: the relative or absolute objective tolerance was met.
    FtolReached,
    /// `NLOPT_XTOL_REACHED`: the relative or absolute parameter tolerance was met.
    XtolReached,
    /// `NLOPT_MAXEVAL_REACHED`: the evaluation budget of [`Optimizer::set_maxeval`] is spent.
    MaxEvalReached,
    /// `NLOPT_MAXTIME_REACHED`: the time budget is spent.
    MaxTimeReached,
}

/// Why a call failed (the negative `nlopt_result` codes), with NLopt's own message where it gave one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Error {
    /// What failed.
    pub kind: ErrorKind,
    /// NLopt's explanation (`nlopt_get_errmsg`), when it set one.
    pub message: Option<String>,
}

/// The kinds of NLopt failure (the negative `nlopt_result` codes, named as in NLopt).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// `NLOPT_FAILURE`: generic failure.
    Failure,
    /// `NLOPT_INVALID_ARGS`: bounds, dimensions or settings NLopt refuses.
    InvalidArgs,
    /// `NLOPT_OUT_OF_MEMORY`.
    OutOfMemory,
    /// `NLOPT_ROUNDOFF_LIMITED`: rounding errors stopped progress (the point is usually still useful).
    RoundoffLimited,
    /// `NLOPT_FORCED_STOP`: the run was stopped early.
    ForcedStop,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self.kind {
            ErrorKind::Failure => "NLopt failed",
            ErrorKind::InvalidArgs => "NLopt refused its arguments",
            ErrorKind::OutOfMemory => "NLopt ran out of memory",
            ErrorKind::RoundoffLimited => "NLopt was stopped by rounding errors",
            ErrorKind::ForcedStop => "NLopt was stopped early",
        };
        match &self.message {
            Some(message) => write!(f, "{what}: {message}"),
            None => f.write_str(what),
        }
    }
}

impl std::error::Error for Error {}

/// The end of a successful [`Optimizer::minimize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Minimum {
    /// Why it stopped.
    pub stop: Stop,
    /// The objective at the returned point.
    pub value: f64,
}

/// A failed [`Optimizer::minimize`]: why, and the objective at the point it left in `x` (NLopt
/// leaves its best point there also on failure).
#[derive(Debug, Clone, PartialEq)]
pub struct Failure {
    /// Why it failed.
    pub error: Error,
    /// The objective at the point left in `x`.
    pub value: f64,
}

/// Seeds NLopt's random numbers on the calling thread (NLopt keeps them per thread), so that the
/// next runs on this thread are repeatable; without it NLopt seeds from the clock.
pub fn seed(seed: u64) {
    // `unsigned long` is 32 bits on some targets: NLopt takes what fits, as its own bindings do.
    // SAFETY: nlopt_srand only writes NLopt's thread-local generator state.
    unsafe { ffi::nlopt_srand(seed as c_ulong) }
}

/// The version of the NLopt library linked in, `(major, minor, bugfix)`.
pub fn version() -> (i32, i32, i32) {
    let (mut major, mut minor, mut bugfix) = (0, 0, 0);
    // SAFETY: the three pointers are valid for writes for the duration of the call.
    unsafe { ffi::nlopt_version(&mut major, &mut minor, &mut bugfix) };
    (major, minor, bugfix)
}

/// One NLopt problem (`nlopt_opt`): an algorithm on `dimension` parameters with its bounds and
/// stopping criteria. Settings follow NLopt's semantics; each returns NLopt's refusal as an
/// [`Error`].
pub struct Optimizer {
    raw: NonNull<ffi::NloptOpt>,
    dimension: usize,
}

impl fmt::Debug for Optimizer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Optimizer")
            .field("dimension", &self.dimension)
            .finish_non_exhaustive()
    }
}

impl Drop for Optimizer {
    fn drop(&mut self) {
        // SAFETY: `raw` came from nlopt_create, is owned by self and destroyed once.
        unsafe { ffi::nlopt_destroy(self.raw.as_ptr()) }
    }
}

/// What the C callback needs: the objective, and where to put a panic that must not cross C.
struct Callback<'f, F> {
    objective: &'f mut F,
    optimizer: *mut ffi::NloptOpt,
    panic: Option<Box<dyn Any + Send>>,
}

unsafe extern "C" fn call_objective<F: FnMut(&[f64]) -> f64>(
    n: c_uint,
    x: *const c_double,
    _gradient: *mut c_double,
    data: *mut c_void,
) -> c_double {
    // SAFETY: `data` is the `Callback<F>` that `minimize` passed with this very function, alive
    // and not otherwise borrowed while nlopt_optimize runs; NLopt passes `x` with `n` entries.
    let callback = unsafe { &mut *data.cast::<Callback<'_, F>>() };
    if callback.panic.is_some() {
        return f64::NAN;
    }
    let x = unsafe { std::slice::from_raw_parts(x, n as usize) };
    match catch_unwind(AssertUnwindSafe(|| (callback.objective)(x))) {
        Ok(value) => value,
        Err(payload) => {
            callback.panic = Some(payload);
            // SAFETY: the optimiser being run; stopping it also stops its local searches.
            unsafe { ffi::nlopt_force_stop(callback.optimizer) };
            f64::NAN
        }
    }
}

impl Optimizer {
    /// A problem of `dimension` parameters for `algorithm`.
    pub fn new(algorithm: Algorithm, dimension: usize) -> Result<Self, Error> {
        let n = c_uint::try_from(dimension).map_err(|_| Error {
            kind: ErrorKind::InvalidArgs,
            message: Some(format!(
                "{dimension} parameters are more than NLopt can take"
            )),
        })?;
        let code = algorithm.code();
        if code < 0 {
            return Err(Error {
                kind: ErrorKind::Failure,
                message: Some(format!("the linked NLopt has no {algorithm:?}")),
            });
        }
        // SAFETY: plain constructor; a null result means NLopt refused or had no memory.
        let raw = unsafe { ffi::nlopt_create(code, n) };
        NonNull::new(raw)
            .map(|raw| Optimizer { raw, dimension })
            .ok_or(Error {
                kind: ErrorKind::OutOfMemory,
                message: Some(format!(
                    "could not create {algorithm:?} on {dimension} parameters"
                )),
            })
    }

    /// The number of parameters.
    pub fn dimension(&self) -> usize {
        self.dimension
    }

    /// Box bounds `lower[i] ≤ x[i] ≤ upper[i]`; both slices have [`Self::dimension`] entries.
    pub fn set_bounds(&mut self, lower: &[f64], upper: &[f64]) -> Result<(), Error> {
        for bounds in [lower, upper] {
            self.check_length(bounds.len(), "bounds")?;
        }
        // SAFETY: both slices hold `dimension` values, which is what NLopt reads.
        self.check(unsafe { ffi::nlopt_set_lower_bounds(self.raw.as_ptr(), lower.as_ptr()) })?;
        self.check(unsafe { ffi::nlopt_set_upper_bounds(self.raw.as_ptr(), upper.as_ptr()) })
    }

    /// Stop as soon as the objective is at or below `value`.
    pub fn set_stopval(&mut self, value: f64) -> Result<(), Error> {
        // SAFETY: `raw` is a live optimiser.
        self.check(unsafe { ffi::nlopt_set_stopval(self.raw.as_ptr(), value) })
    }

    /// Stop when a step changes the objective by less than `tolerance` times its value.
    pub fn set_ftol_rel(&mut self, tolerance: f64) -> Result<(), Error> {
        // SAFETY: `raw` is a live optimiser.
        self.check(unsafe { ffi::nlopt_set_ftol_rel(self.raw.as_ptr(), tolerance) })
    }

    /// Stop after about `evaluations` objective evaluations (at most `i32::MAX`).
    pub fn set_maxeval(&mut self, evaluations: usize) -> Result<(), Error> {
        let evaluations = c_int::try_from(evaluations).unwrap_or(c_int::MAX);
        // SAFETY: `raw` is a live optimiser.
        self.check(unsafe { ffi::nlopt_set_maxeval(self.raw.as_ptr(), evaluations) })
    }

    /// The local optimiser of a global algorithm such as [`Algorithm::MlslLds`]: NLopt copies its
    /// algorithm and stopping criteria (not its bounds: the global problem's bounds at the time of
    /// this call are used), so set the bounds first.
    pub fn set_local_optimizer(&mut self, local: &Optimizer) -> Result<(), Error> {
        self.check_length(local.dimension, "local optimiser")?;
        // SAFETY: both are live optimisers; NLopt copies `local`.
        self.check(unsafe { ffi::nlopt_set_local_optimizer(self.raw.as_ptr(), local.raw.as_ptr()) })
    }

    /// Minimises `objective` from the start point `x` (which must lie within the bounds) and
    /// leaves the best point found in `x`, also when the run fails. A panic in `objective` stops
    /// the run and is resumed here once NLopt has returned.
    pub fn minimize<F>(&mut self, x: &mut [f64], mut objective: F) -> Result<Minimum, Failure>
    where
        F: FnMut(&[f64]) -> f64,
    {
        if let Err(error) = self.check_length(x.len(), "start point") {
            return Err(Failure {
                error,
                value: f64::NAN,
            });
        }
        let mut callback = Callback {
            objective: &mut objective,
            optimizer: self.raw.as_ptr(),
            panic: None,
        };
        let data = (&mut callback as *mut Callback<'_, F>).cast::<c_void>();
        let mut value = f64::NAN;
        // SAFETY: the callback and its data match (`call_objective::<F>` reads a `Callback<F>`),
        // `callback` outlives the run, and `x` holds `dimension` values. The objective is
        // cleared again (after NLopt's message is read) before `callback` goes out of scope.
        let outcome = unsafe {
            let mut code =
                ffi::nlopt_set_min_objective(self.raw.as_ptr(), Some(call_objective::<F>), data);
            if code > 0 {
                code = ffi::nlopt_optimize(self.raw.as_ptr(), x.as_mut_ptr(), &mut value);
            }
            let outcome = self.check(code).map(|()| stop_from_code(code));
            ffi::nlopt_set_min_objective(self.raw.as_ptr(), None, std::ptr::null_mut());
            outcome
        };
        if let Some(payload) = callback.panic.take() {
            resume_unwind(payload);
        }
        outcome
            .map(|stop| Minimum { stop, value })
            .map_err(|error| Failure { error, value })
    }

    fn check_length(&self, length: usize, what: &str) -> Result<(), Error> {
        if length == self.dimension {
            Ok(())
        } else {
            Err(Error {
                kind: ErrorKind::InvalidArgs,
                message: Some(format!(
                    "the {what} has {length} entries for {} parameters",
                    self.dimension
                )),
            })
        }
    }

    /// `Ok` for NLopt's success codes, its error and message for the failure codes.
    fn check(&self, code: c_int) -> Result<(), Error> {
        let kind = match code {
            c if c > 0 => return Ok(()),
            -2 => ErrorKind::InvalidArgs,
            -3 => ErrorKind::OutOfMemory,
            -4 => ErrorKind::RoundoffLimited,
            -5 => ErrorKind::ForcedStop,
            _ => ErrorKind::Failure,
        };
        // SAFETY: `raw` is live; NLopt returns null or a NUL-terminated string it owns.
        let message = unsafe {
            let text = ffi::nlopt_get_errmsg(self.raw.as_ptr());
            (!text.is_null()).then(|| CStr::from_ptr(text).to_string_lossy().into_owned())
        };
        Err(Error { kind, message })
    }
}

fn stop_from_code(code: c_int) -> Stop {
    match code {
        2 => Stop::StopValReached,
        3 => Stop::FtolReached,
        4 => Stop::XtolReached,
        5 => Stop::MaxEvalReached,
        6 => Stop::MaxTimeReached,
        _ => Stop::Success,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// NLopt's own string table for a result code.
    fn result_name(code: c_int) -> String {
        // SAFETY: NLopt returns a static string (or null for codes it does not know).
        let text = unsafe { ffi::nlopt_result_to_string(code) };
        assert!(!text.is_null(), "NLopt knows no result {code}");
        unsafe { CStr::from_ptr(text) }
            .to_string_lossy()
            .into_owned()
    }

    #[test]
    fn algorithms_and_results_carry_nlopts_own_codes() {
        for algorithm in [Algorithm::NelderMead, Algorithm::MlslLds] {
            let code = algorithm.code();
            assert!(code >= 0, "{algorithm:?} unknown to the linked NLopt");
            // SAFETY: a valid code; NLopt returns a static string.
            let name = unsafe { CStr::from_ptr(ffi::nlopt_algorithm_to_string(code)) };
            assert_eq!(name, algorithm.nlopt_name());
        }
        let stops = [
            (1, Stop::Success, "SUCCESS"),
            (2, Stop::StopValReached, "STOPVAL_REACHED"),
            (3, Stop::FtolReached, "FTOL_REACHED"),
            (4, Stop::XtolReached, "XTOL_REACHED"),
            (5, Stop::MaxEvalReached, "MAXEVAL_REACHED"),
            (6, Stop::MaxTimeReached, "MAXTIME_REACHED"),
        ];
        for (code, stop, name) in stops {
            assert_eq!(stop_from_code(code), stop);
            assert_eq!(result_name(code), name);
        }
        let opt = Optimizer::new(Algorithm::NelderMead, 1).unwrap();
        let failures = [
            (-1, ErrorKind::Failure, "FAILURE"),
            (-2, ErrorKind::InvalidArgs, "INVALID_ARGS"),
            (-3, ErrorKind::OutOfMemory, "OUT_OF_MEMORY"),
            (-4, ErrorKind::RoundoffLimited, "ROUNDOFF_LIMITED"),
            (-5, ErrorKind::ForcedStop, "FORCED_STOP"),
        ];
        for (code, kind, name) in failures {
            assert_eq!(opt.check(code).unwrap_err().kind, kind);
            assert_eq!(result_name(code), name);
        }
    }

    #[test]
    fn the_library_is_nlopt_2_9_1() {
        assert_eq!(version(), (2, 9, 1));
    }

    #[test]
    fn nelder_mead_finds_a_quadratic_minimum_within_bounds() {
        // Minimum of (x−0.3)² + 2(y+0.2)² is 0 at (0.3, −0.2); with y ≥ 0 it is at (0.3, 0): 0.08.
        let mut opt = Optimizer::new(Algorithm::NelderMead, 2).unwrap();
        opt.set_bounds(&[-1.0, 0.0], &[1.0, 1.0]).unwrap();
        opt.set_ftol_rel(1e-14).unwrap();
        let mut x = [0.9, 0.9];
        let mut evaluations = 0;
        let minimum = opt
            .minimize(&mut x, |x| {
                evaluations += 1;
                (x[0] - 0.3).powi(2) + 2.0 * (x[1] + 0.2).powi(2)
            })
            .unwrap();
        assert!((x[0] - 0.3).abs() < 1e-6 && x[1].abs() < 1e-6, "{x:?}");
        assert!((minimum.value - 0.08).abs() < 1e-10);
        assert!(evaluations > 10);
    }

    #[test]
    fn mlsl_runs_repeat_exactly_with_the_same_seed() {
        let run = |seed_value: u64| {
            seed(seed_value);
            let mut local = Optimizer::new(Algorithm::NelderMead, 3).unwrap();
            local.set_ftol_rel(1e-6).unwrap();
            let mut opt = Optimizer::new(Algorithm::MlslLds, 3).unwrap();
            opt.set_bounds(&[-3.0; 3], &[3.0; 3]).unwrap();
            opt.set_maxeval(2000).unwrap();
            opt.set_local_optimizer(&local).unwrap();
            let mut x = [0.0; 3];
            // Rastrigin-like: many local minima, global minimum 0 at the origin shifted by 1.
            let f = |x: &[f64]| {
                x.iter()
                    .map(|v| (v - 1.0).powi(2) - (6.0 * (v - 1.0)).cos() + 1.0)
                    .sum::<f64>()
            };
            let minimum = opt.minimize(&mut x, f).unwrap();
            (x, minimum.value)
        };
        let (a, b) = (run(11), run(11));
        assert_eq!(a.0.map(f64::to_bits), b.0.map(f64::to_bits));
        assert!(a.1 < 1e-6, "global minimum missed: {a:?}");
    }

    #[test]
    fn refusals_and_panics_come_back_to_the_caller() {
        let mut opt = Optimizer::new(Algorithm::NelderMead, 2).unwrap();
        let wrong = opt.set_bounds(&[0.0], &[1.0]).unwrap_err();
        assert_eq!(wrong.kind, ErrorKind::InvalidArgs);
        assert!(wrong.to_string().contains("1 entries for 2 parameters"));
        // NLopt checks the bounds against each other and the start when the run begins.
        opt.set_bounds(&[1.0, 1.0], &[0.0, 0.0]).unwrap();
        let inverted = opt.minimize(&mut [0.5, 0.5], |x| x[0]).unwrap_err();
        assert_eq!(inverted.error.kind, ErrorKind::InvalidArgs);
        // MLSL without a local optimiser is refused by NLopt itself, with its message.
        let mut mlsl = Optimizer::new(Algorithm::MlslLds, 1).unwrap();
        mlsl.set_bounds(&[-1.0], &[1.0]).unwrap();
        let failure = mlsl.minimize(&mut [0.0], |x| x[0] * x[0]).unwrap_err();
        assert_eq!(failure.error.kind, ErrorKind::InvalidArgs);
        assert!(
            failure.error.to_string().contains("local optimizer"),
            "{failure:?}"
        );
        // A panic inside the objective stops NLopt and reaches the caller unchanged.
        let mut opt = Optimizer::new(Algorithm::NelderMead, 1).unwrap();
        let mut calls = 0;
        let caught = std::panic::catch_unwind(AssertUnwindSafe(|| {
            opt.minimize(&mut [0.5], |_| {
                calls += 1;
                panic!("objective failed")
            })
        }));
        let payload = caught.unwrap_err();
        assert_eq!(payload.downcast_ref::<&str>(), Some(&"objective failed"));
        assert_eq!(calls, 1);
    }
}
