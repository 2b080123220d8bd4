//! Streaming MCAP reading at the speed of the disk.
//!
//! A producer thread reads the file with the `mcap` crate's sans-io reader, which hands over whole
//! chunk records without decompressing them; it hands each chunk to the thread pool (rayon) to be
//! decompressed as soon as it is read, and passes the decompressed chunks, in file order, through
//! a bounded channel to the caller's thread, which walks their records and decodes the messages it
//! wants. Reading, decompressing and decoding thus overlap, memory stays at a few chunks whatever
//! the file's length, and the decompressed buffers go back to the producer to be filled again.

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::path::Path;
use std::sync::mpsc::{channel, sync_channel, Receiver, SyncSender};
use std::time::{Duration, Instant};

use mcap::records::{op, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use crate::log::in_order::InOrder;
use crate::log::{deliver, ChannelKind, FrameNames, LogError, PassStats, Sample, Stream, Topics};

/// How many times its file size a decompressed chunk may be.
const MAX_INFLATION: u64 = 256;
/// The longest record read, bytes, whatever the file size (ROS 2 writes chunks of a few MB).
const MAX_RECORD: usize = 1 << 30;
/// Chunks being decompressed at once, on the thread pool.
const DECOMPRESSING: usize = 4;
/// Decompressed blocks in flight between the threads (beyond those being decompressed).
const IN_FLIGHT: usize = 2 * DECOMPRESSING;

/// What the producer hands over, in file order.
enum Block {
    /// A chunk's records, decompressed.
    Chunk(Vec<u8>),
    /// A record outside chunks (schemas, channels and messages may be written there too).
    Record(u8, Vec<u8>),
}

/// A chunk as read: its compression, uncompressed size and CRC, and its compressed records.
struct Compressed {
    compression: String,
    size: usize,
    crc: u32,
    data: Vec<u8>,
}

/// Streams the samples of `stream` from the MCAP file at `path`.
pub fn read(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    samples(path, None, stream, topics, visit, progress)
}

/// Streams the samples of `stream` from the MCAP file at `path` while it is being written: at its
/// end, waits for more, until the file is complete (its footer read) or has not grown for `idle`
/// (a record cut off there is not read). A file not there yet is waited for as long.
pub fn follow(
    path: &Path,
    idle: Duration,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let started = Instant::now();
    while !path.exists() && started.elapsed() < idle {
        std::thread::sleep(POLL);
    }
    samples(path, Some(idle), stream, topics, visit, progress)
}

/// How often a followed file is looked at for more bytes.
const POLL: Duration = Duration::from_millis(50);

/// [`read`], or [`follow`] with `follow` the idle time.
fn samples(
    path: &Path,
    follow: Option<Duration>,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let mut schemas: HashMap<u16, String> = HashMap::new();
    // By channel id: a lookup per message without hashing.
    let mut channels: Vec<Option<ChannelKind>> = Vec::new();
    let mut stats = PassStats::default();
    let mut frames = FrameNames::default();
    let size = blocks(path, follow, progress, &mut |opcode, data| match opcode {
        op::MESSAGE => {
            let Some((channel, body)) = message_body(data) else {
                stats
                    .general(stream)
                    .problem("a message record shorter than its header".into());
                return Ok(());
            };
            match channels.get(usize::from(channel)).and_then(Option::as_ref) {
                Some(kind) => Ok(deliver(
                    kind,
                    body,
                    stream,
                    topics,
                    &mut frames,
                    &mut stats,
                    visit,
                )?),
                None => {
                    stats
                        .general(stream)
                        .problem(format!("a message on unknown channel {channel}"));
                    Ok(())
                }
            }
        }
        op::SCHEMA | op::CHANNEL => {
            match lengths_fit(opcode, data).and_then(|()| mcap::parse_record(opcode, data)) {
                Ok(Record::Schema { header, .. }) => {
                    schemas.insert(header.id, header.name);
                }
                Ok(Record::Channel(c)) => {
                    let schema = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                    let kind = ChannelKind::of(&c.topic, &schema, &c.message_encoding, topics);
                    let id = usize::from(c.id);
                    if channels.len() <= id {
                        channels.resize(id + 1, None);
                    }
                    channels[id] = Some(kind);
                }
                Ok(_) => {}
                Err(e) => return Err(RecordError::Mcap(e)),
            }
            Ok(())
        }
        _ => Ok(()),
    });
    size.map(|_| stats)
}

/// Decompresses and walks every record of the MCAP file at `path` without decoding any message
/// (the least a reader must do); returns the number of messages.
pub fn bare_pass(path: &Path) -> Result<u64, LogError> {
    let mut messages = 0u64;
    blocks(path, None, &mut |_| {}, &mut |opcode, _| {
        messages += u64::from(opcode == op::MESSAGE);
        Ok(())
    })?;
    Ok(messages)
}

/// What is done with each record: its opcode and body.
type RecordVisitor<'a> = dyn FnMut(u8, &[u8]) -> Result<(), RecordError> + 'a;

/// Why a record could not be handled.
enum RecordError {
    /// The visitor stopped.
    Visit(LogError),
    /// The record is damaged.
    Mcap(mcap::McapError),
}

impl From<LogError> for RecordError {
    fn from(e: LogError) -> Self {
        RecordError::Visit(e)
    }
}

/// Hands every record of the file at `path` to `record`, chunks decompressed, in file order
/// (following the file as it grows for `follow`'s idle time); returns the file size.
fn blocks(
    path: &Path,
    follow: Option<Duration>,
    progress: &mut dyn FnMut(u64),
    record: &mut RecordVisitor<'_>,
) -> Result<u64, LogError> {
    let io_error = |source| LogError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = File::open(path).map_err(io_error)?;
    let size = file.metadata().map_err(io_error)?.len();
    let mcap_error = |e: mcap::McapError| LogError::Mcap {
        path: path.to_path_buf(),
        reason: damage(&e, size),
    };
    std::thread::scope(|scope| {
        let (blocks, received) = sync_channel(IN_FLIGHT);
        let (recycle, recycled) = channel();
        let producer = scope.spawn(move || produce(file, size, follow, &blocks, &recycled));
        let mut outcome = Ok(());
        for (block, read_bytes) in &received {
            let handled = match &block {
                Block::Chunk(records) => walk(records, record),
                Block::Record(opcode, data) => record(*opcode, data),
            };
            if let Err(e) = handled {
                outcome = Err(e);
                break;
            }
            if let Block::Chunk(buffer) = block {
                let _ = recycle.send(buffer);
            }
            progress(read_bytes);
        }
        // Stops the producer if the loop ended early.
        drop(received);
        // A producer that panicked read only part of the file: never a silent short read.
        let produced = producer.join().unwrap_or_else(|_| {
            Err(mcap::McapError::DecompressionError(
                "the reading thread stopped unexpectedly".into(),
            ))
        });
        match (outcome, produced) {
            (Err(RecordError::Visit(e)), _) => Err(e),
            (Err(RecordError::Mcap(e)), _) | (Ok(()), Err(e)) => Err(mcap_error(e)),
            (Ok(()), Ok(())) => Ok(size),
        }
    })
}

/// The producer: reads the file, decompresses its chunks a batch at a time in parallel, and
/// sends every block in file order with the bytes read so far. Stops at the first error (returned)
/// or when the receiver is gone; a followed file (`follow`: the idle time) is read as it grows.
fn produce(
    mut file: File,
    size: u64,
    follow: Option<Duration>,
    blocks: &SyncSender<(Block, u64)>,
    recycled: &Receiver<Vec<u8>>,
) -> Result<(), mcap::McapError> {
    // Lengths come from the file: a damaged one may claim exabytes. No record can be longer than
    // the file, nor a chunk decompress to more than MAX_INFLATION times its size (zstd's best
    // ratio on skin logs is far below).
    let limit = match follow {
        // A file being written is no longer than what is written next.
        Some(_) => MAX_RECORD,
        None => usize::try_from(size.saturating_mul(MAX_INFLATION))
            .unwrap_or(usize::MAX)
            .clamp(1 << 20, MAX_RECORD),
    };
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_record_length_limit(limit),
    );
    // Chunks being decompressed, in file order: each on the thread pool as soon as it is read,
    // so reading overlaps decompressing.
    let mut pending: Decompressing = InOrder::new();
    let mut read_bytes = 0u64;
    // Sends the oldest chunk on once it is decompressed; false when the receiver is gone.
    let forward = |pending: &mut Decompressing, read_bytes: u64| -> Result<bool, mcap::McapError> {
        let Some(decompressed) = pending.next() else {
            return Ok(true);
        };
        let records = decompressed.unwrap_or_else(|_| {
            Err(mcap::McapError::DecompressionError(
                "decompressing a chunk failed unexpectedly".into(),
            ))
        })?;
        Ok(blocks.send((Block::Chunk(records), read_bytes)).is_ok())
    };
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(need) => {
                let buffer = reader.insert(need.max(1 << 20));
                let mut n = file.read(buffer)?;
                if let Some(idle) = follow {
                    let since = Instant::now();
                    while n == 0 {
                        if since.elapsed() >= idle {
                            // The writer stopped: what it wrote whole has been read.
                            return drain(&mut pending, &forward, read_bytes);
                        }
                        std::thread::sleep(POLL);
                        n = file.read(buffer)?;
                    }
                }
                reader.notify_read(n);
                read_bytes += n as u64;
            }
            LinearReadEvent::Record { opcode, data } => match opcode {
                op::CHUNK => {
                    lengths_fit(opcode, data)?;
                    let Record::Chunk { header, data } = mcap::parse_record(opcode, data)? else {
                        continue;
                    };
                    let size = usize::try_from(header.uncompressed_size)
                        .ok()
                        .filter(|&s| s <= limit)
                        .ok_or_else(|| mcap::McapError::ChunkTooLarge(header.uncompressed_size))?;
                    let chunk = Compressed {
                        compression: header.compression,
                        size,
                        crc: header.uncompressed_crc,
                        data: data.to_vec(),
                    };
                    let buffer = recycled.try_recv().unwrap_or_default();
                    pending.spawn(move || decompress(chunk, buffer));
                    while pending.len() > DECOMPRESSING {
                        if !forward(&mut pending, read_bytes)? {
                            return Ok(());
                        }
                    }
                }
                op::SCHEMA | op::CHANNEL | op::MESSAGE => {
                    while !pending.is_empty() {
                        if !forward(&mut pending, read_bytes)? {
                            return Ok(());
                        }
                    }
                    let block = Block::Record(opcode, data.to_vec());
                    if blocks.send((block, read_bytes)).is_err() {
                        return Ok(());
                    }
                }
                _ => {}
            },
        }
    }
    drain(&mut pending, &forward, read_bytes)
}

