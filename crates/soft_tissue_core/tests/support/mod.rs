//! Seeded, reproducible mutations of input files for the no-panic sweeps (`formats.rs`,
//! `mutation.rs`): truncations, bit flips, byte replacements and declared counts replaced by
//! zero, negative and huge values. Every mutation prints as what it did, so a failure names
//! the exact input to rebuild. [`tissue`] holds the heated tissue block the burn tests
//! share.

#![allow(dead_code)] // Each test file uses part of it.

pub mod tissue;

use std::fmt;
use std::path::Path;

/// Whether a missing shared-mesh folder (`../shared/meshes` beside the clone) skips what
/// reads it (the default, printed as SKIPPED on stderr) or fails the test:
/// `SOFT_TISSUE_REQUIRE_SHARED=1`, which `.ci/run` always sets (it requires the folder), so
/// a wrong path or a lost folder cannot pass as a skip.
pub fn shared_meshes_required() -> bool {
    std::env::var("SOFT_TISSUE_REQUIRE_SHARED").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// The shared-mesh folder `dir` where it is a folder. Where it is not: a panic naming it and
/// `test` when `required` (see [`shared_meshes_required`]), else `None` after printing
/// SKIPPED for `test` on stderr
/// (shown even when the test passes).
pub fn shared_folder<'a>(dir: &'a Path, test: &str, required: bool) -> Option<&'a Path> {
    if dir.is_dir() {
        return Some(dir);
    }
    if required {
        panic!(
            "{test}: the shared real-world meshes are missing ({} is not a folder), and \
             SOFT_TISSUE_REQUIRE_SHARED is set",
            dir.display()
        );
    }
    // Written to the standard error itself, which `cargo test` shows even when the test
    // passes (the print macros' output is captured).
    use std::io::Write;
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: {} is not a folder (set SOFT_TISSUE_REQUIRE_SHARED=1 to make this a \
         failure)",
        dir.display()
    );
    None
}

