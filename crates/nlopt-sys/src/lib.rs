//! The C declarations of `nlopt.h` that `skincal-nlopt` calls, linked against NLopt 2.9.1 as
//! `build.rs` compiles it from `nlopt/` (see `skincal-nlopt` for the safe interface).

#![no_std]

use core::ffi::{c_char, c_double, c_int, c_uint, c_ulong, c_void};

/// `struct nlopt_opt_s`, opaque.
#[repr(C)]
pub struct NloptOpt {
    _private: [u8; 0],
}

/// `nlopt_func`: objective with optional gradient.
pub type Func = Option<
    unsafe extern "C" fn(
        n: c_uint,
        x: *const c_double,
        gradient: *mut c_double,
        data: *mut c_void,
    ) -> c_double,
>;

#[allow(missing_docs)]
unsafe extern "C" {
    pub fn nlopt_srand(seed: c_ulong);
    pub fn nlopt_version(major: *mut c_int, minor: *mut c_int, bugfix: *mut c_int);
    pub fn nlopt_algorithm_from_string(name: *const c_char) -> c_int;
    pub fn nlopt_algorithm_to_string(algorithm: c_int) -> *const c_char;
    pub fn nlopt_result_to_string(result: c_int) -> *const c_char;
    pub fn nlopt_create(algorithm: c_int, n: c_uint) -> *mut NloptOpt;
    pub fn nlopt_destroy(opt: *mut NloptOpt);
    pub fn nlopt_optimize(opt: *mut NloptOpt, x: *mut c_double, opt_f: *mut c_double) -> c_int;
    pub fn nlopt_set_min_objective(opt: *mut NloptOpt, f: Func, data: *mut c_void) -> c_int;
    pub fn nlopt_get_errmsg(opt: *mut NloptOpt) -> *const c_char;
    pub fn nlopt_set_lower_bounds(opt: *mut NloptOpt, lb: *const c_double) -> c_int;
    pub fn nlopt_set_upper_bounds(opt: *mut NloptOpt, ub: *const c_double) -> c_int;
    pub fn nlopt_set_stopval(opt: *mut NloptOpt, stopval: c_double) -> c_int;
    pub fn nlopt_set_ftol_rel(opt: *mut NloptOpt, tol: c_double) -> c_int;
    pub fn nlopt_set_maxeval(opt: *mut NloptOpt, maxeval: c_int) -> c_int;
    pub fn nlopt_force_stop(opt: *mut NloptOpt) -> c_int;
    pub fn nlopt_set_local_optimizer(opt: *mut NloptOpt, local: *const NloptOpt) -> c_int;
}
