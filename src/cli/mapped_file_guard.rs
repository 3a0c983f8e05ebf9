//! What the tool does when a file it has mapped is shortened underneath it: this module owns the
//! SIGBUS handler that turns that into exit code 2 and one sentence, instead of a crash.
//!
//! The tool maps its input files: one-shot commands use a saved scene (`.rpk`) in place, in the
//! file's mapped pages ([`raypick::rpk::load_in_place`]), and the OBJ reader cuts a mapped file
//! into chunks. Should another program shorten such a file while it is read, the next read of a
//! lost page raises SIGBUS; the handler says so and exits. (Nothing else the tool does raises
//! SIGBUS.)

/// The sentence written on SIGBUS.
const MESSAGE: &[u8] = b"error: an input file raypick had mapped (a scene file) was shortened by \
another program while raypick was reading it; run the command again once the file is whole\n";

/// Installs the handler (Unix; elsewhere nothing).
pub fn install() {
    #[cfg(unix)]
    // SAFETY: `on_sigbus` only calls async-signal-safe functions (write, _exit); the action
    // struct is zeroed (no flags, empty mask) before the handler is set.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_sigbus as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::sigemptyset(&mut action.sa_mask);
        libc::sigaction(libc::SIGBUS, &action, std::ptr::null_mut());
    }
}

#[cfg(unix)]
extern "C" fn on_sigbus(_: libc::c_int) {
    // SAFETY: write and _exit are async-signal-safe; MESSAGE is a static byte string.
    unsafe {
        libc::write(2, MESSAGE.as_ptr().cast(), MESSAGE.len());
        libc::_exit(2);
    }
}
