//! Ctrl-C ends boxpose at once, whatever it is doing.
//!
//! Every long command can be killed at any moment and resumed (batches, shards and checkpoints
//! are published atomically), so an interrupt needs no clean-up: the process ends with status 130,
//! as SIGINT's default action would end it, after one line on stderr. The default action alone
//! does not survive the embedded Python: CPython's `signal` module, which pyarrow imports,
//! replaces a default SIGINT disposition with its own handler, whose KeyboardInterrupt Blender's
//! render engine catches and prints, so a search went on to its last sample. CPython leaves a
//! handler that is not the default alone. A SIGINT that the process inherited as ignored (a job
//! started with `&` by a non-interactive shell, `nohup`) stays ignored.

/// Status of a process ended by SIGINT, as a shell reports it (128 + 2).
const INTERRUPTED_STATUS: libc::c_int = 130;

extern "C" fn end_interrupted(_signal: libc::c_int) {
    const MESSAGE: &[u8] =
        b"\ninterrupted: a long job (scenes, training, search) resumes when the same command runs again\n";
    // SAFETY: write(2) and _exit(2) are async-signal-safe.
    unsafe {
        libc::write(2, MESSAGE.as_ptr().cast(), MESSAGE.len());
        libc::_exit(INTERRUPTED_STATUS);
    }
}

/// Makes SIGINT end the process (see the module), unless it is ignored.
pub fn end_on_interrupt() {
    // SAFETY: sigaction with a zeroed, then filled struct; the handler only calls
    // async-signal-safe functions.
    unsafe {
        let mut current: libc::sigaction = std::mem::zeroed();
        if libc::sigaction(libc::SIGINT, std::ptr::null(), &mut current) != 0
            || current.sa_sigaction == libc::SIG_IGN
        {
            return;
        }
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = end_interrupted as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::sigemptyset(&mut action.sa_mask);
        libc::sigaction(libc::SIGINT, &action, std::ptr::null_mut());
    }
}
