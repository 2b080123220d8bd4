//! Project tasks, run as `cargo xtask <task>` (an alias in `.cargo/config.toml`).
//!
//! `cargo xtask test [ARGS…]` makes sure everything the tests need is there (while the tests
//! are built: `cargo test --no-run`), then runs `cargo test --workspace --release [ARGS…]`
//! (optimised: the integration tests take three
//! quarters of the time they take at the debug build's light optimisation, and the Python
//! package's tests then use much of the same release build):
//! - the Python packages of `tests/python/requirements.txt` (pinned), in a virtual environment at
//!   `target/test-env` that is made once and updated only when the requirements change, so the
//!   second run costs nothing; the tests find it through `SKINCAL_TEST_PYTHON`;
//! - real robots' descriptions: the one wheel of `tests/python/robot-descriptions.txt` (pinned,
//!   hash checked), downloaded once with the environment's pip and its URDF and SRDF files and collision meshes unpacked into
//!   `target/robot-descriptions`; the tests find them through `SKINCAL_ROBOT_DESCRIPTIONS`;
//! - system packages (Debian's `python3` and `python3-venv` when the environment cannot be made
//!   without them; `chromium`, in which the HTML report is rendered headless), installed with
//!   apt-get only when running as root and only when missing; as another user the task stops and
//!   prints the command that installs them. The tests find the browser through
//!   `SKINCAL_TEST_CHROMIUM`.
//!
//! After the Rust tests, a full run (no ARGS) tests the Python package: the package is installed
//! into the same environment (`pip install ./crates/skincal-py`, built by maturin from the same
//! target directory), and `pytest crates/skincal-py/tests` and `examples/paper_arm.py` run against
//! the release `skincal` command the Rust tests built.
//!
//! Nothing is skipped silently: what cannot be installed ends the task with the command that fixes it.
//! `cargo xtask test-env` does the installation alone and prints the environment's Python.

use std::env;
use std::ffi::OsString;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

const USAGE: &str = "\
usage: cargo xtask <task>

tasks:
  test [ARGS...]   install what the tests need (once), then cargo test --workspace --release [ARGS...];
                   without ARGS also the Python package's tests and example
  test-env         only install what the tests need (the Python environment and the robot
                   descriptions in target/); prints the test environment's Python";

fn main() -> ExitCode {
    let mut args = env::args_os().skip(1);
    let task = args.next();
    let rest: Vec<OsString> = args.collect();
    let result = match task.as_ref().and_then(|t| t.to_str()) {
        Some("test") => test(&rest),
        Some("test-env") => test_env().and_then(|python| {
            robot_descriptions(&python)?;
            println!("{}", python.display());
            Ok(ExitCode::SUCCESS)
        }),
        Some("-h" | "--help" | "help") => {
            println!("{USAGE}");
            Ok(ExitCode::SUCCESS)
        }
        _ => {
            eprintln!("{USAGE}");
            Ok(ExitCode::from(2))
        }
    };
    result.unwrap_or_else(|message| {
        eprintln!("xtask: {message}");
        ExitCode::FAILURE
    })
}

/// The workspace root (the parent of this crate's directory).
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask lives in the workspace")
        .to_path_buf()
}

/// Cargo's target directory, as cargo itself chooses it.
fn target_dir(root: &Path) -> PathBuf {
    env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .map(|dir| {
            if dir.is_absolute() {
                dir
            } else {
                root.join(dir)
            }
        })
        .unwrap_or_else(|| root.join("target"))
}

