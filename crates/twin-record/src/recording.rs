//! Read recordings made by [`crate::record::Recorder`]: summary (`inspect`), CSV export,
//! the run's metadata (for `replay`), and comparison of two recordings (`diff`, `replay`).
//!
//! Everything streams through the file once with the `mcap` crate's linear reader, so
//! memory does not grow with the recording's length. Chunk CRCs are checked before a
//! chunk's messages are used, so a truncated file (a killed run) yields exactly the
//! messages of its complete chunks, followed by an error that says so; a file that is not
//! MCAP at all is an error. Nothing here panics on a malformed file.

use std::collections::BTreeMap;
use std::fmt;
use std::fs::File;
use std::io::{Read as _, Seek as _, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context as _, anyhow, bail};
use csp::cfp::CanFrame;
use mcap::McapError;
use mcap::records::{Metadata, Record};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use serde::de::{DeserializeSeed, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::Value;

use crate::record::{
    AdcsMsg, BeginFields, CanFramesMsg, CommandMsg, CspPacketMsg, ExpectationMsg, KissFrameMsg,
    METADATA_NAME, NetPacketMsg, RecordingMeta, SCENARIO_ATTACHMENT, TOPIC_ADCS, TOPIC_COMMANDS,
    TOPIC_CSP, TOPIC_EXPECTATIONS, TOPIC_TRUTH_STATE, TruthStateMsg, service_name,
};

/// Largest record the reader accepts, compressed or not: twice the recorder's chunk (4 MiB;
/// a chunk passes its size by at most one message, and recordings before format 6 had 1 MiB
/// chunks). A corrupt length beyond it is an error, never an allocation.
const RECORD_LIMIT: usize = 2 * crate::record::CHUNK_SIZE as usize;

/// The reader asks for at most this many bytes of the file at a time, so a record length
/// beyond the end of the file costs a read to the end, not an allocation of that length.
const READ_STEP: usize = 1 << 20;

/// One message of a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedMessage {
    /// Channel topic.
    pub topic: Arc<str>,
    /// Schema name of the channel (empty when it has none).
    pub schema: Arc<str>,
    /// The schema's encoding (`protobuf`; `jsonschema` in recordings of format 2).
    pub schema_encoding: Arc<str>,
    /// The schema's bytes (a `FileDescriptorSet` for `protobuf`).
    pub schema_data: Arc<[u8]>,
    /// Log time, ns since the Unix epoch (simulated).
    pub log_time: u64,
    /// The message bytes (protobuf; JSON in recordings of format 2).
    pub data: Vec<u8>,
}

impl RecordedMessage {
    /// The message decoded with its schema, as JSON ([`crate::protobuf::decode`]).
    pub fn json(&self) -> anyhow::Result<Value> {
        crate::protobuf::decode(
            &self.schema,
            &self.schema_encoding,
            &self.schema_data,
            &self.data,
        )
        .with_context(|| format!("a message on {}", self.topic))
    }

    /// [`RecordedMessage::json`] as JSON text, the fields in schema order.
    pub fn json_text(&self) -> anyhow::Result<Vec<u8>> {
        crate::protobuf::decode_text(
            &self.schema,
            &self.schema_encoding,
            &self.schema_data,
            &self.data,
        )
        .with_context(|| format!("a message on {}", self.topic))
    }

    /// The message decoded into `T` (through [`RecordedMessage::json`]).
    pub fn decode<T: serde::de::DeserializeOwned>(&self) -> anyhow::Result<T> {
        Ok(serde_json::from_value(self.json()?)?)
    }
}

/// A schema as the reader keeps it.
#[derive(Debug, Clone)]
struct SchemaInfo {
    name: Arc<str>,
    encoding: Arc<str>,
    data: Arc<[u8]>,
}

impl Default for SchemaInfo {
    fn default() -> Self {
        SchemaInfo {
            name: Arc::from(""),
            encoding: Arc::from(""),
            data: Arc::from(&[][..]),
        }
    }
}

/// A top-level item of the file, in file order.
#[derive(Debug)]
enum Item {
    Header {
        library: String,
    },
    Message(RecordedMessage),
    Metadata(Metadata),
    Attachment {
        name: String,
        log_time: u64,
        data: Vec<u8>,
    },
    /// A summary record after the data section ended.
    Summary,
}

/// The records the reader decodes: header, schema, channel, message, attachment,
/// metadata, data end.
const USED_OPCODES: [u8; 7] = [0x01, 0x03, 0x04, 0x05, 0x09, 0x0c, 0x0f];

/// What is wrong in a record or a chunk, found before its bytes are trusted (`what` names
/// the field: `schema name`, `chunk records`).
#[derive(Debug, thiserror::Error)]
enum Malformed {
    #[error("{what} claims {claimed} bytes, {left} are left in the record")]
    PastRecord {
        what: &'static str,
        claimed: usize,
        left: usize,
    },
    #[error("{what}: record too short for its length")]
    TooShort { what: &'static str },
    #[error("{what}: length overflow")]
    LengthOverflow { what: &'static str },
    #[error(
        "chunk claims {size} uncompressed bytes, more than the {RECORD_LIMIT} a recording holds"
    )]
    ChunkTooLarge { size: u64 },
    #[error("zstd decompressor: {0}")]
    Decompressor(std::io::Error),
    #[error("chunk does not decompress (zstd): {0}")]
    Decompress(std::io::Error),
    #[error("chunk compression {compression:?} is not supported (zstd or none)")]
    Compression { compression: String },
    #[error("chunk holds {held} bytes of records, it claims {claimed}")]
    ChunkSize { held: usize, claimed: usize },
    #[error("chunk CRC mismatch (saved {saved:#010x}, calculated {calculated:#010x})")]
    ChunkCrc { saved: u32, calculated: u32 },
    #[error("the chunk ends inside a record's header")]
    ChunkRecordHeader,
    #[error("a record (opcode {opcode:#04x}) claims {len} bytes, {left} are left in its chunk")]
    PastChunk { opcode: u8, len: usize, left: usize },
}

/// The unread rest of a record's body, read with its lengths checked.
struct Body<'a>(&'a [u8]);
impl<'a> Body<'a> {
    fn skip(&mut self, n: usize, what: &'static str) -> Result<(), Malformed> {
        self.bytes(n, what).map(drop)
    }
    fn bytes(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], Malformed> {
        if n > self.0.len() {
            return Err(Malformed::PastRecord {
                what,
                claimed: n,
                left: self.0.len(),
            });
        }
        let (b, rest) = self.0.split_at(n);
        self.0 = rest;
        Ok(b)
    }
    fn take<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], Malformed> {
        let b: [u8; N] = self
            .0
            .get(..N)
            .and_then(|b| b.try_into().ok())
            .ok_or(Malformed::TooShort { what })?;
        self.0 = &self.0[N..];
        Ok(b)
    }
    fn len32(&mut self, what: &'static str) -> Result<usize, Malformed> {
        Ok(u32::from_le_bytes(self.take(what)?) as usize)
    }
    fn len64(&mut self, what: &'static str) -> Result<usize, Malformed> {
        usize::try_from(u64::from_le_bytes(self.take(what)?))
            .map_err(|_| Malformed::LengthOverflow { what })
    }
    fn string(&mut self, what: &'static str) -> Result<(), Malformed> {
        let n = self.len32(what)?;
        self.skip(n, what)
    }
    fn string_map(&mut self, what: &'static str) -> Result<(), Malformed> {
        let n = self.len32(what)?;
        if n > self.0.len() {
            return self.skip(n, what);
        }
        let mut inner = Body(&self.0[..n]);
        while !inner.0.is_empty() {
            inner.string(what)?;
            inner.string(what)?;
        }
        self.skip(n, what)
    }
}