/// Chunks being decompressed, in file order.
type Decompressing = InOrder<Result<Vec<u8>, mcap::McapError>>;

/// Sends every chunk still being decompressed on, in order.
fn drain(
    pending: &mut Decompressing,
    forward: &dyn Fn(&mut Decompressing, u64) -> Result<bool, mcap::McapError>,
    read_bytes: u64,
) -> Result<(), mcap::McapError> {
    while !pending.is_empty() {
        if !forward(pending, read_bytes)? {
            return Ok(());
        }
    }
    Ok(())
}

/// A chunk's records, decompressed into `buffer` and checked against the chunk's CRC.
fn decompress(chunk: Compressed, mut buffer: Vec<u8>) -> Result<Vec<u8>, mcap::McapError> {
    buffer.clear();
    match chunk.compression.as_str() {
        "" => buffer.extend_from_slice(&chunk.data),
        "zstd" => {
            buffer.reserve(chunk.size);
            thread_local! {
                // One decompression context per thread, kept: making one costs as much as a
                // small chunk.
                static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
                    const { std::cell::RefCell::new(None) };
            }
            ZSTD.with(|cell| -> std::io::Result<()> {
                let mut cell = cell.borrow_mut();
                if cell.is_none() {
                    *cell = Some(zstd::bulk::Decompressor::new()?);
                }
                let decompressor = cell.as_mut().expect("made above");
                decompressor.decompress_to_buffer(&chunk.data, &mut buffer)?;
                Ok(())
            })?;
        }
        "lz4" => {
            buffer.resize(chunk.size, 0);
            lz4::Decoder::new(chunk.data.as_slice())?.read_exact(&mut buffer)?;
        }
        other => return Err(mcap::McapError::UnsupportedCompression(other.into())),
    }
    if buffer.len() != chunk.size {
        return Err(mcap::McapError::DecompressionError(format!(
            "a chunk decompressed to {} bytes, not the {} its header gives",
            buffer.len(),
            chunk.size
        )));
    }
    if chunk.crc != 0 {
        let crc = crc32fast::hash(&buffer);
        if crc != chunk.crc {
            return Err(mcap::McapError::BadChunkCrc {
                saved: chunk.crc,
                calculated: crc,
            });
        }
    }
    Ok(buffer)
}

