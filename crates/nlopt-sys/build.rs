//! Builds NLopt's C library from `nlopt/` with the `cc` crate: no cmake, no system library.
//!
//! Mirrors NLopt's own CMake build with `NLOPT_CXX=OFF` (no StoGO/AGS) and `NLOPT_LUKSAN=OFF`
//! (so the compiled library is under NLopt's MIT licence): the same sources, the configuration
//! header its CMake would write for the target, `-O3 -DNDEBUG` and no floating-point contraction
//! (`-ffp-contract=off`, as NLopt's CMake sets), so results match a CMake build bit for bit.

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

/// Directories under `nlopt/src` whose `.c` files make the library (NLopt's `NLOPT_SOURCES`).
const SOURCE_DIRS: &[&str] = &[
    "api",
    "util",
    "algs/auglag",
    "algs/bobyqa",
    "algs/cdirect",
    "algs/cobyla",
    "algs/crs",
    "algs/direct",
    "algs/esch",
    "algs/isres",
    "algs/mlsl",
    "algs/mma",
    "algs/neldermead",
    "algs/newuoa",
    "algs/praxis",
    "algs/slsqp",
];

fn main() {
    let root = Path::new("nlopt/src");
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("nlopt_config.h"), config_header()).expect("OUT_DIR is writable");

    let mut build = cc::Build::new();
    build
        .include(&out)
        .define("NDEBUG", None)
        .opt_level(3)
        .warnings(false)
        .flag_if_supported("-ffp-contract=off");
    for dir in SOURCE_DIRS {
        let dir = root.join(dir);
        build.include(&dir);
        let mut sources: Vec<PathBuf> = fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|entry| entry.expect("readable directory entry").path())
            .filter(|path| path.extension().is_some_and(|ext| ext == "c"))
            .collect();
        sources.sort();
        build.files(sources);
    }
    build.compile("nlopt");
    println!("cargo:rerun-if-changed=nlopt/src");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:include={}", root.join("api").display());
}

/// The `nlopt_config.h` that NLopt's CMake writes for the target being built.
fn config_header() -> String {
    let windows = env::var("CARGO_CFG_TARGET_OS").is_ok_and(|os| os == "windows");
    let msvc = env::var("CARGO_CFG_TARGET_ENV").is_ok_and(|e| e == "msvc");
    let pointer_bits: u32 = env::var("CARGO_CFG_TARGET_POINTER_WIDTH")
        .ok()
        .and_then(|w| w.parse().ok())
        .unwrap_or(64);
    // `unsigned long` is 32 bits on Windows (LLP64) and pointer-sized elsewhere.
    let sizeof_unsigned_long = if windows { 4 } else { pointer_bits / 8 };
    let mut defines = vec![
        "#define MAJOR_VERSION 2".to_string(),
        "#define MINOR_VERSION 9".into(),
        "#define BUGFIX_VERSION 1".into(),
        "#define SIZEOF_UNSIGNED_INT 4".into(),
        format!("#define SIZEOF_UNSIGNED_LONG {sizeof_unsigned_long}"),
        "#define HAVE_COPYSIGN".into(),
        "#define HAVE_FPCLASSIFY".into(),
        "#define HAVE_ISINF".into(),
        "#define HAVE_ISNAN".into(),
        "#define HAVE_STDINT_H".into(),
        "#define HAVE_UINT32_T".into(),
        "#define HAVE_TIME".into(),
    ];
    if msvc {
        defines.push("#define THREADLOCAL __declspec(thread)".into());
    } else {
        defines.push("#define THREADLOCAL __thread".into());
        defines.extend(
            [
                "HAVE_GETOPT_H",
                "HAVE_GETOPT",
                "HAVE_GETPID",
                "HAVE_GETTIMEOFDAY",
                "HAVE_SYS_TIME_H",
                "HAVE_UNISTD_H",
                "TIME_WITH_SYS_TIME",
            ]
            .map(|name| format!("#define {name}")),
        );
    }
    format!(
        "/* NLopt configuration for this target, written by build.rs. */\n{}\n",
        defines.join("\n")
    )
}