/// Check every length prefix of a record the reader decodes (MCAP spec, records section)
/// against the bytes the record has, before the decoder trusts them.
fn check_lengths(opcode: u8, data: &[u8]) -> Result<(), Malformed> {
    let mut b = Body(data);
    match opcode {
        0x01 => {
            b.string("header profile")?;
            b.string("header library")
        }
        0x03 => {
            b.skip(2, "schema id")?;
            b.string("schema name")?;
            b.string("schema encoding")?;
            let n = b.len32("schema data")?;
            b.skip(n, "schema data")
        }
        0x04 => {
            b.skip(4, "channel ids")?;
            b.string("channel topic")?;
            b.string("channel message encoding")?;
            b.string_map("channel metadata")
        }
        0x09 => {
            b.skip(16, "attachment times")?;
            b.string("attachment name")?;
            b.string("attachment media type")?;
            let n = b.len64("attachment data")?;
            b.skip(n, "attachment data")
        }
        0x0c => {
            b.string("metadata name")?;
            b.string_map("metadata")
        }
        _ => Ok(()),
    }
}

/// The MCAP opcode of a chunk.
const OP_CHUNK: u8 = 0x06;

/// The records of a chunk record's body (MCAP spec: start and end time, uncompressed size
/// and CRC, compression, the records' length, the records), decompressed and checked
/// against the sizes and the CRC the chunk states, into `out` (its buffer reused). At most
/// [`RECORD_LIMIT`] bytes.
fn unpack_chunk(
    data: &[u8],
    zstd: &mut Option<zstd::bulk::Decompressor<'static>>,
    out: &mut Vec<u8>,
) -> Result<(), Malformed> {
    let mut b = Body(data);
    b.skip(16, "chunk times")?;
    let size = u64::from_le_bytes(b.take("chunk uncompressed size")?);
    let crc = u32::from_le_bytes(b.take("chunk uncompressed crc")?);
    let n = b.len32("chunk compression")?;
    let compression = b.bytes(n, "chunk compression")?.to_vec();
    let n = b.len64("chunk records")?;
    let records = b.bytes(n, "chunk records")?;
    let size = usize::try_from(size)
        .ok()
        .filter(|&n| n <= RECORD_LIMIT)
        .ok_or(Malformed::ChunkTooLarge { size })?;
    out.clear();
    match compression.as_slice() {
        b"" => out.extend_from_slice(records),
        b"zstd" => {
            let z = match zstd {
                Some(z) => z,
                None => {
                    zstd.insert(zstd::bulk::Decompressor::new().map_err(Malformed::Decompressor)?)
                }
            };
            out.reserve_exact(size);
            z.decompress_to_buffer(records, out)
                .map_err(Malformed::Decompress)?;
        }
        other => {
            return Err(Malformed::Compression {
                compression: String::from_utf8_lossy(other).into_owned(),
            });
        }
    }
    if out.len() != size {
        return Err(Malformed::ChunkSize {
            held: out.len(),
            claimed: size,
        });
    }
    // A CRC of 0 means none was computed (MCAP spec).
    let calculated = crc32fast::hash(out);
    if crc != 0 && calculated != crc {
        return Err(Malformed::ChunkCrc {
            saved: crc,
            calculated,
        });
    }
    Ok(())
}

/// The next record of a chunk's `records` from `*pos`: its opcode and body, `*pos` moved
/// past it. A record header or body running past the chunk is an error.
fn next_chunk_record<'a>(records: &'a [u8], pos: &mut usize) -> Result<(u8, &'a [u8]), Malformed> {
    let rest = &records[*pos..];
    let mut b = Body(rest);
    let [opcode] = b
        .take::<1>("chunk record opcode")
        .map_err(|_| Malformed::ChunkRecordHeader)?;
    let len = b
        .len64("chunk record")
        .map_err(|_| Malformed::ChunkRecordHeader)?;
    let body = b.bytes(len, "").map_err(|_| Malformed::PastChunk {
        opcode,
        len,
        left: rest.len() - 9,
    })?;
    *pos += 9 + len;
    Ok((opcode, body))
}

/// Whether `file` ends with the MCAP magic; leaves it positioned at its start.
fn ends_with_magic(file: &mut File) -> std::io::Result<bool> {
    let len = file.metadata()?.len();
    let mut tail = [0u8; 8];
    let ends = if len >= 16 {
        file.seek(SeekFrom::End(-8))?;
        file.read_exact(&mut tail)?;
        tail == mcap::MAGIC
    } else {
        false
    };
    file.seek(SeekFrom::Start(0))?;
    Ok(ends)
}

/// Streaming reader of one file's records.
struct Reader {
    path: PathBuf,
    file: File,
    reader: LinearReader,
    schemas: BTreeMap<u16, SchemaInfo>,
    channels: BTreeMap<u16, (Arc<str>, SchemaInfo)>,
    records: u64,
    messages: u64,
    past_data_end: bool,
    /// Whether the file ends with the MCAP magic (a writer finished it).
    finished: bool,
    done: bool,
    /// Bytes of the file read so far (where an error was met, within a chunk's length).
    offset: u64,
    /// The file's length.
    file_len: u64,
    /// The records of the chunk being read (decompressed), and where the next one starts.
    chunk: Vec<u8>,
    chunk_pos: usize,
    /// The zstd context, made at the first compressed chunk and reused.
    zstd: Option<zstd::bulk::Decompressor<'static>>,
}

