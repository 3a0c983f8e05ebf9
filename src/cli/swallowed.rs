//! Owns one parse error's wording: an option taken as another option's value.
//!
//! Options whose values may start with a hyphen (`--observer -12 5 3`, `--tmin -inf`,
//! `--epsilon -1e-9`, checked later) take the next words as their values whatever they are, so
//! `--observer 1 2 --targets t.txt` gives `--observer` the values `1 2 --targets` and clap
//! then complains about `t.txt`, a word the user typed correctly. When parsing fails, this
//! looks for such an option followed, within its values, by a word that is an option of the
//! command, and says that instead.

use clap::Command;
use std::ffi::OsString;

/// The sentence for `args` (the whole command line, program name first) when an option of
/// `command` that allows hyphen values took another option as one of its values; `None` when
/// no option did.
pub fn option_taken_as_value(command: &Command, args: &[OsString]) -> Option<String> {
    let words: Vec<&str> = args
        .iter()
        .skip(1)
        .map(|a| a.to_str().unwrap_or(""))
        .collect();
    // The subcommand is the first word naming one (global options come before it too).
    let (at, sub) = words.iter().enumerate().find_map(|(i, w)| {
        command
            .get_subcommands()
            .find(|s| s.get_name() == *w)
            .map(|s| (i, s))
    })?;
    let is_option = |w: &str| {
        w.strip_prefix("--").is_some_and(|name| {
            let name = name.split('=').next().unwrap_or(name);
            sub.get_arguments().any(|a| a.get_long() == Some(name))
                || command.get_arguments().any(|a| a.get_long() == Some(name))
        })
    };
    let mut i = at + 1;
    while i < words.len() {
        let word = words[i];
        if word == "--" {
            return None;
        }
        let taker = word.strip_prefix("--").and_then(|name| {
            sub.get_arguments()
                .find(|a| a.get_long() == Some(name) && a.is_allow_hyphen_values_set())
        });
        if let Some(arg) = taker {
            let count = arg.get_num_args().map_or(1, |r| r.min_values()).max(1);
            let values = &words[i + 1..(i + 1 + count).min(words.len())];
            if let Some(k) = values.iter().position(|v| is_option(v)) {
                let names = arg
                    .get_value_names()
                    .map(|n| n.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(" "))
                    .unwrap_or_else(|| "VALUE".to_string());
                let wanted = if count == 1 {
                    format!("a value ({names})")
                } else {
                    format!("{count} values ({names})")
                };
                let given = match k {
                    0 => "none comes".to_string(),
                    1 => "only 1 comes".to_string(),
                    k => format!("only {k} come"),
                };
                // `--targets=…` may carry a long value: quoted short.
                return Some(format!(
                    "{word} takes {wanted} but {given} before {}",
                    raypick::budget::quote(values[k])
                ));
            }
            i += 1 + count;
        } else {
            i += 1;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Arg, ArgAction};

    fn command() -> Command {
        Command::new("raypick")
            .arg(Arg::new("quiet").long("quiet").action(ArgAction::SetTrue))
            .subcommand(
                Command::new("viewshed")
                    .arg(
                        Arg::new("observer")
                            .long("observer")
                            .num_args(3)
                            .value_names(["X", "Y", "Z"])
                            .allow_hyphen_values(true),
                    )
                    .arg(Arg::new("targets").long("targets"))
                    .arg(
                        Arg::new("epsilon")
                            .long("epsilon")
                            .allow_hyphen_values(true),
                    ),
            )
    }

    fn words(line: &str) -> Vec<OsString> {
        line.split(' ').map(OsString::from).collect()
    }

    #[test]
    fn an_option_among_the_values_is_named() {
        let said = option_taken_as_value(
            &command(),
            &words("raypick --quiet viewshed --observer 1 2 --targets t.txt"),
        );
        assert_eq!(
            said.as_deref(),
            Some("--observer takes 3 values (X Y Z) but only 2 come before --targets")
        );
        let said =
            option_taken_as_value(&command(), &words("raypick viewshed --epsilon --targets t"));
        assert_eq!(
            said.as_deref(),
            Some("--epsilon takes a value (VALUE) but none comes before --targets")
        );
    }

    #[test]
    fn a_long_option_word_is_quoted_short() {
        let line = format!(
            "raypick viewshed --observer 1 --targets={}",
            "t".repeat(100_000)
        );
        let said = option_taken_as_value(&command(), &words(&line)).unwrap();
        assert!(
            said.starts_with(
                "--observer takes 3 values (X Y Z) but only 1 comes before --targets="
            )
        );
        assert!(said.len() < 200, "{} bytes", said.len());
    }

    #[test]
    fn negative_numbers_and_unknown_words_are_left_to_the_parser() {
        for line in [
            "raypick viewshed --observer -1 -2e-3 -inf --targets t",
            "raypick viewshed --observer 1 2 --bogus",
            "raypick viewshed --targets t",
            "raypick viewshed -- --observer 1 --targets",
        ] {
            assert_eq!(
                option_taken_as_value(&command(), &words(line)),
                None,
                "{line}"
            );
        }
    }
}