/// Hands every record of a decompressed chunk (`opcode u8, length u64, body`) to `record`.
fn walk(records: &[u8], record: &mut RecordVisitor<'_>) -> Result<(), RecordError> {
    let mut at = 0usize;
    while at < records.len() {
        let header = records
            .get(at..at + 9)
            .ok_or_else(|| RecordError::Mcap(mcap::McapError::UnexpectedEoc))?;
        let opcode = header[0];
        let len = u64::from_le_bytes(header[1..9].try_into().expect("8 bytes"));
        let body = usize::try_from(len)
            .ok()
            .and_then(|len| records.get(at + 9..(at + 9).checked_add(len)?))
            .ok_or_else(|| RecordError::Mcap(mcap::McapError::RecordTooLarge { opcode, len }))?;
        record(opcode, body)?;
        at += 9 + body.len();
    }
    Ok(())
}

/// What a reader error means for the user's file, and what to do.
fn damage(e: &mcap::McapError, size: u64) -> String {
    use mcap::McapError as E;
    let salvage = "copy it again, or salvage its complete part with `mcap recover`";
    match e {
        _ if size == 0 => "the file is empty: was the recording started?".into(),
        _ if size < 8 => format!("{size} bytes are too few for an MCAP file"),
        E::BadMagic => "it does not start with MCAP's magic bytes: give a ROS 2 bag recorded with \
                        `--storage mcap` (or its .mcap file)"
            .into(),
        E::UnexpectedEof => format!(
            "it ends in the middle of a record after {size} bytes: it was cut short (recording \
             interrupted, or an incomplete copy); {salvage}"
        ),
        E::RecordTooLarge { opcode, len } => format!(
            "a record (opcode {opcode:#04x}) claims {len} bytes, more than a {size}-byte file \
             can hold: the file is damaged; {salvage}"
        ),
        E::ChunkTooLarge(len) => format!(
            "a chunk claims {len} bytes, more than a {size}-byte file can hold: the file is \
             damaged; {salvage}"
        ),
        E::BadChunkCrc { .. } | E::BadDataCrc { .. } | E::BadSummaryCrc { .. } => {
            format!("{e}: the file is damaged; {salvage}")
        }
        other => format!("{other}; if the file is damaged, {salvage}"),
    }
}