impl Reader {
    fn open(path: &Path) -> anyhow::Result<Reader> {
        let ctx = || format!("opening recording {}", path.display());
        let mut file = File::open(path).with_context(ctx)?;
        let finished = ends_with_magic(&mut file).with_context(ctx)?;
        let file_len = file.metadata().with_context(ctx)?.len();
        let options = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true)
            .with_record_length_limit(RECORD_LIMIT)
            // Chunks are unpacked here: mcap 0.26's reader trusts the length of a record
            // inside an uncompressed chunk (an overflow past the chunk's end).
            .with_emit_chunks(true);
        Ok(Reader {
            path: path.to_owned(),
            file,
            reader: LinearReader::new_with_options(options),
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            records: 0,
            messages: 0,
            past_data_end: false,
            finished,
            done: false,
            offset: 0,
            file_len,
            chunk: Vec::new(),
            chunk_pos: 0,
            zstd: None,
        })
    }

    /// Whether nothing of the file could be read (not even its header).
    fn nothing_read(&self) -> bool {
        self.records == 0
    }

    /// Describe a reader error, with where it happened.
    fn error(&self, e: McapError) -> anyhow::Error {
        let path = self.path.display();
        let n = self.messages;
        let at = format!("byte offset {} of {}", self.offset, self.file_len);
        match e {
            McapError::UnexpectedEof if self.finished => {
                anyhow!(
                    "{path}: a record runs past the end of the file at {at} (a damaged length; \
                     {n} messages read)"
                )
            }
            McapError::BadMagic if self.records == 0 => {
                anyhow!("{path}: not an MCAP file (bad magic)")
            }
            McapError::UnexpectedEof if self.past_data_end => {
                anyhow!("{path}: truncated in its summary section after all {n} messages were read")
            }
            McapError::UnexpectedEof if self.records == 0 => {
                anyhow!("{path}: not an MCAP file (too short)")
            }
            // A file that does not end with the magic was never finished: a killed writer
            // leaves its open chunk with placeholder lengths, or the copy was cut.
            e if !self.finished && self.records > 0 => anyhow!(
                "{path}: truncated (a killed run?): {e} at {at}; read up to the last complete \
                 chunk, {n} messages"
            ),
            McapError::RecordTooLarge { opcode, len } => anyhow!(
                "{path}: a record (opcode {opcode:#04x}) near {at} claims {len} bytes, more \
                 than the {RECORD_LIMIT} a recording holds (a damaged length; {n} messages read)"
            ),
            e => anyhow!("{path}: malformed MCAP after {n} messages, near {at}: {e}"),
        }
    }

    /// The next item, `None` at the clean end of the file. Nothing after an error.
    fn next_item(&mut self) -> Option<anyhow::Result<Item>> {
        if self.done {
            return None;
        }
        let r = self.next_inner();
        if !matches!(r, Some(Ok(_))) {
            self.done = true;
        }
        r
    }

    fn next_inner(&mut self) -> Option<anyhow::Result<Item>> {
        loop {
            if self.chunk_pos < self.chunk.len() {
                let chunk = std::mem::take(&mut self.chunk);
                let r = match next_chunk_record(&chunk, &mut self.chunk_pos) {
                    Ok((opcode, data)) => self.decode(opcode, data),
                    Err(why) => Some(Err(self.malformed(why))),
                };
                self.chunk = chunk;
                match r {
                    Some(r) => return Some(r),
                    None => continue,
                }
            }
            let event = match self.reader.next_event()? {
                Ok(ev) => ev,
                Err(e) => {
                    let err = self.error(e);
                    return Some(Err(err));
                }
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need.min(READ_STEP));
                    let n = loop {
                        match self.file.read(buf) {
                            Ok(n) => break n,
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                            Err(e) => {
                                return Some(Err(anyhow!(e).context(format!(
                                    "reading recording {}",
                                    self.path.display()
                                ))));
                            }
                        }
                    };
                    self.reader.notify_read(n);
                    self.offset += n as u64;
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            if opcode == OP_CHUNK && !self.past_data_end {
                match unpack_chunk(data, &mut self.zstd, &mut self.chunk) {
                    Ok(()) => {
                        self.records += 1;
                        self.chunk_pos = 0;
                        continue;
                    }
                    Err(why) => {
                        self.chunk.clear();
                        return Some(Err(self.malformed(why)));
                    }
                }
            }
            if !self.past_data_end && !USED_OPCODES.contains(&opcode) {
                self.records += 1;
                continue;
            }
            let data = data.to_vec();
            if let Some(r) = self.decode(opcode, &data) {
                return Some(r);
            }
        }
    }

    /// An error in the record read last, with where.
    fn malformed(&self, why: impl fmt::Display) -> anyhow::Error {
        anyhow!(
            "{}: malformed MCAP after {} messages, near byte offset {} of {}: {why}",
            self.path.display(),
            self.messages,
            self.offset,
            self.file_len
        )
    }

    /// Decode one record, of the file or of a chunk: the item it is, `None` for a record
    /// that only updates the reader (schema, channel, data end) or that it does not use.
    fn decode(&mut self, opcode: u8, data: &[u8]) -> Option<anyhow::Result<Item>> {
        // The summary section repeats what was read; records this reader does not use
        // are not decoded. The others' length prefixes are checked first: the decoder
        // reserves what a string's prefix claims.
        if self.past_data_end {
            self.records += 1;
            return Some(Ok(Item::Summary));
        }
        if !USED_OPCODES.contains(&opcode) {
            self.records += 1;
            return None;
        }
        if let Err(why) = check_lengths(opcode, data) {
            return Some(Err(self.malformed(format!("record {opcode:#04x}: {why}"))));
        }
        let record = match mcap::parse_record(opcode, data) {
            Ok(r) => r,
            Err(e) => return Some(Err(self.error(e))),
        };
        self.records += 1;
        let item = match record {
            Record::Header(h) => Item::Header { library: h.library },
            Record::DataEnd(_) => {
                self.past_data_end = true;
                return None;
            }
            Record::Schema { header, data } => {
                let info = SchemaInfo {
                    name: header.name.into(),
                    encoding: header.encoding.into(),
                    data: Arc::from(&*data),
                };
                self.schemas.insert(header.id, info);
                return None;
            }
            Record::Channel(c) => {
                let schema = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                self.channels.insert(c.id, (c.topic.into(), schema));
                return None;
            }
            Record::Message { header, data } => {
                let Some((topic, schema)) = self.channels.get(&header.channel_id) else {
                    return Some(Err(anyhow!(
                        "{}: malformed MCAP: message {} on unknown channel {}",
                        self.path.display(),
                        self.messages,
                        header.channel_id
                    )));
                };
                self.messages += 1;
                Item::Message(RecordedMessage {
                    topic: topic.clone(),
                    schema: schema.name.clone(),
                    schema_encoding: schema.encoding.clone(),
                    schema_data: schema.data.clone(),
                    log_time: header.log_time,
                    data: data.into_owned(),
                })
            }
            Record::Metadata(m) => Item::Metadata(m),
            Record::Attachment { header, data, .. } => Item::Attachment {
                name: header.name,
                log_time: header.log_time,
                data: data.into_owned(),
            },
            _ => return None,
        };
        Some(Ok(item))
    }

    /// The next message, `None` at the end.
    fn next_message(&mut self) -> Option<anyhow::Result<RecordedMessage>> {
        loop {
            match self.next_item()? {
                Ok(Item::Message(m)) => return Some(Ok(m)),
                Ok(_) => continue,
                Err(e) => return Some(Err(e)),
            }
        }
    }

    /// Topics of the channels seen so far, by channel id.
    fn topics(&self) -> Vec<String> {
        self.channels.values().map(|(t, _)| t.to_string()).collect()
    }
}

/// Every message of a recording, in file order (see [`messages`]).
pub struct Messages {
    reader: Reader,
}

impl fmt::Debug for Messages {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Messages")
            .field("path", &self.reader.path)
            .field("read", &self.reader.messages)
            .finish_non_exhaustive()
    }
}

impl Iterator for Messages {
    type Item = anyhow::Result<RecordedMessage>;
    fn next(&mut self) -> Option<Self::Item> {
        self.reader.next_message()
    }
}

/// Stream the messages of the recording at `path` in file order; an error (a truncated or
/// malformed file) ends the stream.
pub fn messages(path: &Path) -> anyhow::Result<Messages> {
    Ok(Messages {
        reader: Reader::open(path)?,
    })
}

/// Build the metadata from the `m6p-twin` record and the scenario attachment.
fn meta_from(m: &Metadata, scenario: Option<&[u8]>, path: &Path) -> anyhow::Result<RecordingMeta> {
    let get = |k: &str| {
        m.metadata
            .get(k)
            .cloned()
            .with_context(|| format!("{}: metadata `{METADATA_NAME}` lacks `{k}`", path.display()))
    };
    let seed = get("seed")?;
    let scenario_toml = match scenario {
        Some(bytes) => String::from_utf8(bytes.to_vec()).with_context(|| {
            format!(
                "{}: attachment {SCENARIO_ATTACHMENT} is not UTF-8",
                path.display()
            )
        })?,
        None => bail!(
            "{}: no attachment {SCENARIO_ATTACHMENT} (the scenario text)",
            path.display()
        ),
    };
    Ok(RecordingMeta {
        scenario_name: get("scenario_name")?,
        scenario_toml,
        seed: seed
            .parse()
            .with_context(|| format!("{}: metadata seed {seed:?} is not a u64", path.display()))?,
        start_utc: get("start_utc")?,
        twin_version: get("twin_version")?,
        duration_ns: m.metadata.get("duration_ns").and_then(|d| d.parse().ok()),
        link_addrs: m
            .metadata
            .get("link_addrs")
            .map(|l| crate::record::parse_link_addrs(l))
            .unwrap_or_default(),
        link_tx_budgets: m
            .metadata
            .get("link_tx_budgets")
            .map(|l| crate::record::parse_link_budgets(l))
            .unwrap_or_default(),
        channels: match m.metadata.get("channels") {
            Some(rules) => twin_scenario::channels::parse_rules(rules)
                .with_context(|| format!("{}: metadata `channels` {rules:?}", path.display()))?,
            None => Vec::new(),
        },
        // Older recordings have none: only a scenario's `replaces` replaced nodes then.
        replaced: m
            .metadata
            .get("replaced")
            .map(|r| r.split(',').filter_map(|a| a.trim().parse().ok()).collect())
            .unwrap_or_default(),
    })
}