/// `cargo xtask test [ARGS…]`: the tests are built while what they need is installed (the
/// installation waits on the network, the build on the processor), then run; without ARGS the
/// Python package is tested after them.
fn test(args: &[OsString]) -> Result<ExitCode, String> {
    let mut build = start_build(args)?;
    let needs = test_env().and_then(|python| {
        let robots = robot_descriptions(&python)?;
        let browser = chromium()?;
        Ok((python, robots, browser))
    });
    let (python, robots, browser) = match needs {
        Ok(needs) => needs,
        Err(message) => {
            let _ = build.kill();
            let _ = build.wait();
            return Err(message);
        }
    };
    let built = build
        .wait()
        .map_err(|e| format!("could not wait for cargo test --no-run: {e}"))?;
    if !built.success() {
        return Err("the tests did not build (cargo's errors above)".into());
    }
    let code = run_tests(&python, &robots, &browser, args)?;
    if code != ExitCode::SUCCESS || !args.is_empty() {
        return Ok(code);
    }
    python_package(&python)
}

/// The cargo that runs this task.
fn cargo() -> OsString {
    env::var_os("CARGO").unwrap_or_else(|| "cargo".into())
}

/// Starts `cargo test --workspace --release --no-run` with the cargo options of `args` (those
/// before a `--`; what follows is the test binaries').
fn start_build(args: &[OsString]) -> Result<std::process::Child, String> {
    let options = args.iter().take_while(|a| *a != "--");
    Command::new(cargo())
        .args(["test", "--workspace", "--release", "--no-run"])
        .args(options)
        .current_dir(workspace_root())
        .spawn()
        .map_err(|e| format!("could not run cargo test --no-run: {e}"))
}

/// Runs every test with the test environment's Python and the robot descriptions.
fn run_tests(
    python: &Path,
    robots: &Path,
    browser: &Path,
    args: &[OsString],
) -> Result<ExitCode, String> {
    let status = Command::new(cargo())
        .args(["test", "--workspace", "--release"])
        .args(args)
        .current_dir(workspace_root())
        .env("SKINCAL_TEST_PYTHON", python)
        .env("SKINCAL_ROBOT_DESCRIPTIONS", robots)
        .env("SKINCAL_TEST_CHROMIUM", browser)
        .status()
        .map_err(|e| format!("could not run cargo test: {e}"))?;
    Ok(match status.code() {
        Some(0) => ExitCode::SUCCESS,
        Some(code) => ExitCode::from(u8::try_from(code).unwrap_or(1)),
        None => ExitCode::FAILURE,
    })
}

/// Runs `program` with `args` in the workspace root; an error names the command and its fix.
fn step(program: &Path, args: &[&str], envs: &[(&str, &Path)], fix: &str) -> Result<(), String> {
    let shown = format!("{} {}", program.display(), args.join(" "));
    say(&shown);
    let status = Command::new(program)
        .args(args)
        .envs(envs.iter().copied())
        .current_dir(workspace_root())
        .status()
        .map_err(|e| format!("could not run {shown}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{shown} failed; {fix}"))
    }
}

/// The Python package: installed into the test environment, then its tests and example, which
/// compare it with the release command the Rust tests built (`cli`'s integration tests need it, so
/// `cargo test --workspace --release` leaves it in the target directory).
fn python_package(python: &Path) -> Result<ExitCode, String> {
    let binary = target_dir(&workspace_root()).join("release/skincal");
    if !binary.exists() {
        return Err(format!(
            "{} is missing after the tests: build it with cargo build --release",
            binary.display()
        ));
    }
    step(
        python,
        &[
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "./crates/skincal-py",
        ],
        &[],
        "pip builds the package with maturin from PyPI (is PyPI reachable?)",
    )?;
    let envs = [("SKINCAL_BIN", binary.as_path())];
    step(
        python,
        &["-m", "pytest", "-q", "crates/skincal-py/tests"],
        &envs,
        "a Python package test failed (above)",
    )?;
    step(
        python,
        &["examples/paper_arm.py"],
        &envs,
        "the example failed (above)",
    )?;
    Ok(ExitCode::SUCCESS)
}

/// Debian's Chromium, installed when missing; returns the browser.
fn chromium() -> Result<PathBuf, String> {
    let browser = PathBuf::from("/usr/bin/chromium");
    if !browser.exists() {
        install_system_packages(&["chromium"], "the HTML report is rendered in it headless")?;
    }
    Ok(browser)
}