/// Checks that every length inside a schema, channel or chunk record fits in the record before the mcap
/// crate parses it (it allocates a string's claimed length first).
fn lengths_fit(opcode: u8, data: &[u8]) -> Result<(), mcap::McapError> {
    let mut at;
    let bytes = |at: &mut usize, limit: usize| -> Option<()> {
        let field: [u8; 4] = data.get(*at..*at + 4)?.try_into().ok()?;
        let n = u32::from_le_bytes(field) as usize;
        *at += 4;
        (n <= limit.saturating_sub(*at)).then(|| *at += n)
    };
    let fits = match opcode {
        // id u16, name, encoding, data
        op::SCHEMA => {
            at = 2;
            (0..3).try_for_each(|_| bytes(&mut at, data.len()))
        }
        // id u16, schema_id u16, topic, message_encoding, metadata map<string, string>
        op::CHANNEL => {
            at = 4;
            (0..2)
                .try_for_each(|_| bytes(&mut at, data.len()))
                .and_then(|()| {
                    let start = at + 4;
                    bytes(&mut at, data.len())?;
                    let end = at;
                    let mut entry = start;
                    while entry < end {
                        bytes(&mut entry, end)?;
                        bytes(&mut entry, end)?;
                    }
                    Some(())
                })
        }
        // message_start_time u64, message_end_time u64, uncompressed_size u64,
        // uncompressed_crc u32, compression, records
        op::CHUNK => {
            at = 28;
            bytes(&mut at, data.len())
        }
        _ => Some(()),
    };
    fits.ok_or(mcap::McapError::RecordTooLarge {
        opcode,
        len: data.len() as u64,
    })
}

/// Channel id and CDR payload of a message record (opcode 0x05): `channel_id u16, sequence u32,
/// log_time u64, publish_time u64, data`.
fn message_body(record: &[u8]) -> Option<(u16, &[u8])> {
    const HEADER: usize = 2 + 4 + 8 + 8;
    if record.len() < HEADER {
        return None;
    }
    let channel = u16::from_le_bytes([record[0], record[1]]);
    Some((channel, &record[HEADER..]))
}
