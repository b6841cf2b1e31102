//! A minimal JSON writer (keeps the dependency tree to the two readers).

use std::fmt::Write;

/// Builds one JSON object, key by key, in insertion order.
pub struct Obj {
    buf: String,
    first: bool,
}

impl Obj {
    pub fn new() -> Self {
        Obj { buf: String::from("{"), first: true }
    }

    fn key(&mut self, k: &str) {
        if !self.first {
            self.buf.push_str(", ");
        }
        self.first = false;
        self.buf.push_str(&string(k));
        self.buf.push_str(": ");
    }

    /// A value already rendered as JSON (number, array, object).
    pub fn raw(mut self, k: &str, v: &str) -> Self {
        self.key(k);
        self.buf.push_str(v);
        self
    }

    pub fn num(self, k: &str, v: f64) -> Self {
        let s = number(v);
        self.raw(k, &s)
    }

    pub fn int(self, k: &str, v: i64) -> Self {
        self.raw(k, &v.to_string())
    }

    pub fn boolean(self, k: &str, v: bool) -> Self {
        self.raw(k, if v { "true" } else { "false" })
    }

    pub fn str(self, k: &str, v: &str) -> Self {
        let s = string(v);
        self.raw(k, &s)
    }

    pub fn end(mut self) -> String {
        self.buf.push('}');
        self.buf
    }
}

/// A finite f64 with enough digits to round-trip; null for NaN/inf.
pub fn number(v: f64) -> String {
    if v.is_finite() {
        // Rust's `{:?}` prints the shortest representation that round-trips.
        let s = format!("{:?}", v);
        s
    } else {
        "null".to_string()
    }
}

pub fn string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

pub fn array<I: IntoIterator<Item = String>>(items: I) -> String {
    let v: Vec<String> = items.into_iter().collect();
    format!("[{}]", v.join(", "))
}

pub fn error(msg: &str) -> String {
    Obj::new().str("error", msg).end()
}
