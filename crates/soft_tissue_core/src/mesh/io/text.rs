//! A byte cursor for text files with embedded binary blocks (Gmsh), with positions turned
//! into line numbers only when an error is reported.

use super::{FormatError, Location};

/// The UTF-8 byte order mark some editors write at the start of a text file.
pub(crate) const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";

pub(crate) struct Cursor<'a> {
    pub data: &'a [u8],
    pub pos: usize,
    pub name: &'a str,
}

/// Parsing result with a [`FormatError`].
pub(crate) type Res<T> = Result<T, FormatError>;

impl<'a> Cursor<'a> {
    /// A cursor at the start of `data`, past a UTF-8 byte order mark if there is one.
    pub fn new(data: &'a [u8], name: &'a str) -> Self {
        let pos = if data.starts_with(UTF8_BOM) {
            UTF8_BOM.len()
        } else {
            0
        };
        Self { data, pos, name }
    }

    /// 1-based line number of a byte position. Lines end at LF, CR LF or a lone CR.
    pub fn line_of(&self, pos: usize) -> usize {
        let before = &self.data[..pos.min(self.data.len())];
        let lone_cr = before
            .iter()
            .enumerate()
            .filter(|&(i, &b)| b == b'\r' && self.data.get(i + 1) != Some(&b'\n'))
            .count();
        1 + lone_cr + before.iter().filter(|&&b| b == b'\n').count()
    }

    /// Where the line starting at `start` ends, and where the next one starts: at the first
    /// LF, CR LF or lone CR (classic Mac OS text), else at the end of the data.
    fn line_end(&self, start: usize) -> (usize, usize) {
        match self.data[start..]
            .iter()
            .position(|&b| b == b'\n' || b == b'\r')
        {
            Some(i) => {
                let end = start + i;
                let crlf = self.data[end] == b'\r' && self.data.get(end + 1) == Some(&b'\n');
                (end, end + 1 + usize::from(crlf))
            }
            None => (self.data.len(), self.data.len()),
        }
    }

    /// An error at the line containing `pos`.
    pub fn err_at(&self, pos: usize, msg: impl Into<String>) -> FormatError {
        FormatError::parse(self.name, Location::Line(self.line_of(pos)), msg)
    }

    /// An error at a byte offset in a binary block.
    pub fn err_byte(&self, pos: usize, msg: impl Into<String>) -> FormatError {
        FormatError::parse(self.name, Location::Byte(pos), msg)
    }

    pub fn at_end(&self) -> bool {
        self.pos >= self.data.len()
    }

    pub fn skip_whitespace(&mut self) {
        while self.pos < self.data.len() && self.data[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
    }

    /// The next whitespace-delimited token and its start position. `None` at end.
    pub fn next_token(&mut self) -> Option<(usize, &'a [u8])> {
        self.skip_whitespace();
        if self.at_end() {
            return None;
        }
        let start = self.pos;
        while self.pos < self.data.len() && !self.data[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        Some((start, &self.data[start..self.pos]))
    }

    /// The next raw line (trimmed, possibly empty). `None` at end.
    pub fn raw_line(&mut self) -> Option<&'a [u8]> {
        if self.at_end() {
            return None;
        }
        let start = self.pos;
        let (end, next) = self.line_end(start);
        self.pos = next;
        Some(self.data[start..end].trim_ascii())
    }

    /// The next non-empty line (trimmed), and the position where it starts. `None` at end.
    pub fn next_line(&mut self) -> Option<(usize, &'a [u8])> {
        loop {
            if self.at_end() {
                return None;
            }
            let start = self.pos;
            let (end, next) = self.line_end(start);
            self.pos = next;
            let line = self.data[start..end].trim_ascii();
            if !line.is_empty() {
                return Some((start, line));
            }
        }
    }

    /// The next line, or an error naming what was expected.
    pub fn expect_line(&mut self, what: &str) -> Res<(usize, &'a [u8])> {
        let at = self.pos;
        self.next_line()
            .ok_or_else(|| self.err_at(at, format!("unexpected end of file, expected {what}")))
    }

    /// Reads `n` raw bytes.
    pub fn bytes(&mut self, n: usize, what: &str) -> Res<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        match end {
            Some(end) => {
                let b = &self.data[self.pos..end];
                self.pos = end;
                Ok(b)
            }
            None => Err(self.err_byte(
                self.pos,
                format!(
                    "file ends inside binary data: {what} needs {n} bytes, {} remain",
                    self.data.len() - self.pos.min(self.data.len())
                ),
            )),
        }
    }

