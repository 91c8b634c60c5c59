//! The recorder's MCAP writer: chunked, zstd-compressed, indexed, written as the run goes.
//!
//! It writes what the `mcap` crate's writer wrote for the recorder (the same records in the
//! same places, but for the order of schemas and channels inside a chunk: [MCAP
//! spec](https://mcap.dev/spec)), for less CPU. The crate's writer passes
//! every record through a streaming compressor field by field: about seven zstd calls and
//! seven CRC updates per message, and zstd's slower external-dictionary path as its input
//! buffer wraps. Here a chunk's records are appended to one buffer and compressed at once
//! when it is full (one zstd call per chunk, its tables warm, the CRC in one pass), which
//! measured a third less recording CPU on the full day (docs/recording.md, "Compression").
//!
//! A full chunk is compressed on a thread of its own while the next one fills: the thread
//! that owns the writer (a run's recorder thread) writes it (and its message indexes) when
//! the next chunk closes, or at the next record outside chunks, flush or finish. One chunk
//! at most is under compression, in order, with the one zstd context: the file is the same
//! bytes as compressed inline (a test recompresses every chunk so), and zstd's tenth of a
//! recorded run's CPU is off the writer's thread. A process killed outright loses the chunk
//! under compression as well as the open one.
//!
//! Layout: magic, Header, Metadata and Attachment records (outside chunks), chunks holding
//! each Schema and Channel record before its first use and the Message records, each chunk
//! followed by one MessageIndex per channel in it (channel id order); then DataEnd (CRC of
//! the data section), the summary (Schemas, Channels, Statistics, ChunkIndexes,
//! AttachmentIndexes, MetadataIndexes, each a group with a SummaryOffset), the Footer
//! (summary CRC) and the magic. Nothing reads a clock or iterates a hash map: the same
//! calls give the same bytes.

use std::collections::BTreeMap;
use std::io::{self, Write};
use std::sync::mpsc;

/// MCAP's magic, at both ends of the file.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const ATTACHMENT: u8 = 0x09;
    pub const ATTACHMENT_INDEX: u8 = 0x0A;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// Little-endian record building.
trait Put {
    fn u8(&mut self, v: u8);
    fn u16(&mut self, v: u16);
    fn u32(&mut self, v: u32);
    fn u64(&mut self, v: u64);
    fn str(&mut self, s: &str);
    fn map(&mut self, m: &BTreeMap<String, String>);
    /// A `map<uint16, uint64>` (channel id to a count or an offset).
    fn id_map(&mut self, m: impl ExactSizeIterator<Item = (u16, u64)>);
}

impl Put for Vec<u8> {
    fn u8(&mut self, v: u8) {
        self.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn str(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.extend_from_slice(s.as_bytes());
    }
    fn map(&mut self, m: &BTreeMap<String, String>) {
        let len: usize = m.iter().map(|(k, v)| 8 + k.len() + v.len()).sum();
        self.u32(len as u32);
        for (k, v) in m {
            self.str(k);
            self.str(v);
        }
    }
    fn id_map(&mut self, m: impl ExactSizeIterator<Item = (u16, u64)>) {
        self.u32((m.len() * 10) as u32);
        for (id, v) in m {
            self.u16(id);
            self.u64(v);
        }
    }
}

/// One record: opcode, length, then what `body` puts.
fn record(out: &mut Vec<u8>, opcode: u8, body: impl FnOnce(&mut Vec<u8>)) {
    out.u8(opcode);
    let at = out.len();
    out.u64(0);
    body(out);
    let len = (out.len() - at - 8) as u64;
    out[at..at + 8].copy_from_slice(&len.to_le_bytes());
}

#[derive(Debug, Clone)]
struct SchemaRec {
    id: u16,
    name: String,
    encoding: String,
    data: Vec<u8>,
}

#[derive(Debug, Clone)]
struct ChannelRec {
    id: u16,
    schema_id: u16,
    topic: String,
    message_encoding: String,
    metadata: BTreeMap<String, String>,
}

fn put_schema(out: &mut Vec<u8>, s: &SchemaRec) {
    record(out, op::SCHEMA, |b| {
        b.u16(s.id);
        b.str(&s.name);
        b.str(&s.encoding);
        b.u32(s.data.len() as u32);
        b.extend_from_slice(&s.data);
    });
}

fn put_channel(out: &mut Vec<u8>, c: &ChannelRec) {
    record(out, op::CHANNEL, |b| {
        b.u16(c.id);
        b.u16(c.schema_id);
        b.str(&c.topic);
        b.str(&c.message_encoding);
        b.map(&c.metadata);
    });
}

/// Time bounds `(first, last)` widened to take `t`.
fn widen(bounds: Option<(u64, u64)>, t: u64) -> (u64, u64) {
    bounds.map_or((t, t), |(a, b)| (a.min(t), b.max(t)))
}

/// A chunk's place in the file, for the summary.
#[derive(Debug, Clone)]
struct ChunkIndexRec {
    start_ns: u64,
    end_ns: u64,
    offset: u64,
    length: u64,
    message_index_offsets: Vec<(u16, u64)>,
    message_index_length: u64,
    compressed: u64,
    uncompressed: u64,
}

#[derive(Debug, Clone)]
struct AttachmentIndexRec {
    offset: u64,
    length: u64,
    log_time: u64,
    create_time: u64,
    data_size: u64,
    name: String,
    media_type: String,
}

/// What [`McapFile::finish`] reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Written {
    /// Chunks written.
    pub chunks: u32,
    /// Messages written.
    pub messages: u64,
    /// Bytes in the file.
    pub bytes: u64,
}

