//! `m6p-twin inspect --sizes`: where a recording's bytes go, channel by channel.
//!
//! A chunk holds every channel's messages compressed together (4 MiB chunks), so no
//! channel's share of the file can be read off it. This estimates each share: the channel's
//! message data compressed on its own (zstd level 1, the recorder's level, a block per
//! [`BLOCK_BYTES`] of that channel's data), plus MCAP's message index, which lies outside
//! the chunks, uncompressed, at [`INDEX_BYTES_PER_MESSAGE`] bytes a message (plus 15 bytes
//! per channel per chunk, not counted; Foxglove's indexed reader, the one that seeks, needs
//! the index). A channel compressed alone can come out smaller or larger than its part of
//! the mixed chunks, and the estimates leave out the message records' own headers (31 bytes
//! a message before compression), so their sum is near the file's size, not equal to it.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context as _;

/// A channel's data is compressed in blocks of this many bytes.
pub const BLOCK_BYTES: usize = 1 << 20;

/// Bytes held in blocks not yet compressed, all channels together, before the largest is
/// compressed early (a recording can have many channels: two per KISS connection).
pub const HELD_BYTES_MAX: usize = 64 << 20;

/// zstd level of the estimate: the recorder's.
pub const ZSTD_LEVEL: i32 = 1;

/// An MCAP message index entry: log time and offset, 8 bytes each.
pub const INDEX_BYTES_PER_MESSAGE: u64 = 16;

/// One channel's share of a recording.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelSize {
    /// Topic.
    pub topic: String,
    /// Messages read.
    pub messages: u64,
    /// Their data, uncompressed.
    pub data_bytes: u64,
    /// Their data compressed on its own (zstd level 1, blocks of [`BLOCK_BYTES`]).
    pub zstd_bytes: u64,
    /// Their MCAP message index entries.
    pub index_bytes: u64,
}

impl ChannelSize {
    /// The channel's estimated share of the file: compressed data and index.
    pub fn share_bytes(&self) -> u64 {
        self.zstd_bytes + self.index_bytes
    }
}

/// Where a recording's bytes go.
#[derive(Debug, Clone, PartialEq)]
pub struct Sizes {
    /// Channels that have messages, largest share first (ties by topic).
    pub channels: Vec<ChannelSize>,
    /// The file's size.
    pub file_bytes: u64,
    /// The simulated span the figures per hour divide by, in hours: from the run's start
    /// (its metadata, else the first message) to the last message read, as `inspect`'s
    /// duration; 0 without messages.
    pub hours: f64,
    /// Why the file could not be read to its end, if so (the figures are of what was read).
    pub incomplete: Option<String>,
}

#[derive(Default)]
struct Acc {
    messages: u64,
    data_bytes: u64,
    zstd_bytes: u64,
    block: Vec<u8>,
}

impl Acc {
    fn compress_block(&mut self) -> anyhow::Result<()> {
        if !self.block.is_empty() {
            // Taken, not cleared: a channel done with its block gives its memory back.
            let block = std::mem::take(&mut self.block);
            let z = zstd::bulk::compress(&block, ZSTD_LEVEL).context("zstd")?;
            self.zstd_bytes += z.len() as u64;
        }
        Ok(())
    }
}