/// Read the run's metadata (scenario text, seed, start) from a recording. Stops reading at
/// the first message, since the recorder writes both before any.
pub fn load_meta(path: &Path) -> anyhow::Result<RecordingMeta> {
    let mut r = Reader::open(path)?;
    let mut meta = None;
    let mut scenario = None;
    while let Some(item) = r.next_item() {
        match item? {
            Item::Metadata(m) if m.name == METADATA_NAME => meta = Some(m),
            Item::Attachment { name, data, .. } if name == SCENARIO_ATTACHMENT => {
                scenario = Some(data)
            }
            Item::Message(_) => break,
            _ => {}
        }
        if meta.is_some() && scenario.is_some() {
            break;
        }
    }
    let Some(m) = meta else {
        bail!(
            "{}: no `{METADATA_NAME}` metadata: not a recording made by m6p-twin",
            path.display()
        );
    };
    meta_from(&m, scenario.as_deref(), path)
}

/// Where a recording can be replayed from: the instant it starts at when it was recorded
/// from a snapshot, and the snapshot it carries at or before an instant.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ReplayStart {
    /// The snapshot's instant a resumed recording starts at (metadata
    /// `m6p-twin-resumed`), ns of simulated time.
    pub resumed_at_ns: Option<u64>,
    /// The latest snapshot carried at or before the instant asked for: its instant (ns of
    /// simulated time) and its file's bytes.
    pub snapshot: Option<(u64, Vec<u8>)>,
}

/// Where the recording at `path` can be replayed from to compare from `at_most_ns` of
/// simulated time on (reads the file up to a little after that instant: its snapshots are
/// among its messages).
pub fn replay_start(path: &Path, at_most_ns: u64) -> anyhow::Result<ReplayStart> {
    let mut r = Reader::open(path)?;
    let mut start = ReplayStart::default();
    let mut base_ns = None;
    while let Some(item) = r.next_item() {
        match item? {
            Item::Metadata(m) if m.name == METADATA_NAME => {
                let utc = m.metadata.get("start_utc").with_context(|| {
                    format!(
                        "{}: metadata `{METADATA_NAME}` lacks `start_utc`",
                        path.display()
                    )
                })?;
                base_ns = Some(
                    crate::record::start_ns(utc)
                        .with_context(|| format!("{}: metadata `start_utc`", path.display()))?,
                );
            }
            Item::Metadata(m) if m.name == crate::record::RESUMED_METADATA_NAME => {
                let at = m.metadata.get("at_ns").and_then(|t| t.parse().ok());
                start.resumed_at_ns = Some(at.with_context(|| {
                    format!(
                        "{}: metadata `{}` lacks a number `at_ns`",
                        path.display(),
                        crate::record::RESUMED_METADATA_NAME
                    )
                })?);
            }
            Item::Attachment {
                name,
                log_time,
                data,
            } if name == crate::record::SNAPSHOT_ATTACHMENT => {
                let Some(base) = base_ns else { continue };
                let t = log_time.saturating_sub(base);
                if t <= at_most_ns && start.snapshot.as_ref().is_none_or(|(s, _)| *s <= t) {
                    start.snapshot = Some((t, data));
                }
            }
            // A snapshot is carried when the file has reached its instant less the messages
            // held for log-time order (`crate::log_order`): later messages than that, and
            // none at or before the instant asked for is still to come.
            Item::Message(m)
                if base_ns.is_some_and(|b| {
                    m.log_time.saturating_sub(b)
                        > at_most_ns.saturating_add(2 * crate::log_order::REORDER_WINDOW_NS)
                }) =>
            {
                break;
            }
            _ => {}
        }
    }
    Ok(start)
}

/// Messages on one channel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelSummary {
    /// Topic.
    pub topic: String,
    /// Schema name.
    pub schema: String,
    /// Messages read.
    pub messages: u64,
}

/// Outcome of one scenario command (from `/commands`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommandSummary {
    /// Times sent.
    pub sent: u64,
    /// Times answered.
    pub answered: u64,
    /// Times unanswered (timeout).
    pub unanswered: u64,
}

/// What a recording holds, as `m6p-twin inspect` prints it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Summary {
    /// The run's metadata, when the file has it.
    pub meta: Option<RecordingMeta>,
    /// The header's library field (who wrote the file).
    pub library: String,
    /// Simulated duration covered: the last message's time since the start (ns).
    pub duration_ns: u64,
    /// Messages in all.
    pub messages: u64,
    /// Channels in registration order with their message counts.
    pub channels: Vec<ChannelSummary>,
    /// `/csp/packets` per source address.
    pub packets_per_node: BTreeMap<u8, u64>,
    /// `/csp/packets` per destination port.
    pub packets_per_port: BTreeMap<u8, u64>,
    /// `/commands` per command name.
    pub commands: BTreeMap<String, CommandSummary>,
    /// `/expectations` in file order.
    pub expectations: Vec<ExpectationMsg>,
    /// The last `/fc/truth/state` message (runs that recorded the FC's truth).
    pub truth_last: Option<TruthStateMsg>,
    /// The last `/fc/adcs` message.
    pub adcs_last: Option<AdcsMsg>,
    /// Why a run of this twin recorded no FC truth, if it recorded none.
    pub no_truth: Option<NoTruth>,
    /// Why the file could not be read to its end (truncated or malformed), if so.
    pub incomplete: Option<String>,
}

/// Why a recording holds no `/fc/truth/*` samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoTruth {
    /// The FC had no orbit (no TLE, or SGP4 failing): it publishes no true state then.
    NoOrbit,
    /// The scenario's `[fc] publish_hz` is 0.
    NotPublished,
}

impl Summary {
    /// The scenario name, if recorded.
    pub fn scenario_name(&self) -> Option<&str> {
        self.meta.as_ref().map(|m| m.scenario_name.as_str())
    }

    /// The seed, if recorded.
    pub fn seed(&self) -> Option<u64> {
        self.meta.as_ref().map(|m| m.seed)
    }

    /// Messages read on `topic` (0 if there is no such channel).
    pub fn count(&self, topic: &str) -> u64 {
        self.channels
            .iter()
            .find(|c| c.topic == topic)
            .map_or(0, |c| c.messages)
    }
}

/// Summarize the recording at `path`. A truncated file gives the summary of what could be
/// read, with [`Summary::incomplete`] saying why it stopped; a file with nothing readable
/// is an error.
pub fn read_summary(path: &Path) -> anyhow::Result<Summary> {
    let mut r = Reader::open(path)?;
    let mut s = Summary::default();
    let mut meta = None;
    let mut scenario = None;
    let mut counts: BTreeMap<Arc<str>, u64> = BTreeMap::new();
    let (mut first, mut last) = (u64::MAX, 0u64);
    while let Some(item) = r.next_item() {
        let item = match item {
            Ok(item) => item,
            Err(e) if r.nothing_read() => return Err(e),
            Err(e) => {
                s.incomplete = Some(format!("{e:#}"));
                break;
            }
        };
        match item {
            Item::Header { library } => s.library = library,
            Item::Metadata(m) if m.name == METADATA_NAME => meta = Some(m),
            Item::Attachment { name, data, .. } if name == SCENARIO_ATTACHMENT => {
                scenario = Some(data)
            }
            Item::Message(m) => {
                s.messages += 1;
                first = first.min(m.log_time);
                last = last.max(m.log_time);
                *counts.entry(m.topic.clone()).or_default() += 1;
                summarize_message(&mut s, &m);
            }
            _ => {}
        }
    }
    if let Some(m) = &meta {
        s.meta = Some(meta_from(m, scenario.as_deref(), path)?);
    }
    if s.truth_last.is_none()
        && let Some(m) = &s.meta
    {
        let publish_hz = twin_scenario::scenario::Scenario::parse_with(
            "recorded scenario",
            &m.scenario_toml,
            &[],
        )
        .ok()
        .and_then(|sc| sc.fc.publish_hz);
        s.no_truth = Some(if publish_hz == Some(0) {
            NoTruth::NotPublished
        } else {
            NoTruth::NoOrbit
        });
    }
    let start = s
        .meta
        .as_ref()
        .and_then(|m| twin_core::timefmt::parse_utc(&m.start_utc))
        .and_then(|ns| u64::try_from(ns).ok())
        .unwrap_or(first);
    s.duration_ns = if s.messages == 0 {
        0
    } else {
        last.saturating_sub(start)
    };
    s.channels = r
        .channels
        .values()
        .map(|(topic, schema)| ChannelSummary {
            topic: topic.to_string(),
            schema: schema.name.to_string(),
            messages: counts.get(topic).copied().unwrap_or(0),
        })
        .collect();
    Ok(s)
}

