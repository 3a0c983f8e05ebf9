//! What the file readers say that is not an error (a file that gave no triangle, faces too
//! short for one): written on standard error, as the CLI wants, unless the caller collects them
//! on its thread to say them its own way (the Python package raises each as a `UserWarning`,
//! which a notebook shows where standard error goes to the server's terminal).

use std::cell::RefCell;

thread_local! {
    static COLLECTED: RefCell<Option<Vec<String>>> = const { RefCell::new(None) };
}

/// Says `message` (a sentence naming the file, without "warning: "): collected when this thread
/// is inside [`collect`], else written on standard error after "warning: ".
pub fn warn(message: String) {
    let left = COLLECTED.with(|c| match c.borrow_mut().as_mut() {
        Some(list) => {
            list.push(message);
            None
        }
        None => Some(message),
    });
    if let Some(message) = left {
        // Lost, not a panic, where standard error is closed.
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), "warning: {message}");
    }
}

/// Runs `f` and returns what it returned with the warnings said on this thread meanwhile, in
/// order, instead of writing them. Nested calls each get their own.
pub fn collect<R>(f: impl FnOnce() -> R) -> (R, Vec<String>) {
    // The outer collection (if any), put back on the way out, a panic included.
    struct Restore(Option<Vec<String>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let outer = self.0.take();
            COLLECTED.with(|c| *c.borrow_mut() = outer);
        }
    }
    let restore = Restore(COLLECTED.with(|c| c.replace(Some(Vec::new()))));
    let result = f();
    let said = COLLECTED
        .with(|c| c.borrow_mut().take())
        .unwrap_or_default();
    drop(restore);
    (result, said)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn collected_warnings_come_back_in_order_and_nest() {
        let ((inner, ()), outer) = collect(|| {
            warn("one".into());
            let inner = collect(|| warn("two".into()));
            warn("three".into());
            (inner, ())
        });
        assert_eq!(outer, ["one", "three"]);
        assert_eq!(inner.1, ["two"]);
        // Outside any collection nothing is kept.
        warn("written on standard error".into());
        assert!(COLLECTED.with(|c| c.borrow().is_none()));
    }
}