/// A small deterministic generator (xorshift64): the same seed gives the same mutations.
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed` (zero is replaced, xorshift would stay at zero).
    pub fn new(seed: u64) -> Self {
        Rng(if seed == 0 {
            0x9E37_79B9_7F4A_7C15
        } else {
            seed
        })
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// A number in `0..n` (`n` > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// Values a declared count (or any integer) is replaced by: zero, negative, just past the
/// 32-bit and 64-bit ranges, and far beyond any range.
pub const COUNT_VALUES: [&str; 8] = [
    "0",
    "-1",
    "-9223372036854775808",
    "2147483648",
    "4294967297",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999999",
];

/// One change to an input.
#[derive(Debug, Clone, PartialEq)]
pub enum Mutation {
    /// Keep the first `len` bytes.
    Truncate(usize),
    /// Flip bit `bit` of byte `byte`.
    FlipBit {
        /// Byte offset.
        byte: usize,
        /// Bit, 0 to 7.
        bit: u8,
    },
    /// Replace bytes (offset, new value).
    Replace(Vec<(usize, u8)>),
    /// Replace the integer at `start..end` by `value`.
    Count {
        /// First byte of the integer.
        start: usize,
        /// One past its last byte.
        end: usize,
        /// What replaces it.
        value: &'static str,
    },
}

impl fmt::Display for Mutation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Mutation::Truncate(n) => write!(f, "truncated to {n} bytes"),
            Mutation::FlipBit { byte, bit } => write!(f, "bit {bit} of byte {byte} flipped"),
            Mutation::Replace(at) => {
                write!(f, "bytes replaced:")?;
                for (i, b) in at {
                    write!(f, " [{i}] = {b:#04x}")?;
                }
                Ok(())
            }
            Mutation::Count { start, end, value } => {
                write!(f, "integer at bytes {start}..{end} replaced by {value}")
            }
        }
    }
}

impl Mutation {
    /// The mutated copy of `bytes` (offsets past the end are ignored).
    pub fn apply(&self, bytes: &[u8]) -> Vec<u8> {
        match self {
            Mutation::Truncate(n) => bytes[..(*n).min(bytes.len())].to_vec(),
            Mutation::FlipBit { byte, bit } => {
                let mut b = bytes.to_vec();
                if let Some(x) = b.get_mut(*byte) {
                    *x ^= 1 << bit;
                }
                b
            }
            Mutation::Replace(at) => {
                let mut b = bytes.to_vec();
                for &(i, v) in at {
                    if let Some(x) = b.get_mut(i) {
                        *x = v;
                    }
                }
                b
            }
            Mutation::Count { start, end, value } => {
                let mut b = Vec::with_capacity(bytes.len() + value.len());
                b.extend_from_slice(&bytes[..*start]);
                b.extend_from_slice(value.as_bytes());
                b.extend_from_slice(&bytes[*end..]);
                b
            }
        }
    }
}

/// One to four bytes replaced by a digit, a line break, a sign or noise (the characters that
/// change a text format's structure most).
pub fn replace_bytes(rng: &mut Rng, len: usize) -> Mutation {
    let mut at = Vec::new();
    if len > 0 {
        for _ in 0..1 + rng.below(4) {
            let i = rng.below(len);
            let v = match rng.below(6) {
                0 => b'9',
                1 => b'\n',
                2 => b'-',
                3 => b' ',
                4 => b'"',
                _ => rng.next_u64() as u8,
            };
            at.push((i, v));
        }
    }
    Mutation::Replace(at)
}

/// The byte ranges of the integers in `bytes`: runs of ASCII digits (with a leading `-`)
/// that are not part of a word or a decimal number.
pub fn integers(bytes: &[u8]) -> Vec<(usize, usize)> {
    let word = |b: u8| b.is_ascii_alphanumeric() || b == b'.' || b == b'_';
    let mut found = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if !bytes[i].is_ascii_digit() {
            i += 1;
            continue;
        }
        let mut start = i;
        while i < bytes.len() && bytes[i].is_ascii_digit() {
            i += 1;
        }
        if start > 0 && bytes[start - 1] == b'-' {
            start -= 1;
        }
        let before = start.checked_sub(1).map(|k| bytes[k]);
        let after = bytes.get(i).copied();
        if !before.is_some_and(word) && !after.is_some_and(|b| word(b) || b == b'e' || b == b'E') {
            found.push((start, i));
        }
    }
    found
}

/// How many mutations of each kind [`mutations`] makes.
#[derive(Debug, Clone, Copy)]
pub struct SweepSize {
    /// Truncation points, spread evenly (plus the last few bytes).
    pub truncations: usize,
    /// Single bit flips.
    pub bit_flips: usize,
    /// Byte replacements ([`replace_bytes`]).
    pub replacements: usize,
    /// Integers whose value is replaced by each of [`COUNT_VALUES`]: the first ones, the
    /// ones alone on their line or quoted (counts and attributes), then random others.
    pub integers: usize,
}

/// The mutations of an input of `bytes` for a sweep seeded by `seed`.
pub fn mutations(bytes: &[u8], seed: u64, size: SweepSize) -> Vec<Mutation> {
    let mut rng = Rng::new(seed);
    let len = bytes.len();
    let mut out = Vec::new();
    let step = (len / size.truncations.max(1)).max(1);
    out.extend((0..len).step_by(step).map(Mutation::Truncate));
    out.extend((len.saturating_sub(4)..len).map(Mutation::Truncate));
    if len > 0 {
        for _ in 0..size.bit_flips {
            out.push(Mutation::FlipBit {
                byte: rng.below(len),
                bit: rng.below(8) as u8,
            });
        }
    }
    for _ in 0..size.replacements {
        out.push(replace_bytes(&mut rng, len));
    }
    let all = integers(bytes);
    let alone = |&(s, e): &(usize, usize)| {
        let line_start = s == 0 || bytes[s - 1] == b'\n';
        let line_end = e == len || bytes[e] == b'\n' || bytes[e] == b'\r';
        let quoted = s > 0 && bytes[s - 1] == b'"';
        (line_start && line_end) || quoted
    };
    let mut chosen: Vec<(usize, usize)> = all.iter().take(size.integers / 2).copied().collect();
    chosen.extend(
        all.iter()
            .skip(size.integers / 2)
            .filter(|r| alone(r))
            .take(size.integers / 4),
    );
    let budget = size.integers.saturating_sub(chosen.len());
    if all.len() > chosen.len() {
        for _ in 0..budget {
            chosen.push(all[rng.below(all.len())]);
        }
    }
    chosen.sort_unstable();
    chosen.dedup();
    for (start, end) in chosen {
        for value in COUNT_VALUES {
            out.push(Mutation::Count { start, end, value });
        }
    }
    out
}
