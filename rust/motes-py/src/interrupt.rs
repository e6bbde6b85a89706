//! Ctrl-C for long native work, two ways.
//!
//! * [`interruptible`] (the API): a table build runs on a scoped thread while the calling thread wakes
//!   every [`SIGNAL_POLL`] to run Python's signal handlers; KeyboardInterrupt stops the core through
//!   [`motes_core::cancel`].
//! * [`exit_on_wakeup`] (the `motes` command): a Mitsuba kernel holds the GIL until it returns, so no
//!   Python code — not even a watcher thread — runs on Ctrl-C until then (seconds per pass). Python's
//!   signal handler also writes the signal number to a wakeup socket; a native thread blocked on that
//!   socket prints the message the command keeps current ([`set_exit_message`]) and ends the process at
//!   once, without the GIL.

use pyo3::prelude::*;
use std::io::{Read, Write};
use std::os::fd::{BorrowedFd, RawFd};
use std::sync::Mutex;

/// How often a long computation looks for Ctrl-C (Python's pending signal handlers).
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Run a long computation (a table build) with the GIL released and stop it on Ctrl-C within about
/// [`SIGNAL_POLL`] plus one item of work: it runs on a scoped thread while this (the calling) thread
/// wakes every `SIGNAL_POLL` to run Python's signal handlers. When one raises (KeyboardInterrupt), the
/// core is asked to stop ([`motes_core::cancel`]), its unspecified result is discarded and the
/// exception propagates. A computation stopped by another thread's Ctrl-C raises KeyboardInterrupt too.
pub(crate) fn interruptible<T: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    use std::sync::mpsc::{channel, RecvTimeoutError};
    let run = motes_core::cancel::Run::begin();
    let (tx, mut rx) = channel();
    std::thread::scope(|scope| {
        let worker = scope.spawn(move || {
            let _ = tx.send(work());
        });
        loop {
            // The receiver travels into the GIL-free wait and back (it is Send, not Sync).
            let (back, received) = py.detach(move || {
                let r = rx.recv_timeout(SIGNAL_POLL);
                (rx, r)
            });
            rx = back;
            match received {
                Ok(value) => {
                    let _ = worker.join();
                    if run.cancelled() {
                        return Err(pyo3::exceptions::PyKeyboardInterrupt::new_err(
                            "computation stopped (Ctrl-C)",
                        ));
                    }
                    return Ok(value);
                }
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals() {
                        motes_core::cancel::request();
                        let _ = py.detach(|| worker.join());
                        return Err(e);
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    // The worker panicked: re-raise its panic here, as pyo3 does for the calling thread.
                    match worker.join() {
                        Err(panic) => std::panic::resume_unwind(panic),
                        Ok(()) => unreachable!("the worker sends before it ends"),
                    }
                }
            }
        }
    })
}

/// What the command prints when it ends on Ctrl-C (kept current by the command, e.g. after each pass).
static EXIT_MESSAGE: Mutex<String> = Mutex::new(String::new());

/// Set the line printed (to stderr) when [`exit_on_wakeup`]'s thread ends the process.
#[pyfunction]
pub(crate) fn set_exit_message(message: String) {
    *EXIT_MESSAGE.lock().unwrap_or_else(|e| e.into_inner()) = message;
}

/// Start a native thread that reads `fd` (the read end of the socket given to `signal.set_wakeup_fd`)
/// and, when the byte `signum` arrives, prints the exit message and ends the process with `status`
/// (`_exit`: no clean-up, which could wait on the kernel in flight). The thread reads its own duplicate
/// of `fd` and ends quietly when the other end is closed.
#[pyfunction]
pub(crate) fn exit_on_wakeup(fd: RawFd, signum: u8, status: i32) -> PyResult<()> {
    if fd < 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "invalid fd = {fd}: must be an open file descriptor"
        )));
    }
    // SAFETY: the caller passes an open descriptor and keeps it open for the duration of this call;
    // the duplicate made here is owned by the thread from then on.
    let owned = unsafe { BorrowedFd::borrow_raw(fd) }.try_clone_to_owned()?;
    std::thread::Builder::new()
        .name("motes-ctrl-c".into())
        .spawn(move || {
            let mut socket = std::fs::File::from(owned);
            let mut buf = [0u8; 64];
            loop {
                match socket.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) if buf[..n].contains(&signum) => {
                        let message = EXIT_MESSAGE
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .clone();
                        let mut err = std::io::stderr().lock();
                        let _ = writeln!(err, "\n{message}");
                        let _ = err.flush();
                        // SAFETY: _exit ends the process immediately; nothing is touched afterwards.
                        unsafe { libc::_exit(status) };
                    }
                    Ok(_) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(_) => return,
                }
            }
        })?;
    Ok(())
}
