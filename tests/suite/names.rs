//! The names of the library's choices: every value prints as the name the command line and the
//! server use, parses back (case and `_`/`-` ignored), and an unknown name is refused with the
//! list of names.

use raypick::apps::render::Shade;
use raypick::io::output::Format;
use raypick::names::Named;
use raypick::{Backend, Builder, Cull, Intersector, Mode, SplitAxis};
use std::fmt::Display;
use std::str::FromStr;

fn round_trips<T: Named + Display + FromStr<Err = String> + PartialEq + std::fmt::Debug>(
    expected: &[&str],
) {
    let names: Vec<&str> = T::ALL.iter().map(|v| v.name()).collect();
    assert_eq!(names, expected);
    for &v in T::ALL {
        assert_eq!(v.to_string(), v.name());
        assert_eq!(v.name().parse::<T>().unwrap(), v);
        assert_eq!(
            v.name()
                .to_uppercase()
                .replace('-', "_")
                .parse::<T>()
                .unwrap(),
            v
        );
        assert!(!v.help().is_empty());
    }
    let err = "no-such-choice".parse::<T>().unwrap_err();
    assert!(
        err.contains("no-such-choice") && err.contains(expected[0]),
        "{err}"
    );
}

#[test]
fn every_choice_round_trips_its_names() {
    round_trips::<Mode>(&["closest", "any", "all"]);
    round_trips::<Cull>(&["none", "back", "front"]);
    round_trips::<Intersector>(&["moller-trumbore", "watertight"]);
    round_trips::<Builder>(&["auto", "median-cut", "sah", "grid"]);
    round_trips::<SplitAxis>(&["cycle", "longest"]);
    round_trips::<Backend>(&["auto", "gpu", "cpu", "reference"]);
    round_trips::<Format>(&["csv", "json"]);
    round_trips::<Shade>(&["normal", "depth", "object"]);
}
