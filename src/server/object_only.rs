//! Request records that must be JSON objects. serde's derived structs take their fields from a
//! JSON array too, in order, so `{"rays": [[[0, 0, 9], [0, 0, -1], 0, null, 1]]}` was a ray: a
//! form the API does not document, whose errors name positions instead of fields. A record
//! read through [`ObjectOnly`] is read from an object alone (its fields by name, unknown ones
//! refused as before); anything else is "expected a JSON object".

use serde::de::value::MapAccessDeserializer;
use serde::de::{Deserialize, Deserializer, MapAccess, Visitor};
use std::fmt;
use std::marker::PhantomData;

/// A `T` read from a JSON object only.
#[derive(Debug)]
pub(crate) struct ObjectOnly<T>(pub(crate) T);

impl<'de, T: Deserialize<'de>> Deserialize<'de> for ObjectOnly<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        /// Takes a map, and hands it to `T`'s own reading.
        struct Object<T>(PhantomData<T>);

        impl<'de, T: Deserialize<'de>> Visitor<'de> for Object<T> {
            type Value = T;

            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a JSON object")
            }

            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<T, A::Error> {
                T::deserialize(MapAccessDeserializer::new(map))
            }
        }

        deserializer
            .deserialize_map(Object(PhantomData))
            .map(ObjectOnly)
    }
}

#[cfg(test)]
mod tests {
    use super::ObjectOnly;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Point {
        x: f64,
        y: Option<f64>,
    }

    #[test]
    fn records_are_read_from_objects_alone() {
        let read = |text: &str| serde_json::from_str::<Vec<ObjectOnly<Point>>>(text);
        let points = read(r#"[{"x": 1}, {"y": 2, "x": 3}]"#).unwrap();
        assert_eq!(points[0].0, Point { x: 1.0, y: None });
        assert_eq!(
            points[1].0,
            Point {
                x: 3.0,
                y: Some(2.0)
            }
        );
        // The derived struct alone takes an array; through ObjectOnly it is refused.
        assert!(serde_json::from_str::<Point>("[1, 2]").is_ok());
        let refused = read("[[1, 2]]").unwrap_err().to_string();
        assert!(refused.contains("expected a JSON object"), "{refused}");
        let unknown = read(r#"[{"x": 1, "z": 0}]"#).unwrap_err().to_string();
        assert!(unknown.contains("unknown field `z`"), "{unknown}");
    }
}