/// Count what one message contributes to the summary (messages that do not decode as this
/// project's JSON are only counted per channel).
fn summarize_message(s: &mut Summary, m: &RecordedMessage) {
    match &*m.topic {
        TOPIC_CSP => {
            if let Ok(p) = m.decode::<CspPacketMsg>() {
                *s.packets_per_node.entry(p.src).or_default() += 1;
                *s.packets_per_port.entry(p.dport).or_default() += 1;
            }
        }
        TOPIC_COMMANDS => {
            if let Ok(c) = m.decode::<CommandMsg>() {
                let e = s.commands.entry(c.name).or_default();
                match c.answered {
                    None => e.sent += 1,
                    Some(true) => e.answered += 1,
                    Some(false) => e.unanswered += 1,
                }
            }
        }
        TOPIC_EXPECTATIONS => {
            if let Ok(x) = m.decode::<ExpectationMsg>() {
                s.expectations.push(x);
            }
        }
        TOPIC_TRUTH_STATE => {
            if let Ok(x) = m.decode::<TruthStateMsg>() {
                s.truth_last = Some(x);
            }
        }
        TOPIC_ADCS => {
            if let Ok(x) = m.decode::<AdcsMsg>() {
                s.adcs_last = Some(x);
            }
        }
        _ => {}
    }
}

/// `x` with `decimals` decimals, `-` when null.
fn opt(x: Option<f64>, decimals: usize) -> String {
    x.map_or_else(|| "-".to_owned(), |v| format!("{v:.decimals$}"))
}

/// `ns` as seconds with nine decimals.
fn secs(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.meta {
            Some(m) => writeln!(
                f,
                "scenario: {} (seed {}), start {}, m6p-twin {}",
                m.scenario_name, m.seed, m.start_utc, m.twin_version
            )?,
            None => writeln!(f, "scenario: unknown (no m6p-twin metadata)")?,
        }
        writeln!(f, "written by: {}", self.library)?;
        writeln!(
            f,
            "duration: {} s simulated, {} messages",
            secs(self.duration_ns),
            self.messages
        )?;
        match self.meta.as_ref().map(|m| &m.channels) {
            Some(rules) if !rules.is_empty() => writeln!(
                f,
                "channels (chosen: {}):",
                twin_scenario::channels::format_rules(rules)
            )?,
            _ => writeln!(f, "channels:")?,
        }
        for c in &self.channels {
            writeln!(f, "  {:<28} {:<24} {:>10}", c.topic, c.schema, c.messages)?;
        }
        if !self.packets_per_node.is_empty() {
            writeln!(f, "CSP packets per source node:")?;
            for (n, c) in &self.packets_per_node {
                writeln!(f, "  {n:>2} {c:>10}")?;
            }
            writeln!(f, "CSP packets per destination port:")?;
            for (p, c) in &self.packets_per_port {
                let name = service_name(*p).unwrap_or("");
                writeln!(f, "  {p:>2} {name:<9} {c:>10}")?;
            }
        }
        if !self.commands.is_empty() {
            writeln!(f, "commands (sent / answered / unanswered):")?;
            for (name, c) in &self.commands {
                writeln!(
                    f,
                    "  {name:<28} {:>6} {:>6} {:>6}",
                    c.sent, c.answered, c.unanswered
                )?;
            }
        }
        if let Some(x) = &self.truth_last {
            writeln!(f, "FC truth at the end (t = {} s):", secs(x.t_ns))?;
            writeln!(
                f,
                "  lat {} deg, lon {} deg, alt {} km; body rate {} deg/s; sun visible {}",
                opt(x.lat_deg, 3),
                opt(x.lon_deg, 3),
                opt(x.alt_m.map(|a| a / 1e3), 3),
                opt(x.rate_deg_s.map(f64::from), 4),
                opt(x.sun_visible_fraction.map(f64::from), 2)
            )?;
        }
        match self.no_truth {
            Some(NoTruth::NoOrbit) => writeln!(f, "FC truth: no orbit (none recorded)")?,
            Some(NoTruth::NotPublished) => writeln!(f, "FC truth: not published (publish_hz = 0)")?,
            None => {}
        }
        if let Some(a) = &self.adcs_last {
            writeln!(
                f,
                "ADCS at the end: mode {} (commanded {}), state {}; pointing error {} deg, \
                 estimation error {} deg",
                a.mode_in_effect,
                a.mode_commanded,
                a.state,
                opt(a.pointing_error_deg.map(f64::from), 3),
                opt(a.estimation_error_deg.map(f64::from), 3)
            )?;
        }
        if !self.expectations.is_empty() {
            writeln!(f, "expectations:")?;
            for x in &self.expectations {
                writeln!(
                    f,
                    "  {} {} at {} s: {}",
                    if x.passed { "PASS" } else { "FAIL" },
                    x.name,
                    secs(x.t_ns),
                    x.observed
                )?;
            }
        }
        if let Some(why) = &self.incomplete {
            writeln!(f, "incomplete: {why}")?;
        }
        Ok(())
    }
}

/// Flattens one JSON document into `(dotted key, cell)` pairs in document order (a
/// `serde_json::Value` would sort the keys): objects recurse (`cfp.src`), null is an empty
/// cell, strings are bare, a non-empty array of scalars gives one cell per element
/// (`r_eci_m[0]`, `r_eci_m[1]`, ...), other arrays stay JSON text.
struct Flat<'a> {
    prefix: String,
    out: &'a mut Vec<(String, String)>,
}

impl<'de> DeserializeSeed<'de> for Flat<'_> {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Flat<'_> {
    type Value = ();
    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<(), E> {
        self.out.push((self.prefix, v.to_string()));
        Ok(())
    }
    fn visit_i64<E>(self, v: i64) -> Result<(), E> {
        self.out.push((self.prefix, v.to_string()));
        Ok(())
    }
    fn visit_u64<E>(self, v: u64) -> Result<(), E> {
        self.out.push((self.prefix, v.to_string()));
        Ok(())
    }
    fn visit_f64<E>(self, v: f64) -> Result<(), E> {
        self.out.push((self.prefix, v.to_string()));
        Ok(())
    }
    fn visit_str<E>(self, v: &str) -> Result<(), E> {
        self.out.push((self.prefix, v.to_owned()));
        Ok(())
    }
    fn visit_unit<E>(self) -> Result<(), E> {
        self.out.push((self.prefix, String::new()));
        Ok(())
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        let mut items = Vec::new();
        while let Some(v) = seq.next_element::<Value>()? {
            items.push(v);
        }
        let scalars = !items.is_empty() && items.iter().all(|v| !v.is_array() && !v.is_object());
        if scalars {
            for (i, v) in items.into_iter().enumerate() {
                self.out
                    .push((format!("{}[{i}]", self.prefix), scalar_cell(v)));
            }
        } else {
            self.out
                .push((self.prefix, Value::Array(items).to_string()));
        }
        Ok(())
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        let out = self.out;
        while let Some(k) = map.next_key::<String>()? {
            let prefix = if self.prefix.is_empty() {
                k
            } else {
                format!("{}.{k}", self.prefix)
            };
            map.next_value_seed(Flat {
                prefix,
                out: &mut *out,
            })?;
        }
        Ok(())
    }
}

/// The cell of a scalar array element, written as [`Flat`] writes a scalar field.
fn scalar_cell(v: Value) -> String {
    match v {
        Value::Null => String::new(),
        Value::String(s) => s,
        Value::Number(n) => match (n.as_u64(), n.as_i64(), n.as_f64()) {
            (Some(u), _, _) => u.to_string(),
            (None, Some(i), _) => i.to_string(),
            (None, None, Some(f)) => f.to_string(),
            _ => n.to_string(),
        },
        v => v.to_string(),
    }
}

