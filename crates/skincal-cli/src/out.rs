//! Standard output that a closed pipe cannot break.
//!
//! `skincal calibrate DIR | head -1` must still write `DIR/model.json`: once the reader has gone,
//! further output is dropped and the command carries on and ends normally. Any other failure to
//! write standard output (a full disk behind a redirection) is reported once on standard error.

use std::fmt;
use std::io::{self, IsTerminal, Write};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::sync::atomic::{AtomicBool, Ordering};

/// Set once standard output can no longer be written.
static CLOSED: AtomicBool = AtomicBool::new(false);

/// Set by `--json`: standard output carries one JSON document and no text.
static JSON: AtomicBool = AtomicBool::new(false);

/// Makes standard output machine-readable: the text of `out!` and `outln!` is left out, and
/// [`json`] writes the command's one JSON document.
pub fn json_mode() {
    JSON.store(true, Ordering::Relaxed);
}

/// Writes `value` as the command's JSON document (pretty, one trailing newline), in JSON mode only.
pub fn json(value: &serde_json::Value) {
    if JSON.load(Ordering::Relaxed) {
        let text = serde_json::to_string_pretty(value).unwrap_or_default();
        emit(format_args!("{text}\n"));
    }
}

/// Writes to standard output unless it has been closed or carries JSON; what `out!` and `outln!`
/// call.
pub fn write(args: fmt::Arguments<'_>) {
    if !JSON.load(Ordering::Relaxed) {
        emit(args);
    }
}

fn emit(args: fmt::Arguments<'_>) {
    if CLOSED.load(Ordering::Relaxed) {
        return;
    }
    let mut stdout = io::stdout().lock();
    if let Err(e) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        CLOSED.store(true, Ordering::Relaxed);
        if e.kind() != io::ErrorKind::BrokenPipe {
            eprintln!("warning: cannot write standard output ({e}); carrying on without it");
        }
    }
}

/// `print!` that survives a closed standard output.
macro_rules! out {
    ($($arg:tt)*) => { $crate::out::write(format_args!($($arg)*)) };
}

/// `println!` that survives a closed standard output.
macro_rules! outln {
    () => { $crate::out::write(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::out::write(format_args!("{}\n", format_args!($($arg)*))) };
}

pub(crate) use {out, outln};

/// A progress bar on stderr, hidden when stderr is not a terminal.
pub(crate) fn progress_bar(total: u64, what: &str) -> ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr())
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{msg:40} [{bar:30}] {percent:>3}% {elapsed} (eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// A spinner on stderr with the elapsed time, for work of unknown length; hidden when stderr is
/// not a terminal. `finish_and_clear` it when the work is done.
pub(crate) fn spinner(what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}