/// A streaming MCAP writer (see the module docs).
pub struct McapFile<W: Write> {
    out: W,
    /// Bytes written to `out` so far.
    pos: u64,
    /// CRC of the data section so far (magic included, as the spec and `mcap` count it).
    data_crc: crc32fast::Hasher,
    chunk_size: usize,
    /// The thread compressing closed chunks.
    compressor: ChunkCompressor,
    /// The chunk under compression, to be written next.
    pending: Option<PendingChunk>,
    /// The open chunk's records, uncompressed.
    chunk: Vec<u8>,
    /// The open chunk's message times, if it holds a message.
    chunk_ns: Option<(u64, u64)>,
    /// The open chunk's message index entries.
    index: ChunkIndexEntries,
    /// Buffers back from a written chunk, for the next one: its records' and its index's.
    spare: Option<(Vec<u8>, ChunkIndexEntries)>,
    schemas: Vec<SchemaRec>,
    /// Schemas and channels not yet written to a chunk.
    schemas_due: Vec<usize>,
    channels_due: Vec<usize>,
    channels: Vec<ChannelRec>,
    counts: BTreeMap<u16, u64>,
    messages: u64,
    bounds_ns: Option<(u64, u64)>,
    chunk_indexes: Vec<ChunkIndexRec>,
    attachment_indexes: Vec<AttachmentIndexRec>,
    metadata_indexes: Vec<(u64, u64, String)>,
    finished: Option<Written>,
    /// `finish` was called: nothing more is written (a drop after a failed finish does not
    /// write the end twice).
    finishing: bool,
    /// A write to `out` failed: what reached it is unknown, so nothing more is written (no
    /// summary pointing at the wrong places); the complete chunks before it stay readable.
    poisoned: bool,
}

impl<W: Write> McapFile<W> {
    /// Start a file on `out`: magic and header (`profile`, `library`). Chunks close once
    /// they hold `chunk_size` uncompressed bytes and are compressed with zstd at `level`.
    pub fn new(
        out: W,
        profile: &str,
        library: &str,
        chunk_size: usize,
        level: i32,
    ) -> io::Result<Self> {
        let mut w = McapFile {
            out,
            pos: 0,
            data_crc: crc32fast::Hasher::new(),
            chunk_size,
            compressor: ChunkCompressor::start(level)?,
            pending: None,
            chunk: Vec::with_capacity(chunk_size + 64 * 1024),
            chunk_ns: None,
            index: Vec::new(),
            spare: None,
            schemas: Vec::new(),
            schemas_due: Vec::new(),
            channels_due: Vec::new(),
            channels: Vec::new(),
            counts: BTreeMap::new(),
            messages: 0,
            bounds_ns: None,
            chunk_indexes: Vec::new(),
            attachment_indexes: Vec::new(),
            metadata_indexes: Vec::new(),
            finished: None,
            finishing: false,
            poisoned: false,
        };
        w.data(MAGIC)?;
        let mut rec = Vec::new();
        record(&mut rec, op::HEADER, |b| {
            b.str(profile);
            b.str(library);
        });
        w.data(&rec)?;
        Ok(w)
    }

    /// Write bytes of the data section.
    fn data(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.writable()?;
        if let Err(e) = self.out.write_all(bytes) {
            self.poisoned = true;
            return Err(e);
        }
        self.data_crc.update(bytes);
        self.pos += bytes.len() as u64;
        Ok(())
    }