/// Flatten the JSON message `data` into `out` (cleared first).
fn flatten(data: &[u8], out: &mut Vec<(String, String)>) -> serde_json::Result<()> {
    out.clear();
    let mut de = serde_json::Deserializer::from_slice(data);
    Flat {
        prefix: String::new(),
        out,
    }
    .deserialize(&mut de)?;
    de.end()
}

/// Whether `key` is a field or element inside `parent` (`csp.len` inside `csp`,
/// `r_eci_m[0]` inside `r_eci_m`).
fn is_child(key: &str, parent: &str) -> bool {
    key.len() > parent.len()
        && key.starts_with(parent)
        && matches!(key.as_bytes()[parent.len()], b'.' | b'[')
}

/// Merge one message's keys into the column list, keeping document order: a new key goes
/// after the previous key of the message; an object's fields replace the single column of
/// a message where it was null; a null where other messages have fields adds nothing.
fn merge_columns(cols: &mut Vec<String>, keys: impl Iterator<Item = String>) {
    let mut last: Option<usize> = None;
    for k in keys {
        if let Some(i) = cols.iter().position(|c| *c == k) {
            last = Some(i);
        } else if let Some(i) = cols.iter().position(|c| is_child(&k, c)) {
            cols[i] = k;
            last = Some(i);
        } else if cols.iter().any(|c| is_child(c, &k)) {
            continue;
        } else {
            let at = last.map_or(cols.len(), |i| i + 1);
            cols.insert(at, k);
            last = Some(at);
        }
    }
}

/// Write one CSV row (RFC 4180 quoting).
fn csv_row<'a>(out: &mut impl Write, cells: impl Iterator<Item = &'a str>) -> std::io::Result<()> {
    let mut first = true;
    for c in cells {
        if !first {
            out.write_all(b",")?;
        }
        first = false;
        if c.contains([',', '"', '\n', '\r']) {
            write!(out, "\"{}\"", c.replace('"', "\"\""))?;
        } else {
            out.write_all(c.as_bytes())?;
        }
    }
    out.write_all(b"\n")
}

/// Export channel `channel` as CSV: a header row, then one row per message: `log_time_ns`
/// and the message's JSON fields flattened (`cfp.src`, ...; null as an empty cell; arrays
/// of numbers one column per element, `r_eci_m[0]`; other arrays as JSON text), columns in
/// the messages' field order. Reads the file twice (columns, then
/// rows), streaming both times. Returns the number of rows. A truncated file is an error
/// before anything is written.
pub fn export_csv(path: &Path, channel: &str, out: &mut impl Write) -> anyhow::Result<u64> {
    let schema = {
        let mut r = Reader::open(path)?;
        let mut schema = None;
        while let Some(m) = r.next_message() {
            let m = m?;
            if &*m.topic == channel {
                schema = Some(m.schema.clone());
                break;
            }
        }
        schema
    };
    if schema.as_deref() == Some(crate::record::ChannelKind::Can.schema_name()) {
        return export_can_csv(path, channel, out);
    }
    let not_json = |i: u64| {
        format!(
            "{}: message {i} on {channel} is not decodable",
            path.display()
        )
    };
    // Pass 1: the columns.
    let mut r = Reader::open(path)?;
    let mut cols: Vec<String> = Vec::new();
    let mut cells = Vec::new();
    let mut n = 0u64;
    while let Some(m) = r.next_message() {
        let m = m?;
        if &*m.topic != channel {
            continue;
        }
        flatten(&m.json_text()?, &mut cells).with_context(|| not_json(n))?;
        merge_columns(&mut cols, cells.drain(..).map(|(k, _)| k));
        n += 1;
    }
    if n == 0 {
        let topics = r.topics();
        if !topics.iter().any(|t| t == channel) {
            bail!(
                "{}: no channel {channel}; channels: {}",
                path.display(),
                topics.join(", ")
            );
        }
    }
    csv_row(
        out,
        std::iter::once("log_time_ns").chain(cols.iter().map(String::as_str)),
    )?;
    // Pass 2: the rows.
    let mut r = Reader::open(path)?;
    let mut rows = 0u64;
    while let Some(m) = r.next_message() {
        let m = m?;
        if &*m.topic != channel {
            continue;
        }
        flatten(&m.json_text()?, &mut cells).with_context(|| not_json(rows))?;
        let time = m.log_time.to_string();
        let row = cols.iter().map(|col| {
            cells
                .iter()
                .find(|(k, _)| k == col)
                .map_or("", |(_, v)| v.as_str())
        });
        csv_row(out, std::iter::once(time.as_str()).chain(row))?;
        rows += 1;
    }
    Ok(rows)
}

/// The columns of a CAN channel's CSV, after `log_time_ns`.
const CAN_CSV_COLUMNS: [&str; 18] = [
    "t_ns",
    "from",
    "can_id",
    "dlc",
    "data",
    "cfp.src",
    "cfp.dst",
    "cfp.type",
    "cfp.remain",
    "cfp.ident",
    "dropped",
    "csp.prio",
    "csp.src",
    "csp.dst",
    "csp.dport",
    "csp.sport",
    "csp.flags",
    "csp.len",
];

/// [`export_csv`] of a `/can/<bus>/frames` channel: one row per frame (not per train),
/// `log_time_ns` and `t_ns` its end, its CFP fields and, for a BEGIN frame, the CSP header
/// it carries.
fn export_can_csv(path: &Path, channel: &str, out: &mut impl Write) -> anyhow::Result<u64> {
    csv_row(out, std::iter::once("log_time_ns").chain(CAN_CSV_COLUMNS))?;
    let mut r = Reader::open(path)?;
    let mut base = None;
    let mut rows = 0u64;
    while let Some(m) = r.next_message() {
        let m = m?;
        if &*m.topic != channel {
            continue;
        }
        let train: CanFramesMsg = m
            .decode()
            .with_context(|| format!("{}: a message on {channel}", path.display()))?;
        // Log time = the run's start + t_ns, as for every message.
        let start = *base.get_or_insert(m.log_time.saturating_sub(train.t_ns));
        for (t_ns, can_id, data, dropped) in train.frames() {
            let cfp = crate::record::cfp_fields(can_id);
            let csp = CanFrame::new(can_id, data)
                .as_ref()
                .and_then(crate::record::begin_fields);
            let opt = |x: Option<String>| x.unwrap_or_default();
            let cells = [
                (start + t_ns).to_string(),
                t_ns.to_string(),
                train.from.clone(),
                can_id.to_string(),
                data.len().to_string(),
                hex::encode(data),
                cfp.src.to_string(),
                cfp.dst.to_string(),
                cfp.kind.clone(),
                cfp.remain.to_string(),
                cfp.ident.to_string(),
                dropped.to_string(),
                opt(csp.as_ref().map(|b| b.prio.to_string())),
                opt(csp.as_ref().map(|b| b.src.to_string())),
                opt(csp.as_ref().map(|b| b.dst.to_string())),
                opt(csp.as_ref().map(|b| b.dport.to_string())),
                opt(csp.as_ref().map(|b| b.sport.to_string())),
                opt(csp.as_ref().map(|b| b.flags.to_string())),
                opt(csp.as_ref().map(|b| b.len.to_string())),
            ];
            csv_row(out, cells.iter().map(String::as_str))?;
            rows += 1;
        }
    }
    Ok(rows)
}

/// The outcome of comparing two recordings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DiffResult {
    /// Every medium message is the same in both.
    Identical {
        /// Medium messages compared.
        messages: u64,
    },
    /// The first medium message that differs.
    Diverged {
        /// Index of the message within its channel (0-based).
        index: u64,
        /// Simulated time of the expected message (the actual one's if the expected
        /// recording ended), ns since the start of the run.
        t_ns: u64,
        /// Channel of the expected message (or the actual one's).
        channel: String,
        /// The expected message (first recording): bytes and decoded fields.
        expected: String,
        /// The actual message (second recording).
        actual: String,
    },
}

