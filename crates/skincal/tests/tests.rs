//! Integration tests of the skincal library. Truth always comes from outside the code under test:
//! values computed by hand, independent re-implementations of the paper's equations, or laws that
//! must hold.

/// The allocator the `skincal` command runs the library on: the fits allocate and free blocks of
/// kilobytes per sample on every thread, which glibc's malloc serves a sixth slower. (The Python
/// package keeps the system's: a module loaded by `dlopen` cannot take mimalloc's thread-local
/// state from the static TLS block, and fails to import.)
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod architecture;
mod bags;
mod body;
mod check;
mod collision;
mod common;
mod descriptions;
mod estimation;
mod exploration;
mod kinematics;
mod logs;
mod measurements;
mod mimic;
mod ml_estimation;
mod motion;
mod paper;
mod physics;
mod prismatic;
mod real_logs;
mod real_robots;
mod robot_like;
mod robustness;
mod sensors;
mod simulator;
mod urdf_check;
mod urdf_import;