    /// An error once a write has failed or the file is finished.
    fn writable(&self) -> io::Result<()> {
        if self.poisoned {
            Err(io::Error::other("an earlier write to the recording failed"))
        } else if self.finishing {
            Err(io::Error::other("the recording is already finished"))
        } else {
            Ok(())
        }
    }

    /// The next id after `n` registered (ids from 1), or an error past u16's range.
    fn next_id(n: usize) -> io::Result<u16> {
        u16::try_from(n + 1).map_err(|_| io::Error::other("more than 65535 schemas or channels"))
    }

    /// Register a schema; identical content gets the id it already has.
    pub fn add_schema(&mut self, name: &str, encoding: &str, data: &[u8]) -> io::Result<u16> {
        if let Some(s) = self
            .schemas
            .iter()
            .find(|s| s.name == name && s.encoding == encoding && s.data == data)
        {
            return Ok(s.id);
        }
        let id = Self::next_id(self.schemas.len())?;
        self.schemas.push(SchemaRec {
            id,
            name: name.to_owned(),
            encoding: encoding.to_owned(),
            data: data.to_owned(),
        });
        self.schemas_due.push(self.schemas.len() - 1);
        Ok(id)
    }

    /// Register a channel (ids from 1, in order).
    pub fn add_channel(
        &mut self,
        schema_id: u16,
        topic: &str,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<u16> {
        let id = Self::next_id(self.channels.len())?;
        self.channels.push(ChannelRec {
            id,
            schema_id,
            topic: topic.to_owned(),
            message_encoding: message_encoding.to_owned(),
            metadata: metadata.clone(),
        });
        self.channels_due.push(self.channels.len() - 1);
        Ok(id)
    }

    /// Write one message on channel `channel` (an id [`McapFile::add_channel`] gave).
    pub fn message(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> io::Result<()> {
        self.writable()?;
        // A channel's records go into the chunk before its first message (its schema's
        // before it), as the crate's writer does.
        self.put_due();
        let slot = usize::from(channel);
        if self.index.len() <= slot {
            self.index.resize_with(slot + 1, Vec::new);
        }
        self.index[slot].push((log_time, self.chunk.len() as u64));
        let c = &mut self.chunk;
        c.u8(op::MESSAGE);
        c.u64(2 + 4 + 8 + 8 + data.len() as u64);
        c.u16(channel);
        c.u32(sequence);
        c.u64(log_time);
        c.u64(publish_time);
        c.extend_from_slice(data);
        self.chunk_ns = Some(widen(self.chunk_ns, log_time));
        self.bounds_ns = Some(widen(self.bounds_ns, log_time));
        *self.counts.entry(channel).or_insert(0) += 1;
        self.messages += 1;
        if self.chunk.len() >= self.chunk_size {
            self.close_chunk()?;
        }
        Ok(())
    }

    /// Put the schemas and channels not yet written into the open chunk.
    fn put_due(&mut self) {
        for i in std::mem::take(&mut self.schemas_due) {
            put_schema(&mut self.chunk, &self.schemas[i]);
        }
        for i in std::mem::take(&mut self.channels_due) {
            put_channel(&mut self.chunk, &self.channels[i]);
        }
    }

    /// Hand the open chunk to the compressor (nothing if it is empty), after writing the
    /// one compressed meanwhile.
    fn close_chunk(&mut self) -> io::Result<()> {
        if self.chunk.is_empty() {
            return Ok(());
        }
        self.write_pending()?;
        let (start_ns, end_ns) = self.chunk_ns.take().unwrap_or((0, 0));
        let (chunk, index) = self
            .spare
            .take()
            .unwrap_or_else(|| (Vec::with_capacity(self.chunk_size + 64 * 1024), Vec::new()));
        let chunk = std::mem::replace(&mut self.chunk, chunk);
        let index = std::mem::replace(&mut self.index, index);
        let uncompressed = chunk.len() as u64;
        if let Err(e) = self.compressor.give(chunk) {
            self.poisoned = true;
            return Err(e);
        }
        self.pending = Some(PendingChunk {
            start_ns,
            end_ns,
            uncompressed,
            index,
        });
        Ok(())
    }

    /// Close the open chunk and write every chunk closed (before a record outside chunks,
    /// a flush or the end).
    fn write_chunks(&mut self) -> io::Result<()> {
        self.close_chunk()?;
        self.write_pending()
    }

    /// Write the chunk under compression, once compressed, and its message indexes.
    fn write_pending(&mut self) -> io::Result<()> {
        let Some(p) = self.pending.take() else {
            return Ok(());
        };
        let done = match self.compressor.take() {
            Ok(d) => d,
            Err(e) => {
                self.poisoned = true;
                return Err(e);
            }
        };
        let Compressed {
            mut chunk,
            z,
            crc,
            result,
        } = done;
        if let Err(e) = result {
            self.poisoned = true;
            return Err(e);
        }
        let offset = self.pos;
        let mut head = Vec::with_capacity(64);
        head.u8(op::CHUNK);
        head.u64(8 + 8 + 8 + 4 + 4 + 4 + 8 + z.len() as u64);
        head.u64(p.start_ns);
        head.u64(p.end_ns);
        head.u64(p.uncompressed);
        head.u32(crc);
        head.str("zstd");
        head.u64(z.len() as u64);
        self.data(&head)?;
        self.data(&z)?;
        let length = self.pos - offset;
        let compressed = z.len() as u64;
        self.compressor.recycle(z);

        // One message index per channel with messages in this chunk, by channel id.
        let mut rec = Vec::new();
        let mut offsets = Vec::new();
        let index_start = self.pos;
        let mut index = p.index;
        for (id, entries) in index.iter().enumerate() {
            if entries.is_empty() {
                continue;
            }
            offsets.push((id as u16, index_start + rec.len() as u64));
            record(&mut rec, op::MESSAGE_INDEX, |b| {
                b.u16(id as u16);
                b.u32((entries.len() * 16) as u32);
                for &(t, o) in entries {
                    b.u64(t);
                    b.u64(o);
                }
            });
        }
        self.data(&rec)?;
        for entries in &mut index {
            entries.clear();
        }
        chunk.clear();
        self.spare = Some((chunk, index));
        self.chunk_indexes.push(ChunkIndexRec {
            start_ns: p.start_ns,
            end_ns: p.end_ns,
            offset,
            length,
            message_index_offsets: offsets,
            message_index_length: rec.len() as u64,
            compressed,
            uncompressed: p.uncompressed,
        });
        Ok(())
    }

    /// Bytes written to the file so far (the open chunk not included).
    pub fn position(&self) -> u64 {
        self.pos
    }

    /// Close the open chunk and flush the file.
    pub fn flush(&mut self) -> io::Result<()> {
        self.write_chunks()?;
        self.out.flush().inspect_err(|_| self.poisoned = true)
    }

    /// A metadata record (outside chunks; the open chunk is closed first so records stay in
    /// file order).
    pub fn metadata(&mut self, name: &str, metadata: &BTreeMap<String, String>) -> io::Result<()> {
        self.write_chunks()?;
        let mut rec = Vec::new();
        record(&mut rec, op::METADATA, |b| {
            b.str(name);
            b.map(metadata);
        });
        let offset = self.pos;
        self.data(&rec)?;
        self.metadata_indexes
            .push((offset, rec.len() as u64, name.to_owned()));
        Ok(())
    }

    /// An attachment record (outside chunks).
    pub fn attach(
        &mut self,
        log_time: u64,
        create_time: u64,
        name: &str,
        media_type: &str,
        data: &[u8],
    ) -> io::Result<()> {
        self.write_chunks()?;
        let mut rec = Vec::new();
        record(&mut rec, op::ATTACHMENT, |b| {
            b.u64(log_time);
            b.u64(create_time);
            b.str(name);
            b.str(media_type);
            b.u64(data.len() as u64);
            b.extend_from_slice(data);
            // The CRC covers the record's fields before it (after opcode and length).
            let crc = crc32fast::hash(b.get(9..).unwrap_or_default());
            b.u32(crc);
        });
        let offset = self.pos;
        self.data(&rec)?;
        self.attachment_indexes.push(AttachmentIndexRec {
            offset,
            length: rec.len() as u64,
            log_time,
            create_time,
            data_size: data.len() as u64,
            name: name.to_owned(),
            media_type: media_type.to_owned(),
        });
        Ok(())
    }

    /// Close the last chunk, write the summary and the footer, and flush. Calling it again
    /// does nothing.
    pub fn finish(&mut self) -> io::Result<Written> {
        if let Some(w) = self.finished {
            return Ok(w);
        }
        self.writable()?;
        // Schemas and channels registered but never used go into the last chunk (with no
        // message at all, a chunk of times 0), so the file names every channel, as the
        // crate's writer did.
        self.put_due();
        self.write_chunks()?;
        self.finishing = true;
        let mut rec = Vec::new();
        let crc = self.data_crc.clone().finalize();
        record(&mut rec, op::DATA_END, |b| b.u32(crc));
        self.out.write_all(&rec)?;
        self.pos += rec.len() as u64;

        let summary_start = self.pos;
        let mut s = Vec::new();
        let mut groups: Vec<(u8, u64, u64)> = Vec::new();
        let mut group = |s: &mut Vec<u8>, opcode: u8, f: &mut dyn FnMut(&mut Vec<u8>)| {
            let start = s.len();
            f(s);
            if s.len() > start {
                groups.push((
                    opcode,
                    summary_start + start as u64,
                    (s.len() - start) as u64,
                ));
            }
        };
        group(&mut s, op::SCHEMA, &mut |s| {
            for x in &self.schemas {
                put_schema(s, x);
            }
        });
        group(&mut s, op::CHANNEL, &mut |s| {
            for c in &self.channels {
                put_channel(s, c);
            }
        });
        let (start_ns, end_ns) = self.bounds_ns.unwrap_or((0, 0));
        group(&mut s, op::STATISTICS, &mut |s| {
            record(s, op::STATISTICS, |b| {
                b.u64(self.messages);
                b.u16(self.schemas.len() as u16);
                b.u32(self.channels.len() as u32);
                b.u32(self.attachment_indexes.len() as u32);
                b.u32(self.metadata_indexes.len() as u32);
                b.u32(self.chunk_indexes.len() as u32);
                b.u64(start_ns);
                b.u64(end_ns);
                b.id_map(self.counts.iter().map(|(&id, &n)| (id, n)));
            });
        });
        group(&mut s, op::CHUNK_INDEX, &mut |s| {
            for c in &self.chunk_indexes {
                record(s, op::CHUNK_INDEX, |b| {
                    b.u64(c.start_ns);
                    b.u64(c.end_ns);
                    b.u64(c.offset);
                    b.u64(c.length);
                    b.id_map(c.message_index_offsets.iter().copied());
                    b.u64(c.message_index_length);
                    b.str("zstd");
                    b.u64(c.compressed);
                    b.u64(c.uncompressed);
                });
            }
        });
        group(&mut s, op::ATTACHMENT_INDEX, &mut |s| {
            for a in &self.attachment_indexes {
                record(s, op::ATTACHMENT_INDEX, |b| {
                    b.u64(a.offset);
                    b.u64(a.length);
                    b.u64(a.log_time);
                    b.u64(a.create_time);
                    b.u64(a.data_size);
                    b.str(&a.name);
                    b.str(&a.media_type);
                });
            }
        });
        group(&mut s, op::METADATA_INDEX, &mut |s| {
            for (offset, length, name) in &self.metadata_indexes {
                record(s, op::METADATA_INDEX, |b| {
                    b.u64(*offset);
                    b.u64(*length);
                    b.str(name);
                });
            }
        });
        let summary_offset_start = summary_start + s.len() as u64;
        for (opcode, start, length) in groups {
            record(&mut s, op::SUMMARY_OFFSET, |b| {
                b.u8(opcode);
                b.u64(start);
                b.u64(length);
            });
        }
        // Footer: the summary CRC runs from the summary's start through the footer's
        // `summary_offset_start` field.
        s.u8(op::FOOTER);
        s.u64(8 + 8 + 4);
        s.u64(summary_start);
        s.u64(summary_offset_start);
        let crc = crc32fast::hash(&s);
        s.u32(crc);
        s.extend_from_slice(MAGIC);
        self.out.write_all(&s)?;
        self.pos += s.len() as u64;
        self.out.flush()?;
        let w = Written {
            chunks: self.chunk_indexes.len() as u32,
            messages: self.messages,
            bytes: self.pos,
        };
        self.finished = Some(w);
        Ok(w)
    }

    /// The writer underneath (after [`McapFile::finish`], the whole file).
    pub fn get_mut(&mut self) -> &mut W {
        &mut self.out
    }
}

/// A closed chunk's place, times and index, kept until its compressed bytes are written.
struct PendingChunk {
    start_ns: u64,
    end_ns: u64,
    uncompressed: u64,
    index: ChunkIndexEntries,
}

/// A chunk's message index entries (log time, offset in the chunk), by channel id.
type ChunkIndexEntries = Vec<Vec<(u64, u64)>>;

/// What the compressor thread gives back for a chunk: its buffer (for reuse), the
/// compressed bytes, the CRC of the uncompressed ones, and whether zstd succeeded.
struct Compressed {
    chunk: Vec<u8>,
    z: Vec<u8>,
    crc: u32,
    result: io::Result<()>,
}

/// The thread that compresses chunks, one at a time, in the order given; it ends when
/// its writer is dropped.
struct ChunkCompressor {
    jobs: Option<mpsc::SyncSender<(Vec<u8>, Vec<u8>)>>,
    done: mpsc::Receiver<Compressed>,
    /// A compressed buffer back from a written chunk, for the next one.
    spare_z: Vec<u8>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ChunkCompressor {
    fn start(level: i32) -> io::Result<Self> {
        let mut zstd = zstd::bulk::Compressor::new(level)?;
        let (jobs, rx) = mpsc::sync_channel::<(Vec<u8>, Vec<u8>)>(1);
        let (tx, done) = mpsc::sync_channel(1);
        let thread = std::thread::Builder::new()
            .name("mcap-zstd".into())
            .spawn(move || {
                while let Ok((chunk, mut z)) = rx.recv() {
                    let crc = crc32fast::hash(&chunk);
                    z.clear();
                    z.reserve(zstd::zstd_safe::compress_bound(chunk.len()));
                    let result = zstd.compress_to_buffer(&chunk, &mut z).map(|_| ());
                    let out = Compressed {
                        chunk,
                        z,
                        crc,
                        result,
                    };
                    if tx.send(out).is_err() {
                        return;
                    }
                }
            })?;
        Ok(ChunkCompressor {
            jobs: Some(jobs),
            done,
            spare_z: Vec::new(),
            thread: Some(thread),
        })
    }

    fn gone() -> io::Error {
        io::Error::other("the recording's compressor thread stopped")
    }

    /// Start compressing `chunk` (the previous one must have been taken).
    fn give(&mut self, chunk: Vec<u8>) -> io::Result<()> {
        let z = std::mem::take(&mut self.spare_z);
        self.jobs
            .as_ref()
            .ok_or_else(Self::gone)?
            .send((chunk, z))
            .map_err(|_| Self::gone())
    }

    /// The chunk given last, compressed (waits for it).
    fn take(&mut self) -> io::Result<Compressed> {
        self.done.recv().map_err(|_| Self::gone())
    }

    fn recycle(&mut self, z: Vec<u8>) {
        self.spare_z = z;
    }
}

impl Drop for ChunkCompressor {
    fn drop(&mut self) {
        // The thread sees its queue closed once it has handed back what it holds.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl<W: Write> std::fmt::Debug for McapFile<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapFile")
            .field("pos", &self.pos)
            .field("chunks", &self.chunk_indexes.len())
            .field("messages", &self.messages)
            .finish_non_exhaustive()
    }
}

impl<W: Write> Drop for McapFile<W> {
    /// A writer dropped unfinished (an error on the way) still ends the file with its
    /// summary, as the crate's writer does.
    fn drop(&mut self) {
        if !self.finishing && !self.poisoned {
            let _ = self.finish();
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Two channels sharing a schema, a third with its own, three chunks, metadata and an
    /// attachment: a small file written with 64-byte chunks.
    fn sample() -> Vec<u8> {
        let mut w = McapFile::new(Vec::new(), "", "m6p-twin test", 64, 1).unwrap();
        let meta: BTreeMap<String, String> = [("seed".to_owned(), "7".to_owned())].into();
        w.metadata("m6p-twin", &meta).unwrap();
        w.attach(5, 6, "scenario.toml", "application/toml", b"name = 'x'")
            .unwrap();
        let s1 = w.add_schema("m6p.A", "protobuf", b"schema a").unwrap();
        let s1_again = w.add_schema("m6p.A", "protobuf", b"schema a").unwrap();
        assert_eq!(s1, s1_again, "identical schema content shares its record");
        let s2 = w.add_schema("m6p.B", "protobuf", b"schema b").unwrap();
        let a = w
            .add_channel(s1, "/a", "protobuf", &BTreeMap::new())
            .unwrap();
        let b = w.add_channel(s1, "/b", "protobuf", &meta).unwrap();
        let c = w
            .add_channel(s2, "/c", "protobuf", &BTreeMap::new())
            .unwrap();
        for i in 0..10u32 {
            let ch = [a, b, c][i as usize % 3];
            let t = 1_000 + u64::from(i) * 10;
            w.message(ch, i / 3, t, t, &[i as u8; 20]).unwrap();
        }
        let written = w.finish().unwrap();
        assert_eq!(written.messages, 10);
        assert!(written.chunks >= 3, "{written:?}");
        let bytes = std::mem::take(w.get_mut());
        assert_eq!(written.bytes, bytes.len() as u64);
        bytes
    }

    /// The `mcap` crate's readers take the file: every message in order with its channel,
    /// schema and sequence, the summary's statistics, schemas, channels and indexes, the
    /// attachment and the metadata through their indexes, chunk CRCs checked.
    #[test]
    fn the_mcap_crate_reads_what_it_writes() {
        let bytes = sample();
        let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(Result::unwrap)
            .collect();
        assert_eq!(msgs.len(), 10);
        for (i, m) in msgs.iter().enumerate() {
            assert_eq!(m.channel.topic, ["/a", "/b", "/c"][i % 3]);
            assert_eq!(m.log_time, 1_000 + i as u64 * 10);
            assert_eq!(m.sequence, i as u32 / 3);
            assert_eq!(&m.data[..], &[i as u8; 20]);
            let schema = m.channel.schema.as_ref().unwrap();
            assert_eq!(schema.name, if i % 3 == 2 { "m6p.B" } else { "m6p.A" });
        }
        assert_eq!(msgs[1].channel.metadata.get("seed").unwrap(), "7");

        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let stats = summary.stats.clone().unwrap();
        assert_eq!(stats.message_count, 10);
        assert_eq!((stats.schema_count, stats.channel_count), (2, 3));
        assert_eq!((stats.attachment_count, stats.metadata_count), (1, 1));
        assert_eq!(stats.chunk_count as usize, summary.chunk_indexes.len());
        assert_eq!(
            (stats.message_start_time, stats.message_end_time),
            (1_000, 1_090)
        );
        assert_eq!(stats.channel_message_counts.values().sum::<u64>(), 10);
        assert_eq!(summary.schemas.len(), 2);
        assert_eq!(summary.channels.len(), 3);
        // Each chunk by its index, as a seeking reader (Foxglove) goes.
        let mut by_index = 0;
        for ci in &summary.chunk_indexes {
            assert_eq!(ci.compression, "zstd");
            assert!(!ci.message_index_offsets.is_empty());
            for m in summary.stream_chunk(&bytes, ci).unwrap() {
                let m = m.unwrap();
                assert!(m.log_time >= ci.message_start_time && m.log_time <= ci.message_end_time);
                by_index += 1;
            }
            let idx = summary.read_message_indexes(&bytes, ci).unwrap();
            let entries: usize = idx.values().map(Vec::len).sum();
            assert!(entries > 0);
        }
        assert_eq!(by_index, 10);
        let att = mcap::read::attachment(&bytes, &summary.attachment_indexes[0]).unwrap();
        assert_eq!(
            (att.name.as_str(), &att.data[..]),
            ("scenario.toml", &b"name = 'x'"[..])
        );
        assert_eq!((att.log_time, att.create_time), (5, 6));
        let meta = mcap::read::metadata(&bytes, &summary.metadata_indexes[0]).unwrap();
        assert_eq!(meta.metadata.get("seed").unwrap(), "7");
    }

    /// The chunks are the bytes of compressing inline: each chunk's stored bytes are what
    /// one zstd context at the writer's level makes of its records, chunk after chunk.
    #[test]
    fn each_chunk_is_its_records_compressed_in_order_by_one_context() {
        let bytes = sample();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert!(summary.chunk_indexes.len() >= 3);
        let mut z = zstd::bulk::Compressor::new(1).unwrap();
        for ci in &summary.chunk_indexes {
            let end = (ci.chunk_start_offset + ci.chunk_length) as usize;
            let stored = &bytes[end - ci.compressed_size as usize..end];
            let records = zstd::bulk::decompress(stored, ci.uncompressed_size as usize).unwrap();
            assert_eq!(records.len() as u64, ci.uncompressed_size);
            assert!(z.compress(&records).unwrap() == stored, "{ci:?}");
        }
    }

    /// A record outside chunks follows every chunk closed before it, though chunks are
    /// compressed on another thread: chunks of messages before a metadata record (and an
    /// attachment) lie before it in the file, those after it after.
    #[test]
    fn records_outside_chunks_follow_the_chunks_before_them() {
        let mut w = McapFile::new(Vec::new(), "", "t", 64, 1).unwrap();
        let s = w.add_schema("m6p.A", "protobuf", b"a").unwrap();
        let a = w
            .add_channel(s, "/a", "protobuf", &BTreeMap::new())
            .unwrap();
        for i in 0..30u64 {
            w.message(a, i as u32, i, i, &[i as u8; 30]).unwrap();
            if i == 14 {
                w.metadata("mid", &BTreeMap::new()).unwrap();
                w.attach(14, 14, "mid.txt", "text/plain", b"mid").unwrap();
            }
        }
        w.finish().unwrap();
        let bytes = std::mem::take(w.get_mut());
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let meta = summary.metadata_indexes[0].offset;
        let att = summary.attachment_indexes[0].offset;
        assert!(summary.chunk_indexes.len() >= 10);
        for ci in &summary.chunk_indexes {
            if ci.message_end_time <= 14 {
                assert!(ci.chunk_start_offset + ci.chunk_length <= meta, "{ci:?}");
            } else {
                assert!(
                    ci.message_start_time > 14 && ci.chunk_start_offset > att,
                    "{ci:?}"
                );
            }
        }
        let read = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap().log_time)
            .collect::<Vec<_>>();
        assert_eq!(read, (0..30).collect::<Vec<u64>>());
    }

    /// The same calls give the same bytes, and a writer dropped without `finish` still
    /// ends the file with its summary.
    #[test]
    fn the_same_calls_give_the_same_bytes_and_a_drop_finishes_the_file() {
        assert_eq!(sample(), sample());
        let mut file = Vec::new();
        {
            let mut w = McapFile::new(&mut file, "", "t", 1 << 20, 1).unwrap();
            let s = w.add_schema("m6p.A", "protobuf", b"a").unwrap();
            let a = w
                .add_channel(s, "/a", "protobuf", &BTreeMap::new())
                .unwrap();
            w.message(a, 0, 1, 1, b"x").unwrap();
        }
        let summary = mcap::Summary::read(&file).unwrap().unwrap();
        assert_eq!(summary.stats.unwrap().message_count, 1);
        assert_eq!(&file[file.len() - 8..], MAGIC);
    }

    /// A sink that takes `room` bytes, then fails every write.
    struct Full<'a> {
        bytes: &'a mut Vec<u8>,
        room: usize,
    }

    impl Write for Full<'_> {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.bytes.len() + buf.len() > self.room {
                return Err(io::Error::other("disk full"));
            }
            self.bytes.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// After a failed write nothing more reaches the file: later messages, `finish` and the
    /// drop all stop, so no summary points at chunks that are not there, and the complete
    /// chunks before the failure stay readable. A finished file takes nothing more either.
    #[test]
    fn a_failed_write_stops_the_file_where_it_is() {
        let whole = sample();
        let mut bytes = Vec::new();
        {
            let sink = Full {
                bytes: &mut bytes,
                room: whole.len() / 2,
            };
            let mut w = McapFile::new(sink, "", "t", 64, 1).unwrap();
            let s = w.add_schema("m6p.A", "protobuf", b"a").unwrap();
            let a = w
                .add_channel(s, "/a", "protobuf", &BTreeMap::new())
                .unwrap();
            let mut failed = None;
            for i in 0..100u64 {
                if let Err(e) = w.message(a, i as u32, i, i, &[7; 40]) {
                    failed = Some(i);
                    assert!(e.to_string().contains("disk full"), "{e}");
                    break;
                }
            }
            assert!(failed.is_some());
            let e = w.message(a, 0, 200, 200, b"x").unwrap_err();
            assert!(e.to_string().contains("earlier write"), "{e}");
            assert!(w.finish().is_err());
        }
        let kept = bytes.len();
        assert!(kept <= whole.len() / 2);
        assert_eq!(&bytes[..8], MAGIC);
        // Only whole chunks and their indexes: the crate's linear reader stops cleanly at
        // the end of what was written, after some messages.
        let read = mcap::MessageStream::new(&bytes)
            .unwrap()
            .take_while(Result::is_ok)
            .count();
        assert!(read > 0);

        let mut w = McapFile::new(Vec::new(), "", "t", 64, 1).unwrap();
        let s = w.add_schema("m6p.A", "protobuf", b"a").unwrap();
        let a = w
            .add_channel(s, "/a", "protobuf", &BTreeMap::new())
            .unwrap();
        w.finish().unwrap();
        let n = w.get_mut().len();
        assert!(w.message(a, 0, 1, 1, b"x").is_err());
        assert!(w.metadata("x", &BTreeMap::new()).is_err());
        assert_eq!(w.finish().unwrap().bytes, n as u64);
        assert_eq!(w.get_mut().len(), n);
    }
}