impl DiffResult {
    /// Whether the recordings are identical.
    pub fn is_identical(&self) -> bool {
        matches!(self, DiffResult::Identical { .. })
    }
}

impl fmt::Display for DiffResult {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DiffResult::Identical { messages } => {
                write!(f, "identical ({messages} medium messages)")
            }
            DiffResult::Diverged {
                index,
                t_ns,
                channel,
                expected,
                actual,
            } => write!(
                f,
                "first divergence at t = {} s on {channel} (message {index} of that channel)\n  \
                 expected: {expected}\n  actual:   {actual}",
                secs(*t_ns)
            ),
        }
    }
}

/// The next medium message of `r`, with the error naming the recording's role.
fn next_medium(r: &mut Reader, role: &str) -> anyhow::Result<Option<RecordedMessage>> {
    while let Some(m) = r.next_message() {
        let m = m.with_context(|| format!("reading the {role} recording"))?;
        // The medium channels (`/can/*/frames` and `/errors`, `/ground/packets`, `/kiss/*`)
        // are the table's (`record::is_medium_schema`).
        if crate::record::is_medium_schema(&m.schema) {
            return Ok(Some(m));
        }
    }
    Ok(None)
}

/// The `t_ns` field of a message, else its log time.
fn t_ns_of(m: &RecordedMessage) -> u64 {
    m.json()
        .ok()
        .and_then(|v| v.get("t_ns").and_then(Value::as_u64))
        .unwrap_or(m.log_time)
}

fn describe_header(b: &BeginFields) -> String {
    format!(
        "CSP prio {} {}:{} -> {}:{} flags 0x{:02x} len {}",
        b.prio, b.src, b.sport, b.dst, b.dport, b.flags, b.len
    )
}

/// One CAN frame of a train as bytes and decoded fields, for a divergence report.
fn describe_frame(from: &str, (end_ns, can_id, data, dropped): (u64, u32, &[u8], bool)) -> String {
    let f = CanFrame::new(can_id, data);
    let cfp = crate::record::cfp_fields(can_id);
    let csp = f
        .as_ref()
        .and_then(crate::record::begin_fields)
        .map(|b| format!("; {}", describe_header(&b)))
        .unwrap_or_default();
    format!(
        "t={}s from {from}: can_id 0x{can_id:08x} dlc {} data {}{} (CFP {} src {} dst {} remain {} ident {}{csp})",
        secs(end_ns),
        data.len(),
        if data.is_empty() {
            "-".to_owned()
        } else {
            hex::encode(data)
        },
        if dropped { " DROPPED" } else { "" },
        cfp.kind,
        cfp.src,
        cfp.dst,
        cfp.remain,
        cfp.ident
    )
}

/// A message as bytes and decoded fields, for a divergence report (a CAN train: its
/// first frame).
pub fn describe(m: &RecordedMessage) -> String {
    let t = |t_ns: u64| format!("t={}s", secs(t_ns));
    let dropped = |d: bool| if d { " DROPPED" } else { "" };
    if m.topic.starts_with("/can/")
        && let Ok(c) = m.decode::<CanFramesMsg>()
        && let Some(first) = c.frames().next()
    {
        return format!(
            "{} (frame 1 of {})",
            describe_frame(&c.from, first),
            c.can_id.len()
        );
    }
    if m.topic.starts_with("/kiss/")
        && let Ok(k) = m.decode::<KissFrameMsg>()
    {
        return format!(
            "{} {} {}: {} bytes {}",
            t(k.t_ns),
            k.link,
            k.dir,
            k.len,
            hex::encode(&k.bytes)
        );
    }
    if m.schema.as_ref() == crate::record::ChannelKind::Net.schema_name()
        && let Ok(p) = m.decode::<NetPacketMsg>()
    {
        let csp = match (p.prio, p.src, p.dst, p.dport, p.sport, p.flags) {
            (Some(prio), Some(src), Some(dst), Some(dport), Some(sport), Some(flags)) => {
                format!(
                    " ({})",
                    describe_header(&BeginFields {
                        prio,
                        src,
                        dst,
                        dport,
                        sport,
                        flags,
                        len: p.len.saturating_sub(4) as u16,
                    })
                )
            }
            _ => String::new(),
        };
        return format!(
            "{} from {}: bytes {}{}{csp}",
            t(p.t_ns),
            p.from,
            hex::encode(&p.bytes),
            dropped(p.dropped)
        );
    }
    let text = m
        .json_text()
        .unwrap_or_else(|e| format!("{e:#}").into_bytes());
    format!("{} {}", t(t_ns_of(m)), String::from_utf8_lossy(&text))
}

/// Compare the medium channels (`/can/*/frames`, `/ground/packets`, `/kiss/*`) of two
/// recordings message by message in file order; `a` is the expected one. Other channels
/// (logs, decoded packets, verdicts) follow from these and are not compared. An unreadable
/// or truncated recording is an error unless a divergence comes before the damage.
pub fn diff(a: &Path, b: &Path) -> anyhow::Result<DiffResult> {
    Ok(diff_summary(a, b, 0)?.result)
}

/// Where one medium channel of two recordings differs: the message's index within the
/// channel (0-based) and its simulated time, ns since the start of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DivergencePoint {
    /// Index of the message within its channel (0-based).
    pub index: u64,
    /// Simulated time of the divergence (as `DiffResult::Diverged::t_ns`).
    pub t_ns: u64,
}

/// One medium channel of two recordings compared.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelDiff {
    /// The channel (topic).
    pub channel: String,
    /// Messages on it in the expected recording (A).
    pub expected: u64,
    /// Messages on it in the actual recording (B).
    pub actual: u64,
    /// Positions where the two differ, a message only one of them has included.
    pub differing: u64,
    /// The first of them.
    pub first: Option<DivergencePoint>,
}

impl ChannelDiff {
    /// Whether the channel is the same message for message in both recordings.
    pub fn is_identical(&self) -> bool {
        self.differing == 0
    }
}

/// One divergence of a `--all` listing: where, and the two messages as a report shows them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Divergence {
    /// The channel.
    pub channel: String,
    /// Index within the channel and simulated time.
    pub at: DivergencePoint,
    /// The expected message (first recording): bytes and decoded fields.
    pub expected: String,
    /// The actual message (second recording).
    pub actual: String,
}

/// Two recordings compared: the first divergence in detail, a line per medium channel and,
/// when asked, the earliest divergences of all channels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiffSummary {
    /// The first divergence (as [`diff`] returns it).
    pub result: DiffResult,
    /// Every medium channel of either recording, in name order.
    pub channels: Vec<ChannelDiff>,
    /// The earliest divergences of all channels by time (then channel, then index), at
    /// most the `max_listed` given to [`diff_summary`].
    pub listed: Vec<Divergence>,
}

impl DiffSummary {
    /// Whether the recordings are identical.
    pub fn is_identical(&self) -> bool {
        self.result.is_identical()
    }

    /// Divergences on all channels together.
    pub fn differing(&self) -> u64 {
        self.channels.iter().map(|c| c.differing).sum()
    }
}

impl fmt::Display for DiffSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{}", self.result)?;
        let width = self
            .channels
            .iter()
            .map(|c| c.channel.len())
            .chain(["channel".len()])
            .max()
            .unwrap_or_default();
        writeln!(f, "per channel (expected = A, actual = B):")?;
        write!(
            f,
            "  {:width$}  {:>8}  {:>8}  {:>9}  first divergence",
            "channel", "expected", "actual", "differing"
        )?;
        for c in &self.channels {
            let first = match c.first {
                Some(p) => format!("message {} at t = {} s", p.index, secs(p.t_ns)),
                None => "identical".to_owned(),
            };
            write!(
                f,
                "\n  {:width$}  {:>8}  {:>8}  {:>9}  {first}",
                c.channel, c.expected, c.actual, c.differing
            )?;
        }
        let total = self.differing();
        if !self.listed.is_empty() {
            let shown = self.listed.len() as u64;
            if shown < total {
                write!(f, "\nthe first {shown} of {total} divergences, by time:")?;
            } else {
                write!(f, "\nall {total} divergences, by time:")?;
            }
            for d in &self.listed {
                write!(
                    f,
                    "\n  t = {} s on {} (message {})\n    expected: {}\n    actual:   {}",
                    secs(d.at.t_ns),
                    d.channel,
                    d.at.index,
                    d.expected,
                    d.actual
                )?;
            }
        }
        Ok(())
    }
}

