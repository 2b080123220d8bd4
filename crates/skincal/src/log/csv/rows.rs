//! The rows of a CSV log, parsed: `imu.csv` in blocks on the thread pool while the next are read,
//! numbers converted as their fields are scanned.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use crate::log::in_order::InOrder;
use crate::log::{LogError, ReadStats, Sample};

/// Bytes of `imu.csv` parsed as one block (with the end of a line from the block before: far
/// less than 4 GB in all, so byte ranges in a block fit in `u32`).
const BLOCK: usize = 1 << 22;
/// Blocks being parsed at once, on the thread pool.
const BLOCKS: usize = 4;

/// The rows of `imu.csv` after its header: a producer thread reads blocks of whole lines and
/// hands each to the thread pool to be parsed; the caller's thread hands the rows to the visitor
/// in order.
pub(super) struct ImuRows<'a> {
    pub(super) path: &'a Path,
    /// Lines before the first block.
    pub(super) line: usize,
    /// Bytes before the first block.
    pub(super) bytes: u64,
}

/// One parsed block: its text, its rows and its bad lines.
#[derive(Default)]
struct Parsed {
    text: String,
    /// `(stamp, frame id's byte range in text, acceleration)`; a block is far shorter than 4 GB.
    rows: Vec<(f64, (u32, u32), [f64; 3])>,
    /// Lines that are not a sample, by their number within the block (1-based).
    bad: Vec<usize>,
    lines: usize,
}

impl ImuRows<'_> {
    pub(super) fn read(
        self,
        reader: BufReader<File>,
        stats: &mut ReadStats,
        visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
        progress: &mut dyn FnMut(u64),
    ) -> Result<(), LogError> {
        let path = self.path;
        let io_error = |source| LogError::Io {
            path: path.to_path_buf(),
            source,
        };
        let carry = reader.buffer().to_vec();
        let file = reader.into_inner();
        std::thread::scope(|scope| {
            let (blocks, received) = std::sync::mpsc::sync_channel::<(Parsed, u64)>(BLOCKS);
            let producer = scope.spawn(move || produce(file, carry, &blocks));
            let (mut line, mut bytes) = (self.line, self.bytes);
            for (block, read) in &received {
                for &bad in &block.bad {
                    stats.problem(format!(
                        "{}, line {}: expected `stamp,frame_id,ax,ay,az` with finite numbers",
                        path.display(),
                        line + bad
                    ));
                }
                for &(stamp, (from, to), a) in &block.rows {
                    stats.samples += 1;
                    visit(Sample::Imu {
                        stamp,
                        frame_id: &block.text[from as usize..to as usize],
                        acceleration: a,
                    })?;
                }
                line += block.lines;
                bytes = self.bytes + read;
                progress(bytes);
            }
            drop(received);
            // A producer that panicked read only part of the file: never a silent short read.
            let stopped = || {
                Err(Produced::Io(std::io::Error::other(
                    "the reading thread stopped unexpectedly",
                )))
            };
            producer
                .join()
                .unwrap_or_else(|_| stopped())
                .map_err(|e| match e {
                    Produced::Io(source) => io_error(source),
                    Produced::Utf8 { at, lines } => LogError::Csv {
                        path: path.to_path_buf(),
                        line: line + lines + 1,
                        reason: format!("not UTF-8 text (byte {at} of the rows): is it a CSV log?"),
                    },
                    Produced::LongLine(at) => LogError::Csv {
                        path: path.to_path_buf(),
                        line: line + 1,
                        reason: format!(
                            "a line longer than {} MB (from byte {at} of the rows): is it a CSV \
                             log?",
                            LONGEST_LINE >> 20
                        ),
                    },
                })?;
            progress(bytes);
            Ok(())
        })
    }
}

/// Why the producer stopped.
enum Produced {
    Io(std::io::Error),
    /// Text that is not UTF-8: the bytes read before it, and the whole lines before it in its
    /// block.
    Utf8 {
        at: u64,
        lines: usize,
    },
    /// Bytes read before a line longer than [`LONGEST_LINE`].
    LongLine(u64),
}

