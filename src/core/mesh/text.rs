//! Text scanning shared by the ASCII parsers: lines and whitespace-separated tokens streamed
//! from an [`Input`], and numbers parsed exactly as `str::parse` parses them, only faster.
//!
//! Every function here returns what the `str` method it replaces returns on the same text (the
//! tests compare them): the common spellings (decimal digits, a sign, a point, an exponent) take
//! a fast path (`fast-float2`, itself exact: the same correctly rounded value as the standard
//! library), anything else is handed to the standard library.

use super::input::Input;

/// `u8::is_ascii_whitespace`, the separator of `split_ascii_whitespace`.
#[inline]
pub(super) fn is_ws(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r' | b'\x0c')
}

/// The text of a token for a message. Tokens are cut at ASCII bytes, so a token of valid UTF-8
/// text is valid UTF-8 (and input that is not is reported as such before any message of ours).
pub(super) fn show(t: &[u8]) -> std::borrow::Cow<'_, str> {
    String::from_utf8_lossy(t)
}

/// The value of 1 to 18 ASCII digits (and nothing else).
#[inline]
fn digits(t: &[u8]) -> Option<u64> {
    if t.is_empty() || t.len() > 18 {
        return None;
    }
    let mut v = 0u64;
    for &b in t {
        let d = b.wrapping_sub(b'0');
        if d > 9 {
            return None;
        }
        v = v * 10 + u64::from(d);
    }
    Some(v)
}

/// Whether `t` is `[+-]? (d+ ('.' d*)? | '.' d+) ([eE] [+-]? d+)?`: a spelling the standard
/// library accepts, read by `fast-float2` to the same value.
#[inline]
fn plain_decimal(t: &[u8]) -> bool {
    let mut i = usize::from(matches!(t.first(), Some(b'+' | b'-')));
    let int_start = i;
    while i < t.len() && t[i].is_ascii_digit() {
        i += 1;
    }
    let mut mantissa = i - int_start;
    if i < t.len() && t[i] == b'.' {
        i += 1;
        let frac_start = i;
        while i < t.len() && t[i].is_ascii_digit() {
            i += 1;
        }
        mantissa += i - frac_start;
    }
    if mantissa == 0 {
        return false;
    }
    if i < t.len() && (t[i] == b'e' || t[i] == b'E') {
        i += 1;
        if i < t.len() && (t[i] == b'+' || t[i] == b'-') {
            i += 1;
        }
        let exp_start = i;
        while i < t.len() && t[i].is_ascii_digit() {
            i += 1;
        }
        if i == exp_start {
            return false;
        }
    }
    i == t.len()
}

/// `str::parse::<f64>` of the token (`None` for an error, and for bytes that are not UTF-8).
#[inline]
pub(super) fn parse_f64(t: &[u8]) -> Option<f64> {
    if let Some(v) = digits(t) {
        if v < 1 << 53 {
            return Some(v as f64);
        }
    }
    if plain_decimal(t) {
        return fast_float2::parse::<f64, _>(t).ok();
    }
    std::str::from_utf8(t).ok()?.parse().ok()
}

/// `str::parse::<u32>` of the token.
#[inline]
pub(super) fn parse_u32(t: &[u8]) -> Option<u32> {
    if t.len() <= 9 {
        if let Some(v) = digits(t) {
            return Some(v as u32);
        }
    }
    std::str::from_utf8(t).ok()?.parse().ok()
}

/// `str::parse::<usize>` of the token.
#[inline]
pub(super) fn parse_usize(t: &[u8]) -> Option<usize> {
    match digits(t) {
        Some(v) => usize::try_from(v).ok(),
        None => std::str::from_utf8(t).ok()?.parse().ok(),
    }
}

/// `str::parse::<i64>` of the token.
#[inline]
pub(super) fn parse_i64(t: &[u8]) -> Option<i64> {
    let (neg, d) = match t.split_first() {
        Some((b'-', d)) => (true, d),
        _ => (false, t),
    };
    match digits(d) {
        Some(v) => Some(if neg { -(v as i64) } else { v as i64 }),
        None => std::str::from_utf8(t).ok()?.parse().ok(),
    }
}

/// `split_ascii_whitespace` over bytes.
pub(super) struct Words<'a> {
    rest: &'a [u8],
}

impl<'a> Words<'a> {
    #[inline]
    pub(super) fn new(line: &'a [u8]) -> Words<'a> {
        Words { rest: line }
    }
}

impl<'a> Iterator for Words<'a> {
    type Item = &'a [u8];

    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        let r = self.rest;
        let mut i = 0;
        while i < r.len() && is_ws(r[i]) {
            i += 1;
        }
        if i == r.len() {
            self.rest = &[];
            return None;
        }
        let mut j = i + 1;
        while j < r.len() && !is_ws(r[j]) {
            j += 1;
        }
        self.rest = &r[j..];
        Some(&r[i..j])
    }
}

/// The part of a line before its first `#` (`line.split('#').next()`).
#[inline]
pub(super) fn before_comment(line: &[u8]) -> &[u8] {
    match memchr::memchr(b'#', line) {
        Some(i) => &line[..i],
        None => line,
    }
}

/// Calls `f` on every line of the rest of the input, as `str::split_inclusive('\n')` cuts them,
/// without the `\n` and with whether there was one; stops early when `f` returns `Ok(false)`.
pub(super) fn for_each_line(
    input: &mut Input,
    mut f: impl FnMut(&[u8], bool) -> Result<bool, String>,
) -> Result<(), String> {
    loop {
        let w = input.window();
        let mut start = 0;
        let mut go = true;
        for end in memchr::memchr_iter(b'\n', w) {
            go = f(&w[start..end], true)?;
            start = end + 1;
            if !go {
                break;
            }
        }
        input.consume(start);
        if !go {
            return Ok(());
        }
        if !input.more() {
            let last = input.window();
            if !last.is_empty() {
                f(last, false)?;
                let n = last.len();
                input.consume(n);
            }
            return Ok(());
        }
    }
}

/// `line` as `str::lines` yields it: a `\r` before the `\n` removed.
#[inline]
pub(super) fn strip_cr(line: &[u8], had_newline: bool) -> &[u8] {
    match line.split_last() {
        Some((b'\r', rest)) if had_newline => rest,
        _ => line,
    }
}

/// The whitespace-separated tokens of the rest of the input (the ASCII PLY body).
pub(super) struct Tokens<'a> {
    input: &'a mut Input,
}

impl<'a> Tokens<'a> {
    pub(super) fn new(input: &'a mut Input) -> Tokens<'a> {
        Tokens { input }
    }

    /// The next token; `None` at the end of the input.
    #[inline]
    pub(super) fn next_token(&mut self) -> Option<&[u8]> {
        loop {
            let w = self.input.window();
            let mut i = 0;
            while i < w.len() && is_ws(w[i]) {
                i += 1;
            }
            if i == w.len() {
                self.input.consume(i);
                if self.input.more() {
                    continue;
                }
                return None;
            }
            let mut j = i + 1;
            while j < w.len() && !is_ws(w[j]) {
                j += 1;
            }
            if j == w.len() && !self.input.at_end() {
                // The token may go on in the next chunk.
                self.input.consume(i);
                self.input.more();
                continue;
            }
            self.input.consume(j);
            let w = self.input.window_before(j - i);
            return Some(w);
        }
    }
}