/// Makes (or reuses) the Python environment of the tests and returns its interpreter.
fn test_env() -> Result<PathBuf, String> {
    let root = workspace_root();
    let requirements_file = root.join("tests/python/requirements.txt");
    let requirements = fs::read_to_string(&requirements_file)
        .map_err(|e| format!("{}: {e}", requirements_file.display()))?;
    let dir = target_dir(&root).join("test-env");
    let python = venv_python(&dir);
    let stamp = dir.join("skincal-requirements.txt");
    if python.exists() && fs::read_to_string(&stamp).is_ok_and(|s| s == requirements) {
        return Ok(python);
    }
    if !python.exists() {
        make_venv(&dir)?;
    }
    say(&format!(
        "installing the tests' Python packages ({}) into {}",
        pinned(&requirements).join(", "),
        dir.display()
    ));
    let pip = Command::new(&python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
        ])
        .arg("--requirement")
        .arg(&requirements_file)
        .status()
        .map_err(|e| format!("could not run {}: {e}", python.display()))?;
    if !pip.success() {
        return Err(format!(
            "pip could not install {} into {} (is PyPI reachable?); retry with \
             `{} -m pip install -r {}`",
            requirements_file.display(),
            dir.display(),
            python.display(),
            requirements_file.display()
        ));
    }
    fs::write(&stamp, &requirements).map_err(|e| format!("{}: {e}", stamp.display()))?;
    Ok(python)
}

/// Downloads (once) the wheel of `tests/python/robot-descriptions.txt` with the test
/// environment's pip, hash checked, and unpacks its URDF and SRDF files and collision meshes;
/// returns the directory.
fn robot_descriptions(python: &Path) -> Result<PathBuf, String> {
    let root = workspace_root();
    let list_file = root.join("tests/python/robot-descriptions.txt");
    let list =
        fs::read_to_string(&list_file).map_err(|e| format!("{}: {e}", list_file.display()))?;
    let dir = target_dir(&root).join("robot-descriptions");
    let stamp = dir.join("skincal-robot-descriptions.txt");
    // What is unpacked: a new layout unpacks again.
    let stamp_text = format!("{list}# unpacked: URDF, SRDF and collision meshes\n");
    if fs::read_to_string(&stamp).is_ok_and(|s| s == stamp_text) {
        return Ok(dir);
    }
    let wheels = target_dir(&root).join("robot-description-wheels");
    say(&format!(
        "downloading the robot descriptions ({}) into {}",
        pinned(&list)
            .iter()
            .map(|l| l.split_whitespace().next().unwrap_or(l))
            .collect::<Vec<_>>()
            .join(", "),
        dir.display()
    ));
    let download = Command::new(python)
        .args([
            "-m",
            "pip",
            "download",
            "--quiet",
            "--disable-pip-version-check",
            "--no-deps",
            "--only-binary=:all:",
            "--require-hashes",
        ])
        .arg("--requirement")
        .arg(&list_file)
        .arg("--dest")
        .arg(&wheels)
        .status()
        .map_err(|e| format!("could not run {}: {e}", python.display()))?;
    if !download.success() {
        return Err(format!(
            "pip could not download {} (is PyPI reachable?); retry with `{} -m pip download \
             --no-deps --require-hashes -r {} -d {}`",
            list_file.display(),
            python.display(),
            list_file.display(),
            wheels.display()
        ));
    }
    // The URDF and SRDF files, and the meshes the URDFs' <collision> elements name (the wheels
    // carry visual meshes the tests do not need), by the wheel's paths under its robots/ folder.
    let unpack = r#"
import pathlib, re, sys, zipfile
wheels, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
count = 0
for wheel in sorted(wheels.glob("*.whl")):
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        by_suffix = {n.split("/robots/", 1)[1]: n for n in names if "/robots/" in n}
        wanted = set()
        for name in names:
            if name.endswith((".urdf", ".srdf")) and "/robots/" in name:
                wanted.add(name.split("/robots/", 1)[1])
                if name.endswith(".urdf"):
                    text = z.read(name).decode("utf-8", "replace")
                    for element in re.findall(r"<collision.*?</collision>", text, re.S):
                        for f in re.findall(r'filename="package://[^/]+/robots/([^"]+)"', element):
                            if f in by_suffix:
                                wanted.add(f)
        for suffix in sorted(wanted):
            target = out / suffix
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(z.read(by_suffix[suffix]))
            count += suffix.endswith(".urdf")
if count == 0:
    sys.exit("no URDF file in " + str(wheels))
"#;
    let _ = fs::remove_dir_all(&dir);
    let unpacked = Command::new(python)
        .args(["-c", unpack])
        .arg(&wheels)
        .arg(&dir)
        .status()
        .map_err(|e| format!("could not run {}: {e}", python.display()))?;
    if !unpacked.success() {
        return Err(format!(
            "could not unpack the robot descriptions of {} into {} (see above)",
            wheels.display(),
            dir.display()
        ));
    }
    fs::write(&stamp, &stamp_text).map_err(|e| format!("{}: {e}", stamp.display()))?;
    Ok(dir)
}

