//! Leaf-by-leaf differences of two JSON documents (run settings, run identities): what
//! `cgenreg diff`, the inspector's Compare tab and a resumed run's identity check print.

use serde_json::Value;

/// Leaf-by-leaf differences of two JSON values, `labels` naming the two sides:
/// "params.voxel: 0.05 here, 0.1 there". Long arrays (the selected pairs) are summarised, an
/// object against null (a branch on in one run, off in the other) is listed leaf by leaf, and
/// long values are cut.
pub fn json_diff(path: &str, a: &Value, b: &Value, labels: (&str, &str), out: &mut Vec<String>) {
    let mut both = Vec::new();
    json_diff_settings(path, a, b, labels, None, &mut both);
    out.extend(both.into_iter().map(|(_, line)| line));
}

/// Longest rendering of one value in a difference line (characters).
const MAX_VALUE_CHARS: usize = 60;

fn short_value(v: &Value) -> String {
    let s = v.to_string();
    if s.chars().count() <= MAX_VALUE_CHARS {
        s
    } else {
        let cut: String = s.chars().take(MAX_VALUE_CHARS - 1).collect();
        format!("{cut}…")
    }
}

/// An object's entries; null counts as an object without entries.
fn as_map<'a>(
    v: &'a Value,
    empty: &'a serde_json::Map<String, Value>,
) -> Option<&'a serde_json::Map<String, Value>> {
    match v {
        Value::Object(m) => Some(m),
        Value::Null => Some(empty),
        _ => None,
    }
}

/// [`json_diff`] with each line's setting: the leaf path, or the path of the object that is
/// null (absent) on one side, so "image on in B only" is one setting however many leaves it
/// has.
pub(crate) fn json_diff_settings(
    path: &str,
    a: &Value,
    b: &Value,
    labels: (&str, &str),
    setting: Option<&str>,
    out: &mut Vec<(String, String)>,
) {
    let (la, lb) = labels;
    if a == b {
        return;
    }
    let name = if path.is_empty() { "(root)" } else { path };
    let empty = serde_json::Map::new();
    let objects = matches!(a, Value::Object(_)) || matches!(b, Value::Object(_));
    match (as_map(a, &empty), as_map(b, &empty)) {
        (Some(x), Some(y)) if objects => {
            // a side that is null: every leaf below belongs to this one setting
            let setting = setting
                .map(str::to_string)
                .or_else(|| (a.is_null() || b.is_null()).then(|| name.to_string()));
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                json_diff_settings(
                    &p,
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                    labels,
                    setting.as_deref(),
                    out,
                );
            }
        }
        _ => {
            let line = match (a, b) {
                (Value::Array(x), Value::Array(y)) if x.len() > 8 || y.len() > 8 => {
                    let first = x.iter().zip(y).position(|(p, q)| p != q);
                    format!(
                        "{name}: {} entries {la}, {} {lb}{}",
                        x.len(),
                        y.len(),
                        first
                            .map(|i| format!(", first difference at entry {i}"))
                            .unwrap_or_default()
                    )
                }
                _ => format!("{name}: {} {la}, {} {lb}", short_value(a), short_value(b)),
            };
            out.push((setting.unwrap_or(name).to_string(), line));
        }
    }
}
