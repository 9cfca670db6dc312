//! Blender's noise on stderr: the CUDA-wrangler warning when Cycles starts (this build renders
//! on the CPU) and the memory-leak report at process exit (an embedded interpreter is never
//! finalized, so Blender's memory is never freed).
//!
//! The filter is a `grep -v` child process per stream, not a buffer in this process: if Blender
//! crashes while its output is filtered, the pipe's write end closes with the process and grep
//! still passes on everything written before the crash (an in-memory capture died with it).
//! Only when the binary asks ([`quiet_blender_output`]): the library does not touch the
//! process's streams on its own.
use std::ffi::c_int;
use std::io::Write;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

unsafe extern "C" {
    fn atexit(f: extern "C" fn()) -> c_int;
    fn dup(fd: c_int) -> c_int;
    fn dup2(old: c_int, new: c_int) -> c_int;
}

const STDOUT: c_int = 1;
const STDERR: c_int = 2;

/// The lines dropped: Cycles probing for CUDA (it logs this to stdout).
const NOISE: &str = "CUEW initialization failed";

extern "C" fn silence_at_exit() {
    let _ = std::io::stdout().flush();
    let _ = std::io::stderr().flush();
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        unsafe {
            dup2(null.as_raw_fd(), STDOUT);
            dup2(null.as_raw_fd(), STDERR);
        }
    }
}

/// Blender's session temp folder (`bpy.app.tempdir`), removed at exit.
static BLENDER_TEMPDIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();

/// Blender makes a `blender_XXXXXX` folder in the temp folder at start-up and removes it in its
/// Python exit handler, which an embedded interpreter that is never finalized does not run: every
/// process that rendered left one behind (1186 in /tmp here after some weeks of tests).
extern "C" fn remove_blender_tempdir() {
    if let Some(dir) = BLENDER_TEMPDIR.get() {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// Whether the process asked for Blender's noise to be filtered ([`quiet_blender_output`]): the
/// library leaves the process's streams alone unless its binary asks.
static QUIET: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Asks that Blender's known noise be filtered from this process's stdout and stderr while a
/// renderer starts and first renders, and that the process's output be silenced at exit (after
/// Rust's streams are flushed), before Blender's memory-leak report. A choice for a binary to
/// make: it redirects the whole process's streams, so a library never makes it for its caller.
pub fn quiet_blender_output() {
    QUIET.store(true, std::sync::atomic::Ordering::SeqCst);
}

fn quiet() -> bool {
    QUIET.load(std::sync::atomic::Ordering::SeqCst)
}

/// Registers the exit hooks: Blender's temp folder `blender_tempdir` is removed (only a
/// `blender_*` folder, so a misread path cannot remove anything else), and with
/// [`quiet_blender_output`] the output silenced.
/// C atexit hooks run in reverse order of registration, so once bpy is imported these run before
/// Blender's leak report (and C++ static destructors).
pub fn at_exit(blender_tempdir: &std::path::Path) {
    let is_session_folder = blender_tempdir
        .file_name()
        .and_then(|name| name.to_str())
        .is_some_and(|name| name.starts_with("blender_"));
    unsafe {
        if is_session_folder && BLENDER_TEMPDIR.set(blender_tempdir.to_path_buf()).is_ok() {
            atexit(remove_blender_tempdir);
        }
        if quiet() {
            atexit(silence_at_exit);
        }
    }
}

/// One redirected stream: `fd` writes into a `grep -v` child that writes to the saved original.
struct Filter {
    fd: c_int,
    saved: OwnedFd,
    grep: Child,
}

impl Filter {
    /// Redirects `fd` through a new filter; None (the stream left as it is) if grep cannot run.
    fn start(fd: c_int) -> Option<Self> {
        let saved = unsafe { dup(fd) };
        if saved < 0 {
            return None;
        }
        let saved = unsafe { OwnedFd::from_raw_fd(saved) };
        let mut grep = Command::new("grep")
            .args(["-v", "-a", "-F", "--line-buffered", "-e", NOISE])
            .stdin(Stdio::piped())
            .stdout(Stdio::from(saved.try_clone().ok()?))
            .stderr(Stdio::null())
            .spawn()
            .ok()?;
        let pipe = grep.stdin.take()?;
        if unsafe { dup2(pipe.as_raw_fd(), fd) } < 0 {
            return None;
        }
        // `fd` is now the only write end of the pipe in this process (the original is closed
        // here), so restoring `fd` gives grep its end of input.
        drop(pipe);
        Some(Self { fd, saved, grep })
    }
}

impl Drop for Filter {
    fn drop(&mut self) {
        unsafe { dup2(self.saved.as_raw_fd(), self.fd) };
        // Wait for grep to pass on the rest, so that output keeps its order; a process started
        // meanwhile that still holds the pipe would keep grep alive, so the wait is bounded.
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            match self.grep.try_wait() {
                Ok(None) => std::thread::sleep(Duration::from_millis(1)),
                _ => return,
            }
        }
    }
}

/// Runs `f` with stdout and stderr passed through the noise filter when the binary asked for it
/// ([`quiet_blender_output`]; else `f` alone). The streams are restored however `f` ends (a panic
/// included), and a crash inside `f` loses nothing written before it.
pub fn filter_output<T>(f: impl FnOnce() -> T) -> T {
    if !quiet() {
        return f();
    }
    let _ = std::io::stdout().flush();
    let _ = std::io::stderr().flush();
    let filters: Vec<Filter> = [STDOUT, STDERR]
        .into_iter()
        .filter_map(Filter::start)
        .collect();
    let _restore = FlushThenRestore(filters);
    f()
}

/// Flushes Rust's buffered streams into the filters before they are removed (in reverse order).
struct FlushThenRestore(Vec<Filter>);

impl Drop for FlushThenRestore {
    fn drop(&mut self) {
        let _ = std::io::stdout().flush();
        let _ = std::io::stderr().flush();
        while let Some(filter) = self.0.pop() {
            drop(filter);
        }
    }
}
