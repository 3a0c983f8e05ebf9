//! The clap value parser for the library's named choices ([`raypick::names::Named`]): the
//! library owns the names and help lines, the command line only maps them.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use raypick::names::Named;

/// Parses one of `T`'s names; `--help` lists them with their help lines.
pub fn choice<T: Named + Send + Sync + Clone>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(
        T::ALL
            .iter()
            .map(|v| PossibleValue::new(v.name()).help(v.help())),
    )
    .map(|name| T::from_name(&name).expect("clap only passes listed names"))
}