/// When `x` and `y` (the same position of one channel, either may be missing) differ:
/// the first different frame's time for CAN trains, else the expected message's time.
fn divergence_t_ns(x: Option<&RecordedMessage>, y: Option<&RecordedMessage>) -> u64 {
    match (x, y) {
        (Some(x), Some(y)) => first_frame_difference(x, y).map_or(t_ns_of(x), |d| d.0),
        _ => x.or(y).map_or(u64::MAX, t_ns_of),
    }
}

/// `x` and `y` as a divergence report shows them: the first different frame of CAN trains,
/// else the whole messages, `(end of recording)` for a missing one.
fn divergence_text(x: Option<&RecordedMessage>, y: Option<&RecordedMessage>) -> (String, String) {
    if let (Some(x), Some(y)) = (x, y)
        && let Some((_, expected, actual)) = first_frame_difference(x, y)
    {
        return (expected, actual);
    }
    let end = || "(end of recording)".to_owned();
    (x.map_or_else(end, describe), y.map_or_else(end, describe))
}

/// The medium channels of the recording at `path`, each its own sequence, from simulated
/// time `from_ns` on.
fn medium_by_topic(
    path: &Path,
    label: &str,
    from_ns: u64,
) -> anyhow::Result<BTreeMap<Arc<str>, Vec<RecordedMessage>>> {
    let mut r = Reader::open(path)?;
    let mut by_topic: BTreeMap<Arc<str>, Vec<RecordedMessage>> = BTreeMap::new();
    // A message's log time is the run's start plus its simulated time: the start is worked
    // out once, from the first message (decoding each would be slow).
    let mut start_ns: Option<u64> = None;
    while let Some(m) = next_medium(&mut r, label)? {
        if from_ns > 0 {
            let start = *start_ns.get_or_insert_with(|| m.log_time - t_ns_of(&m).min(m.log_time));
            if m.log_time.saturating_sub(start) < from_ns {
                continue;
            }
        }
        by_topic.entry(m.topic.clone()).or_default().push(m);
    }
    Ok(by_topic)
}

/// [`diff`] with a line per medium channel (messages in each recording, how many differ,
/// the first divergence) and the earliest `max_listed` divergences of all channels in
/// detail (none when 0). The listing is kept in a heap of at most `max_listed` entries.
pub fn diff_summary(a: &Path, b: &Path, max_listed: usize) -> anyhow::Result<DiffSummary> {
    diff_summary_from(a, b, max_listed, 0)
}

/// [`diff_summary`] of what the two recordings hold from simulated time `from_ns` on: each
/// channel's messages before it are left out of both (`diff --from T`, a run started from
/// a snapshot at T against the run that took it). Indices count from the first message
/// compared.
pub fn diff_summary_from(
    a: &Path,
    b: &Path,
    max_listed: usize,
    from_ns: u64,
) -> anyhow::Result<DiffSummary> {
    // Each medium channel is compared as its own sequence: messages of different channels
    // that happen within the same scheduler tick may be written in either order, and that
    // order is not part of what happened on the wire.
    let xa = medium_by_topic(a, "expected", from_ns)?;
    let xb = medium_by_topic(b, "actual", from_ns)?;
    let topics: Vec<&Arc<str>> = xa
        .keys()
        .chain(xb.keys())
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    let empty = Vec::new();
    let mut same = 0u64;
    let mut channels = Vec::with_capacity(topics.len());
    // The first divergence of all: (time, topic, index); the earliest channel in name
    // order wins a tie.
    let mut first: Option<(u64, usize, u64)> = None;
    // The latest of the earliest `max_listed` divergences on top: (time, topic, index).
    let mut heap: std::collections::BinaryHeap<(u64, usize, u64)> =
        std::collections::BinaryHeap::with_capacity(max_listed.saturating_add(1).min(1024));
    for (k, topic) in topics.iter().enumerate() {
        let (ea, eb) = (
            xa.get(*topic).unwrap_or(&empty),
            xb.get(*topic).unwrap_or(&empty),
        );
        let mut c = ChannelDiff {
            channel: topic.to_string(),
            expected: ea.len() as u64,
            actual: eb.len() as u64,
            differing: 0,
            first: None,
        };
        for i in 0..ea.len().max(eb.len()) {
            let (x, y) = (ea.get(i), eb.get(i));
            if let (Some(x), Some(y)) = (x, y)
                && x.data == y.data
            {
                same += 1;
                continue;
            }
            c.differing += 1;
            // Times are worked out only where they are reported: a channel's first
            // divergence and, with a listing, every candidate for it.
            if c.first.is_some() && max_listed == 0 {
                continue;
            }
            let t = divergence_t_ns(x, y);
            if c.first.is_none() {
                c.first = Some(DivergencePoint {
                    index: i as u64,
                    t_ns: t,
                });
                if first.is_none_or(|f| t < f.0) {
                    first = Some((t, k, i as u64));
                }
            }
            if max_listed > 0 {
                heap.push((t, k, i as u64));
                if heap.len() > max_listed {
                    heap.pop();
                }
            }
        }
        channels.push(c);
    }
    let at = |k: usize, i: u64| {
        let (ea, eb) = (
            xa.get(topics[k]).unwrap_or(&empty),
            xb.get(topics[k]).unwrap_or(&empty),
        );
        let i = usize::try_from(i).unwrap_or(usize::MAX);
        (ea.get(i), eb.get(i))
    };
    let listed = heap
        .into_sorted_vec()
        .into_iter()
        .map(|(t_ns, k, index)| {
            let (x, y) = at(k, index);
            let (expected, actual) = divergence_text(x, y);
            Divergence {
                channel: topics[k].to_string(),
                at: DivergencePoint { index, t_ns },
                expected,
                actual,
            }
        })
        .collect();
    let result = match first {
        None => DiffResult::Identical { messages: same },
        Some((t_ns, k, index)) => {
            let (x, y) = at(k, index);
            let (expected, actual) = divergence_text(x, y);
            DiffResult::Diverged {
                index,
                t_ns,
                channel: topics[k].to_string(),
                expected,
                actual,
            }
        }
    };
    Ok(DiffSummary {
        result,
        channels,
        listed,
    })
}

/// Where two CAN trains first differ: the time and the frame as each has it (the first
/// frame that is not the same, or the end of the shorter train); `None` when they are not
/// both CAN trains or when they are the same frame for frame.
fn first_frame_difference(
    x: &RecordedMessage,
    y: &RecordedMessage,
) -> Option<(u64, String, String)> {
    if !x.topic.starts_with("/can/") || !x.topic.ends_with("/frames") {
        return None;
    }
    let (a, b) = (
        x.decode::<CanFramesMsg>().ok()?,
        y.decode::<CanFramesMsg>().ok()?,
    );
    let (mut fa, mut fb) = (a.frames(), b.frames());
    for k in 1.. {
        let (p, q) = (fa.next(), fb.next());
        if p.is_none() && q.is_none() {
            return None;
        }
        let same = match (p, q) {
            (Some(p), Some(q)) => a.from == b.from && p == q,
            _ => false,
        };
        if same {
            continue;
        }
        let describe = |from: &str, f: Option<(u64, u32, &[u8], bool)>, n: usize| {
            f.map_or_else(
                || format!("(end of its train of {n} frames)"),
                |f| format!("{} (frame {k} of {n})", describe_frame(from, f)),
            )
        };
        let t = p.or(q).map_or(a.t_ns, |f| f.0);
        return Some((
            t,
            describe(&a.from, p, a.can_id.len()),
            describe(&b.from, q, b.can_id.len()),
        ));
    }
    None
}