    /// Skips to just after the next line equal to `tag` (searching bytes, so it works over
    /// binary data). Errors if the tag is missing.
    pub fn skip_past_tag(&mut self, tag: &str, opened_at: usize) -> Res<()> {
        let t = tag.as_bytes();
        let mut i = self.pos;
        while i + t.len() <= self.data.len() {
            if &self.data[i..i + t.len()] == t
                && (i == 0 || self.data[i - 1] == b'\n' || self.data[i - 1] == b'\r')
            {
                self.pos = i + t.len();
                return Ok(());
            }
            i += 1;
        }
        Err(self.err_at(
            opened_at,
            format!("section is never closed: {tag} not found"),
        ))
    }
}

/// Splits a line into whitespace-separated tokens.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// Shows a token in messages (lossy UTF-8, shortened).
pub(crate) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(tok);
    if s.chars().count() > 40 {
        format!("{}...", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

/// Parses an unsigned integer token.
pub(crate) fn parse_usize(tok: &[u8]) -> Option<usize> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// Parses an integer token that may be negative.
pub(crate) fn parse_i64(tok: &[u8]) -> Option<i64> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// Parses a floating-point token; accepts Fortran-style `D` exponents.
pub(crate) fn parse_f64(tok: &[u8]) -> Option<f64> {
    let s = std::str::from_utf8(tok).ok()?;
    match s.parse() {
        Ok(v) => Some(v),
        Err(_) => s.replace(['d', 'D'], "e").parse().ok(),
    }
}

/// Reads whitespace-separated numbers from a text line with messages naming the line.
pub(crate) struct LineFields<'a, 'c> {
    pub cursor: &'c Cursor<'a>,
    pub start: usize,
    pub toks: Vec<&'a [u8]>,
}

impl<'a, 'c> LineFields<'a, 'c> {
    pub fn new(cursor: &'c Cursor<'a>, start: usize, line: &'a [u8]) -> Self {
        Self {
            cursor,
            start,
            toks: tokens(line).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.toks.len()
    }

    pub fn need(&self, n: usize, what: &str) -> Res<()> {
        if self.toks.len() < n {
            Err(self.cursor.err_at(
                self.start,
                format!(
                    "{what}: expected at least {n} fields, found {}",
                    self.toks.len()
                ),
            ))
        } else {
            Ok(())
        }
    }

    pub fn usize(&self, i: usize, what: &str) -> Res<usize> {
        self.parsed(i, what, "a non-negative integer", parse_usize)
    }

    pub fn i64(&self, i: usize, what: &str) -> Res<i64> {
        self.parsed(i, what, "an integer", parse_i64)
    }

    pub fn f64(&self, i: usize, what: &str) -> Res<f64> {
        self.parsed(i, what, "a number", parse_f64)
    }

    fn parsed<T>(&self, i: usize, what: &str, kind: &str, parse: fn(&[u8]) -> Option<T>) -> Res<T> {
        let tok = self.tok(i, what)?;
        parse(tok).ok_or_else(|| {
            self.cursor
                .err_at(self.start, format!("{what}: '{}' is not {kind}", show(tok)))
        })
    }

    fn tok(&self, i: usize, what: &str) -> Res<&'a [u8]> {
        self.toks.get(i).copied().ok_or_else(|| {
            self.cursor.err_at(
                self.start,
                format!("{what}: missing field {} of the line", i + 1),
            )
        })
    }
}
