//! Reading JSON files so that an error says where and what to do: the field path
//! (`training.poses[0].static[1]`) besides line and column, the kind of file it is when it is not
//! the kind expected, and a hint for the usual ways non-JSON numbers sneak in.

use serde::de::DeserializeOwned;
use serde_json::Value;

/// Parses `text` as a `T` described as `what` ("a measurement set"); the error names the field.
pub(crate) fn parse<T: DeserializeOwned>(text: &str, what: &str) -> Result<T, String> {
    let mut de = serde_json::Deserializer::from_str(text);
    let result = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| (e.path().to_string(), e.into_inner()))
        .and_then(|v: T| de.end().map(|()| v).map_err(|e| (String::new(), e)));
    result.map_err(|(path, inner)| {
        if let Some(other) = other_kind(text, what) {
            return other;
        }
        let message = plain(&inner);
        let place = format!("line {}, column {}", inner.line(), inner.column());
        let hint = hint(text, &inner);
        if path.is_empty() || path == "." {
            format!("{message} at {place}{hint}")
        } else {
            format!("{path}: {message} ({place}){hint}")
        }
    })
}

/// Parses the file `reader` reads as a `T` described as `what`, without holding its text (a
/// minute's motion record is 25 MB of it); on an error, `text` gives the file's text again and
/// [`parse`] words the error from it.
pub(crate) fn parse_reader<T: DeserializeOwned>(
    reader: impl std::io::Read,
    what: &str,
    text: impl FnOnce() -> std::io::Result<String>,
) -> Result<T, String> {
    let mut de = serde_json::Deserializer::from_reader(std::io::BufReader::new(reader));
    let parsed = serde_path_to_error::deserialize(&mut de)
        .map_err(|_| ())
        .and_then(|v: T| de.end().map(|()| v).map_err(|_| ()));
    parsed.or_else(|()| match text() {
        Ok(text) => parse(&text, what),
        Err(e) => Err(format!("not JSON text: {e}")),
    })
}

/// serde_json's message without its trailing " at line L column C".
fn plain(e: &serde_json::Error) -> String {
    let text = e.to_string();
    match text.rfind(" at line ") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

/// What usually causes this error, and the fix.
fn hint(text: &str, e: &serde_json::Error) -> &'static str {
    let at = offset(text, e.line(), e.column());
    let rest = text.get(at.saturating_sub(1)..).unwrap_or("").trim_start();
    let bare = rest.trim_start_matches(['-', '+']);
    if bare.starts_with("NaN")
        || bare.starts_with("nan")
        || bare.starts_with("Infinity")
        || bare.starts_with("inf")
    {
        return ": NaN and infinity are not JSON numbers; remove or re-record that value";
    }
    let message = e.to_string();
    if message.contains("null") {
        return ": a number is missing (most JSON writers write NaN and infinite values as null); remove or re-record that value";
    }
    if message.contains("trailing characters") || message.contains("invalid length") {
        return ": an array has more entries than it may (a reading is [x, y, z])";
    }
    if e.is_eof() {
        return ": the file ends early; was it written whole?";
    }
    ""
}

/// Byte offset of a 1-based line and column.
fn offset(text: &str, line: usize, column: usize) -> usize {
    let start: usize = text
        .split_inclusive('\n')
        .take(line.saturating_sub(1))
        .map(str::len)
        .sum();
    (start + column).min(text.len())
}

/// When the text is a skincal file of another kind than `what`, says which and what to give.
fn other_kind(text: &str, what: &str) -> Option<String> {
    let value: Value = serde_json::from_str(text).ok()?;
    let kind = kind(&value)?;
    (!what.contains(kind.0)).then(|| format!("this is {} ({}), not {what}", kind.0, kind.1))
}

/// The kind of skincal file a JSON value is, and what writes it.
pub(crate) fn kind(value: &Value) -> Option<(&'static str, &'static str)> {
    let format = value.get("format").and_then(Value::as_str);
    Some(match format {
        Some("skincal-measurements") => ("a measurement set", "from skincal simulate or ingest"),
        Some("skincal-model") => ("a calibrated model", "model.json from skincal calibrate"),
        Some("skincal-model-paper") => (
            "a paper-method model",
            "model-paper.json from skincal calibrate --method paper; predict, validate and export-urdf need model.json from --method ml",
        ),
        Some("skincal-truth") => ("a ground truth", "truth.json from skincal simulate"),
        Some("skincal-plan") => ("an exploration plan", "plan.json from skincal plan"),
        _ if value.get("segments").is_some() && value.get("joints").is_some() && value.get("limbs").is_some() => {
            ("a structure", "structure.json from skincal explore")
        }
        _ => return None,
    })
}