/// The pinned `name==version` lines of a requirements file.
fn pinned(requirements: &str) -> Vec<&str> {
    requirements
        .lines()
        .map(|line| line.split('#').next().unwrap_or("").trim())
        .filter(|line| !line.is_empty())
        .collect()
}

/// The interpreter inside a virtual environment.
fn venv_python(dir: &Path) -> PathBuf {
    if cfg!(windows) {
        dir.join("Scripts").join("python.exe")
    } else {
        dir.join("bin").join("python")
    }
}

/// Creates the virtual environment, installing Debian's `python3`/`python3-venv` if they are what
/// is missing (as root), or saying how to.
fn make_venv(dir: &Path) -> Result<(), String> {
    let base = if succeeds("python3", &["--version"]) {
        "python3"
    } else {
        install_system_packages(
            &["python3", "python3-venv"],
            "Python 3 runs the interop tests",
        )?;
        "python3"
    };
    say(&format!("making the test environment {}", dir.display()));
    let venv = |quiet: bool| {
        let mut command = Command::new(base);
        command.arg("-m").arg("venv").arg("--clear").arg(dir);
        if quiet {
            command.stderr(std::process::Stdio::null());
        }
        command.status().is_ok_and(|s| s.success())
    };
    if venv(true) {
        return Ok(());
    }
    // Debian and Ubuntu ship `venv`'s pip bootstrap in a package of its own.
    install_system_packages(&["python3-venv"], "`python3 -m venv` needs it")?;
    if venv(false) {
        Ok(())
    } else {
        Err(format!(
            "`{base} -m venv {}` failed (see above); install Python's venv module and retry",
            dir.display()
        ))
    }
}

/// Installs Debian packages with apt-get when running as root; otherwise fails with the command.
fn install_system_packages(packages: &[&str], why: &str) -> Result<(), String> {
    let command = format!("apt-get install -y {}", packages.join(" "));
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|out| String::from_utf8_lossy(&out.stdout).trim() == "0");
    if !root || !succeeds("apt-get", &["--version"]) {
        return Err(format!(
            "the tests need {} ({why}); install it, e.g. `sudo {command}`, and run again",
            packages.join(" ")
        ));
    }
    say(&format!(
        "installing {} ({why}): {command}",
        packages.join(" ")
    ));
    let apt = |args: &[&str]| {
        Command::new("apt-get")
            .args(args)
            .env("DEBIAN_FRONTEND", "noninteractive")
            .status()
            .is_ok_and(|s| s.success())
    };
    let installed =
        apt(&["update", "-qq"]) && apt(&[&["install", "-y", "-qq"][..], packages].concat());
    if installed {
        Ok(())
    } else {
        Err(format!("`{command}` failed (see above)"))
    }
}

/// Whether a program runs and exits 0.
fn succeeds(program: &str, args: &[&str]) -> bool {
    Command::new(program)
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn say(message: &str) {
    eprintln!("xtask: {message}");
}