/// The longest line read, bytes: a block holds whole lines, and a file without line ends must not
/// be read into memory whole.
const LONGEST_LINE: usize = 1 << 26;

/// Reads `file` (after `carry`) in blocks of whole lines, parses each on the thread pool while
/// it reads the next, and sends them in order with the bytes read so far.
fn produce(
    mut file: File,
    mut carry: Vec<u8>,
    blocks: &std::sync::mpsc::SyncSender<(Parsed, u64)>,
) -> Result<(), Produced> {
    // Blocks being parsed, in file order: each on the thread pool as soon as it is read, so
    // reading overlaps parsing.
    let mut pending: InOrder<Result<Parsed, Produced>> = InOrder::new();
    let mut read = 0u64;
    // Sends the oldest block on once it is parsed; false when the receiver is gone.
    let forward = |pending: &mut InOrder<_>, read: u64| -> Result<bool, Produced> {
        let Some(parsed) = pending.next() else {
            return Ok(true);
        };
        let parsed = parsed.unwrap_or_else(|_| {
            Err(Produced::Io(std::io::Error::other(
                "parsing a block failed unexpectedly",
            )))
        })?;
        Ok(blocks.send((parsed, read)).is_ok())
    };
    loop {
        let mut block = std::mem::take(&mut carry);
        let start = block.len();
        block.resize(start + BLOCK, 0);
        let n = read_full(&mut file, &mut block[start..]).map_err(Produced::Io)?;
        block.truncate(start + n);
        let done = n == 0;
        // Whole lines only: the rest goes to the next block.
        let cut = if done {
            block.len()
        } else {
            memchr::memrchr(b'\n', &block).map_or(0, |i| i + 1)
        };
        carry = block.split_off(cut);
        let at = read;
        read += block.len() as u64;
        if !block.is_empty() {
            pending.spawn(move || {
                String::from_utf8(block).map(parse).map_err(|e| {
                    let valid = e.utf8_error().valid_up_to();
                    let lines = memchr::memchr_iter(b'\n', &e.as_bytes()[..valid]).count();
                    Produced::Utf8 {
                        at: at + valid as u64,
                        lines,
                    }
                })
            });
        }
        let long_line = carry.len() > LONGEST_LINE;
        let keep = if done || long_line { 0 } else { BLOCKS };
        // Once the whole lines before a line too long are handed over, it is the error.
        while pending.len() > keep {
            if !forward(&mut pending, read)? {
                return Ok(());
            }
        }
        if long_line {
            return Err(Produced::LongLine(read));
        }
        if done {
            return Ok(());
        }
    }
}