/// Read the recording at `path` and estimate each channel's share (module docs). A
/// truncated file gives the figures of what could be read, with [`Sizes::incomplete`]
/// saying why it stopped; a file that fails before its first message (not an MCAP file, or
/// cut before its first chunk) is an error. A recording without messages has no channels.
pub fn read_sizes(path: &Path) -> anyhow::Result<Sizes> {
    let file_bytes = std::fs::metadata(path)
        .with_context(|| format!("{}", path.display()))?
        .len();
    let start_ns = crate::recording::load_meta(path)
        .ok()
        .and_then(|m| twin_core::timefmt::parse_utc(&m.start_utc))
        .and_then(|ns| u64::try_from(ns).ok());
    let mut accs: BTreeMap<Arc<str>, Acc> = BTreeMap::new();
    let mut held = 0usize;
    let (mut first, mut last) = (u64::MAX, 0u64);
    let mut incomplete = None;
    for m in crate::recording::messages(path)? {
        let m = match m {
            Ok(m) => m,
            // Nothing readable (not an MCAP file, or cut before its first chunk): an error.
            Err(e) if accs.is_empty() => return Err(e),
            Err(e) => {
                incomplete = Some(format!("{e:#}"));
                break;
            }
        };
        first = first.min(m.log_time);
        last = last.max(m.log_time);
        let acc = accs.entry(m.topic).or_default();
        acc.messages += 1;
        acc.data_bytes += m.data.len() as u64;
        acc.block.extend_from_slice(&m.data);
        held += m.data.len();
        if acc.block.len() >= BLOCK_BYTES {
            held -= acc.block.len();
            acc.compress_block()?;
        }
        if held > HELD_BYTES_MAX
            && let Some(big) = accs.values_mut().max_by_key(|a| a.block.len())
        {
            held -= big.block.len();
            big.compress_block()?;
        }
    }
    let mut channels = Vec::with_capacity(accs.len());
    for (topic, mut acc) in accs {
        acc.compress_block()?;
        channels.push(ChannelSize {
            topic: topic.to_string(),
            messages: acc.messages,
            data_bytes: acc.data_bytes,
            zstd_bytes: acc.zstd_bytes,
            index_bytes: acc.messages * INDEX_BYTES_PER_MESSAGE,
        });
    }
    channels.sort_by(|a, b| {
        b.share_bytes()
            .cmp(&a.share_bytes())
            .then_with(|| a.topic.cmp(&b.topic))
    });
    let span_ns = last.saturating_sub(start_ns.unwrap_or(first));
    Ok(Sizes {
        channels,
        file_bytes,
        hours: span_ns as f64 / 3.6e12,
        incomplete,
    })
}

impl fmt::Display for Sizes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let per_hour = |bytes: u64| {
            if self.hours > 0.0 {
                format!("{:>10.3}", bytes as f64 / 1e6 / self.hours)
            } else {
                format!("{:>10}", "-")
            }
        };
        let mb = |bytes: u64| format!("{:>10.3}", bytes as f64 / 1e6);
        // The topic column as wide as the longest topic (KISS topics can be long).
        let w = self
            .channels
            .iter()
            .map(|c| c.topic.chars().count())
            .max()
            .unwrap_or(0)
            .max(32);
        writeln!(
            f,
            "where the bytes go, in MB: each channel's data compressed on its own \
             (zstd {ZSTD_LEVEL}),\n  and its MCAP message index ({INDEX_BYTES_PER_MESSAGE} \
             bytes a message); share = zstd + index"
        )?;
        writeln!(
            f,
            "  {:<w$} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
            "topic", "messages", "data", "zstd", "index", "share", "share/h"
        )?;
        let mut total = ChannelSize {
            topic: "all channels".into(),
            messages: 0,
            data_bytes: 0,
            zstd_bytes: 0,
            index_bytes: 0,
        };
        for c in &self.channels {
            total.messages += c.messages;
            total.data_bytes += c.data_bytes;
            total.zstd_bytes += c.zstd_bytes;
            total.index_bytes += c.index_bytes;
        }
        for c in self.channels.iter().chain(std::iter::once(&total)) {
            writeln!(
                f,
                "  {:<w$} {:>10} {} {} {} {} {}",
                c.topic,
                c.messages,
                mb(c.data_bytes),
                mb(c.zstd_bytes),
                mb(c.index_bytes),
                mb(c.share_bytes()),
                per_hour(c.share_bytes())
            )?;
        }
        write!(f, "file: {} MB", mb(self.file_bytes).trim())?;
        if self.hours > 0.0 {
            write!(
                f,
                ", {} MB per simulated hour over {:.3} h",
                per_hour(self.file_bytes).trim(),
                self.hours
            )?;
        }
        writeln!(f)?;
        if let Some(why) = &self.incomplete {
            writeln!(f, "incomplete: {why}")?;
        }
        Ok(())
    }
}
