//! The names the command line, the server and scene descriptions use for the library's choices
//! (query mode, culling, intersector, builder, split axis, backend, output format, shading).
//!
//! The library owns the names; front ends map them (the CLI through a clap value parser in
//! `src/cli/choice.rs`, the server by [`Named::from_name`]), so the core needs no CLI crate.

/// A choice with fixed names: every value, its name and a one-line help.
pub trait Named: Sized + Copy + 'static {
    /// Every value, in the order help lists them.
    const ALL: &'static [Self];
    /// The name users type.
    fn name(self) -> &'static str;
    /// One line of help.
    fn help(self) -> &'static str;
    /// The value named `name` (ASCII case and `_`/`-` ignored), if any.
    fn from_name(name: &str) -> Option<Self> {
        let wanted = name.replace('_', "-");
        Self::ALL
            .iter()
            .copied()
            .find(|v| v.name().eq_ignore_ascii_case(&wanted))
    }
    /// The names, comma-separated, for error messages.
    fn names() -> String {
        Self::ALL
            .iter()
            .map(|v| v.name())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Implements [`Named`], `Display` and `FromStr` for a fieldless enum from a table of
/// `Variant => ("name", "help")`.
macro_rules! named {
    ($ty:ty { $($variant:ident => ($name:literal, $help:literal)),+ $(,)? }) => {
        impl $crate::names::Named for $ty {
            const ALL: &'static [Self] = &[$(<$ty>::$variant),+];
            fn name(self) -> &'static str {
                match self { $(<$ty>::$variant => $name),+ }
            }
            fn help(self) -> &'static str {
                match self { $(<$ty>::$variant => $help),+ }
            }
        }
        impl std::fmt::Display for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str($crate::names::Named::name(*self))
            }
        }
        impl std::str::FromStr for $ty {
            type Err = String;
            fn from_str(s: &str) -> std::result::Result<Self, String> {
                <$ty as $crate::names::Named>::from_name(s).ok_or_else(|| {
                    format!(
                        "unknown value {} (expected one of: {})",
                        $crate::budget::quote(s),
                        <$ty as $crate::names::Named>::names()
                    )
                })
            }
        }
    };
}
pub(crate) use named;