/// Fills `buffer` as far as the file goes.
fn read_full(file: &mut File, buffer: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buffer.len() {
        match file.read(&mut buffer[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// The rows `stamp,frame_id,ax,ay,az` of a block of whole lines.
fn parse(text: String) -> Parsed {
    let mut parsed = Parsed::default();
    let bytes = text.as_bytes();
    // Rows of a skin log take about 50 bytes.
    parsed.rows.reserve(bytes.len() / 48);
    let mut start = 0;
    while start < bytes.len() {
        let end = memchr::memchr(b'\n', &bytes[start..]).map_or(bytes.len(), |i| start + i);
        parsed.lines += 1;
        // Line ends are ASCII: the row is whole characters.
        let line = &text[start..end];
        let row = line.strip_suffix('\r').unwrap_or(line);
        if !row.is_empty() && !row.starts_with('#') {
            match imu_row(row) {
                Some((stamp, frame, a)) => parsed.rows.push((
                    stamp,
                    ((start + frame.start) as u32, (start + frame.end) as u32),
                    a,
                )),
                None => parsed.bad.push(parsed.lines),
            }
        }
        start = end + 1;
    }
    parsed.text = text;
    parsed
}

/// A row `stamp,<positions…>` with `dofs` positions (no line end): the stamp, the positions in
/// `positions`; `None` unless every number is finite.
pub(super) fn joint_row(row: &str, dofs: usize, positions: &mut Vec<f64>) -> Option<f64> {
    let mut fields = Fields { row, at: 0 };
    let stamp = fields.number()?;
    positions.clear();
    while fields.at <= row.len() {
        positions.push(fields.number()?);
    }
    (positions.len() == dofs).then_some(stamp)
}

/// A row `stamp,frame_id,ax,ay,az` (no line end): the stamp, the frame id's byte range (trimmed)
/// and the acceleration; `None` unless every number is finite and the frame id is not empty.
fn imu_row(row: &str) -> Option<(f64, std::ops::Range<usize>, [f64; 3])> {
    let mut fields = Fields { row, at: 0 };
    let stamp = fields.number()?;
    let frame = fields.text()?;
    let a = [fields.number()?, fields.number()?, fields.number()?];
    (fields.at > row.len() && !frame.is_empty()).then_some((stamp, frame, a))
}

/// The comma-separated fields of a row, taken in turn.
struct Fields<'a> {
    row: &'a str,
    /// Where the next field starts; past the row's end when none is left.
    at: usize,
}

impl Fields<'_> {
    /// The next field, trimmed, as a finite number.
    fn number(&mut self) -> Option<f64> {
        let start = self.at;
        let bytes = self.row.as_bytes();
        if start > bytes.len() {
            return None;
        }
        // Most fields are plain decimals, read as they are scanned; anything else (an exponent,
        // spaces, `inf`) goes to the standard library's parser.
        let (value, end) = decimal(bytes, start);
        if let (Some(v), None | Some(b',')) = (value, bytes.get(end)) {
            self.at = end + 1;
            return Some(v);
        }
        let range = self.text()?;
        self.row[range]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
    }

    /// The next field's byte range in the row, trimmed.
    fn text(&mut self) -> Option<std::ops::Range<usize>> {
        let start = self.at;
        let rest = self.row.as_bytes().get(start..)?;
        let end = memchr::memchr(b',', rest).map_or(self.row.len(), |i| start + i);
        self.at = end + 1;
        let field = &self.row[start..end];
        // Only a field that starts or ends in whitespace or a non-ASCII character can need trimming.
        let plain = |b: Option<&u8>| b.is_none_or(|b| b.is_ascii() && !b.is_ascii_whitespace());
        if plain(field.as_bytes().first()) && plain(field.as_bytes().last()) {
            return Some(start..end);
        }
        let trimmed = field.trim_start();
        let from = end - trimmed.len();
        Some(from..from + trimmed.trim_end().len())
    }
}

/// Exact powers of ten as f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// The plain decimal (`-12.345`: sign, digits, at most one point) starting at `at` in `bytes`,
/// and where it ends; `None` where it is not one, or where it has more than 19 digits, or more
/// than 2^53 as its digits and more than 9 after the point (the standard parser then decides).
/// The value is the correctly rounded one, as `str::parse::<f64>` gives.
fn decimal(bytes: &[u8], mut at: usize) -> (Option<f64>, usize) {
    let negative = bytes.get(at) == Some(&b'-');
    if negative || bytes.get(at) == Some(&b'+') {
        at += 1;
    }
    let (mut digits, mut count, mut point) = (0u64, 0u32, None);
    while let Some(&b) = bytes.get(at) {
        if b.is_ascii_digit() {
            if count == 19 {
                return (None, at);
            }
            digits = digits * 10 + u64::from(b - b'0');
            count += 1;
        } else if b == b'.' && point.is_none() {
            point = Some(at);
        } else {
            break;
        }
        at += 1;
    }
    let decimals = point.map_or(0, |p| at - p - 1);
    let v = match decimals {
        _ if count == 0 => return (None, at),
        // Both exact in f64, so their quotient is correctly rounded (Clinger's fast path).
        _ if digits <= 1 << 53 => digits as f64 / POW10[decimals],
        // Stamps: seconds since the epoch to the nanosecond have 19 digits.
        0 => long_decimal::<1>(digits),
        1 => long_decimal::<10>(digits),
        2 => long_decimal::<100>(digits),
        3 => long_decimal::<1_000>(digits),
        4 => long_decimal::<10_000>(digits),
        5 => long_decimal::<100_000>(digits),
        6 => long_decimal::<1_000_000>(digits),
        7 => long_decimal::<10_000_000>(digits),
        8 => long_decimal::<100_000_000>(digits),
        9 => long_decimal::<1_000_000_000>(digits),
        _ => return (None, at),
    };
    (Some(if negative { -v } else { v }), at)
}

/// `digits / D` correctly rounded (to even on a tie), for `digits` above 2^53 and `D` a power of
/// ten up to 10^9: the quotient in integers to 32 bits after the point, then rounded to 53
/// significant bits with the remainder as the sticky bit.
fn long_decimal<const D: u64>(digits: u64) -> f64 {
    let (whole, rest) = (digits / D, digits % D);
    // rest < 10^9 < 2^30: no overflow.
    let scaled = rest << 32;
    let (fraction, sticky) = (scaled / D, scaled % D != 0);
    let q = (u128::from(whole) << 32) | u128::from(fraction);
    // whole > 2^53 / 10^9 > 2^23, so q has at least 56 bits.
    let shift = 128 - q.leading_zeros() - 53;
    let mut mantissa = (q >> shift) as u64;
    let dropped = q & ((1 << shift) - 1);
    let half = 1u128 << (shift - 1);
    if dropped > half || (dropped == half && (sticky || mantissa & 1 == 1)) {
        // At most 2^53: still exact.
        mantissa += 1;
    }
    // q's unit is 2^-32; shift is at most 43, so the power of two is a normal number.
    let scale = f64::from_bits((1023 + u64::from(shift) - 32) << 52);
    mantissa as f64 * scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The standard parser's verdict on a field, as a row's number.
    fn std_number(field: &str) -> Option<f64> {
        field.trim().parse::<f64>().ok().filter(|v| v.is_finite())
    }

    fn same(a: Option<f64>, b: Option<f64>) -> bool {
        match (a, b) {
            (Some(a), Some(b)) => a.to_bits() == b.to_bits(),
            (None, None) => true,
            _ => false,
        }
    }

    #[test]
    fn numbers_are_what_the_standard_parser_reads() {
        for field in [
            "9.058056",
            "-0.974319",
            "0",
            "-0",
            "-0.000",
            "+5",
            "5.",
            ".5",
            ".",
            "-",
            "",
            " 1.5",
            "1.5 ",
            "1e3",
            "1.5E-3",
            "inf",
            "-inf",
            "NaN",
            "1..2",
            "1.2.3",
            "0.1",
            "0.3",
            "9007199254740993",
            "9007199254740992.5",
            "1767225600.000000000",
            "1767225600.123456789",
            "0.0000000000000000000001",
            "123456789012345678901234",
            "12a",
            "--1",
            "1-",
            "٣",
            "1,5",
            // Bytes just past '9' and just before '0'.
            "1234567:",
            "12:34:56.789",
            "0.12345;78",
            "1234567/",
            "99999999?",
            // Ties and near-ties of 53 bits.
            "9007199254740995",
            "18014398509481986.0",
            "18014398509481990.00",
            "18014398509481986.01",
            "18014398509481985.99",
            "1767225600.000000001",
        ] {
            let mut fields = Fields { row: field, at: 0 };
            let got = fields.number().filter(|_| fields.at > field.len());
            assert!(same(got, std_number(field)), "`{field}`: {got:?}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 20_000, rng_seed: proptest::test_runner::RngSeed::Fixed(14), ..ProptestConfig::default() })]

        /// Decimals as loggers write them: any sign, digits and point, every rounding case.
        #[test]
        fn decimals_round_as_the_standard_parser(
            sign in prop::sample::select(vec!["", "-", "+"]),
            int in "[0-9]{0,20}",
            point in any::<bool>(),
            frac in "[0-9]{0,24}",
        ) {
            let field = format!("{sign}{int}{}{frac}", if point { "." } else { "" });
            let mut fields = Fields { row: &field, at: 0 };
            let got = fields.number().filter(|_| fields.at > field.len());
            prop_assert!(same(got, std_number(&field)), "`{}`: {:?}", field, got);
        }

        /// Stamps as loggers write them, seconds since the epoch to the nanosecond or coarser.
        #[test]
        fn stamps_round_as_the_standard_parser(sec in 0u64..10_000_000_000, nanos in 0u64..1_000_000_000, decimals in 0usize..=9) {
            let field = format!("{sec}.{:0decimals$}", nanos / 10u64.pow(9 - decimals as u32));
            let mut fields = Fields { row: &field, at: 0 };
            prop_assert!(same(fields.number(), std_number(&field)), "`{}`", field);
        }

        /// Printed floats read back bit for bit.
        #[test]
        fn printed_floats_read_back(v in any::<f64>().prop_filter("finite", |v| v.is_finite()), decimals in 0usize..12) {
            for field in [format!("{v}"), format!("{v:.decimals$}")] {
                let mut fields = Fields { row: &field, at: 0 };
                prop_assert!(same(fields.number(), std_number(&field)), "`{}`", field);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 500, rng_seed: proptest::test_runner::RngSeed::Fixed(14), ..ProptestConfig::default() })]

        /// Blocks of rows, read with the standard splitter and parser as the oracle: line ends
        /// (CRLF too, and none at the end) and fields the fast path leaves to the standard parser.
        #[test]
        fn blocks_read_as_the_standard_splitter_and_parser(
            rows in prop::collection::vec(
                (
                    prop::collection::vec(
                        prop_oneof![
                            "-?[0-9]{1,12}\\.[0-9]{0,9}",
                            "[0-9]{10}\\.[0-9]{9}",
                            prop::sample::select(vec!["1e3", " 2.5", "inf", "", "-", "7.", "0x10", "12345678901234567890"]).prop_map(String::from),
                        ],
                        5,
                    ),
                    "[a-z_0-9]{0,6}",
                    prop::sample::select(vec!["\n", "\r\n"]),
                ),
                1..40,
            ),
        ) {
            let mut text = String::new();
            let mut expected = Vec::new();
            for (numbers, frame, end) in &rows {
                let fields = [&numbers[0], frame, &numbers[1], &numbers[2], &numbers[3]];
                let row = fields.iter().map(|f| f.as_str()).collect::<Vec<_>>().join(",");
                text.push_str(&row);
                text.push_str(end);
                let std: Vec<&str> = row.split(',').map(str::trim).collect();
                let number = |i: usize| std_number(std[i]);
                expected.push(match (number(0), number(2), number(3), number(4)) {
                    (Some(t), Some(x), Some(y), Some(z)) if !std[1].is_empty() => {
                        Some((t.to_bits(), std[1].to_string(), [x, y, z].map(f64::to_bits)))
                    }
                    _ => None,
                });
            }
            // The last row without its line end, as at the end of a file.
            text.truncate(text.trim_end().len());
            let parsed = parse(text);
            let mut got: Vec<Option<_>> = vec![None; rows.len()];
            let mut next = parsed.rows.iter();
            for (line, slot) in got.iter_mut().enumerate() {
                if !parsed.bad.contains(&(line + 1)) {
                    let &(t, (from, to), a) = next.next().expect("a row per good line");
                    *slot = Some((
                        t.to_bits(),
                        parsed.text[from as usize..to as usize].to_string(),
                        a.map(f64::to_bits),
                    ));
                }
            }
            prop_assert_eq!(parsed.lines, rows.len());
            prop_assert_eq!(got, expected);
        }

    }

    #[test]
    fn rows_split_as_written() {
        let text = "1.5,su_1 , 9.8,-0.25,1e-3\n# comment\n\n2,su_2,1,2\n3,,1,2,3\r\n4,su_4,1,2,3,4\n5,su_5,1,inf,3\n6,sü,0,0,0";
        let parsed = parse(text.to_string());
        assert_eq!(parsed.lines, 8);
        assert_eq!(parsed.bad, vec![4, 5, 6, 7]);
        let rows: Vec<_> = parsed
            .rows
            .iter()
            .map(|&(t, (from, to), a)| (t, &parsed.text[from as usize..to as usize], a))
            .collect();
        assert_eq!(
            rows,
            vec![(1.5, "su_1", [9.8, -0.25, 1e-3]), (6.0, "sü", [0.0; 3])]
        );
    }
}
