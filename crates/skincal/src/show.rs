//! How numbers from files and settings appear in messages.

/// `v` as a person reads it: plain for everyday magnitudes, scientific beyond them (`1e308`
/// rather than 309 digits).
pub(crate) fn number(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 || !v.is_finite() || (1e-4..1e7).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `text` for XML (and HTML) text and attribute values.
pub(crate) fn xml_escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn extremes_are_short_and_everyday_numbers_plain() {
        assert_eq!(super::number(1e308), "1e308");
        assert_eq!(super::number(-2.5e-300), "-2.5e-300");
        assert_eq!(super::number(0.05), "0.05");
        assert_eq!(super::number(9.81), "9.81");
        assert_eq!(super::number(f64::NAN), "NaN");
        assert_eq!(super::number(0.0), "0");
    }
}
