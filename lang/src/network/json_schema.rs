//! The network file's JSON Schema (`pabctl schema`, docs/network-file.schema.json), derived from
//! the raw tables the parser reads a file into.

use schemars::Schema;
use schemars::transform::RecursiveTransform;

use super::RawFile;

/// The network file's JSON Schema (draft 7), for editors that complete and check TOML with one
/// (taplo, Even Better TOML): pretty-printed, with a final newline, as committed in
/// docs/network-file.schema.json and printed by `pabctl schema`.
///
/// It is derived from the raw tables the parser reads the file into, so it takes exactly their
/// keys (an unknown key is refused: `additionalProperties: false`), with their types and their
/// doc comments as descriptions, and the values of `combine`, `endian` and `kind` from the lists
/// the parser checks them against. It checks a file's shape only: names, ranges and everything
/// else [`Network::parse`](super::Network::parse) reports stay the parser's.
pub fn json_schema() -> String {
    let mut settings = schemars::generate::SchemaSettings::draft07();
    // Before the draft-7 transforms, which move a `$ref`'s siblings into an `allOf`.
    settings
        .transforms
        .insert(0, Box::new(RecursiveTransform(for_toml as fn(&mut Schema))));
    let mut schema = settings.into_generator().into_root_schema_for::<RawFile>();
    schema.insert("title".into(), "pab network file".into());
    let mut text = serde_json::to_string_pretty(&schema).expect("a schema is JSON");
    text.push('\n');
    text
}

/// `schema` as a TOML file's, not a Rust type's: without the null that schemars allows for an
/// `Option` (TOML has none: an optional key is one left out), so `"type": ["integer", "null"]`
/// becomes `"type": "integer"` and `"anyOf": [X, {"type": "null"}]` becomes X with the schema's
/// own keys (its description); without `format`s that name Rust's types (`int64`, `double`);
/// with each description's lines, wrapped as a doc comment, joined into one.
fn for_toml(schema: &mut Schema) {
    use serde_json::Value;
    let Some(object) = schema.as_object_mut() else {
        return;
    };
    if let Some(Value::Array(types)) = object.get_mut("type") {
        types.retain(|t| t != "null");
        if let [only] = types.as_slice() {
            let only = only.clone();
            object.insert("type".into(), only);
        }
    }
    let is_null = |value: &Value| value.get("type").is_some_and(|t| t == "null");
    if let Some(Value::Array(options)) = object.get_mut("anyOf") {
        options.retain(|option| !is_null(option));
        if let [Value::Object(only)] = options.as_slice() {
            let only = only.clone();
            object.remove("anyOf");
            for (key, value) in only {
                object.entry(key).or_insert(value);
            }
        }
    }
    object.remove("format");
    if let Some(Value::String(description)) = object.get_mut("description") {
        *description = description.replace('\n', " ");
    }
}
